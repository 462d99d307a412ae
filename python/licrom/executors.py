"""Where independent tasks run: in this process, in a pool of local processes, or on a Ray cluster.

:func:`run_tasks` calls one module-level function on each of a list of arguments and
yields ``(index, result)`` as the tasks finish, whatever runs them:

- ``"local"`` with ``jobs=1``: one after the other in this process, in order;
- ``"local"`` with ``jobs=N``: a pool of N processes on this machine, started with the
  ``spawn`` method (warp and CUDA do not survive ``fork``);
- ``"ray"``: one Ray task each, on the cluster :func:`ray.init` finds (``RAY_ADDRESS``, or
  a cluster started on this machine by ``ray start``; else a local one for the call),
  with one GPU per task when the cluster has GPUs. Ray is an optional extra:
  ``pip install "licrom[ray]"``.

The function and its arguments must be picklable; the function must be importable where
the tasks run (licrom installed on every node of a cluster). Exceptions of a task pass
through to the caller; the tasks not yet finished are then cancelled.
"""

from __future__ import annotations

import multiprocessing
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from typing import Any

import numpy as np

from .errors import ConfigError

__all__ = ["EXECUTORS", "check_executor", "run_tasks", "task_resources"]

EXECUTORS = ("local", "ray")


def check_executor(executor: Any, jobs: Any) -> tuple[str, int]:
    """``(executor, jobs)`` checked: ``jobs`` (processes of the local executor) as an int.

    ``jobs=None`` means 1 for ``"local"``; Ray schedules by the cluster's resources, so
    ``"ray"`` takes no ``jobs``.

    Raises:
        ConfigError: an unknown executor, ``jobs`` not an integer >= 1, or ``jobs`` with Ray.
    """
    if executor not in EXECUTORS:
        raise ConfigError(f"executor must be one of {', '.join(EXECUTORS)}, got {executor!r}")
    if jobs is not None and (isinstance(jobs, bool) or not isinstance(jobs, (int, np.integer)) or jobs < 1):
        raise ConfigError(f"jobs must be an integer >= 1, got {jobs!r}")
    if executor == "ray":
        if jobs is not None:
            raise ConfigError("jobs applies to executor 'local' only; Ray runs as many tasks at once as the cluster has resources for")
        return executor, 0
    return executor, 1 if jobs is None else int(jobs)


def run_tasks(fn: Callable[..., Any], args: Sequence[tuple[Any, ...]], executor: str = "local", jobs: int | None = None) -> Iterator[tuple[int, Any]]:
    """Yield ``(i, fn(*args[i]))`` for every i, as the tasks finish.

    Raises:
        ConfigError: see :func:`check_executor`; Ray not installed.
    """
    executor, jobs = check_executor(executor, jobs)
    if executor == "ray":
        yield from _run_ray(fn, args)
    elif jobs == 1 or len(args) <= 1:
        for i, a in enumerate(args):
            yield i, fn(*a)
    else:
        yield from _run_pool(fn, args, jobs)


def _run_pool(fn: Callable[..., Any], args: Sequence[tuple[Any, ...]], jobs: int) -> Iterator[tuple[int, Any]]:
    with ProcessPoolExecutor(max_workers=min(jobs, len(args)), mp_context=multiprocessing.get_context("spawn")) as pool:
        pending = {pool.submit(fn, *a): i for i, a in enumerate(args)}
        try:
            while pending:
                done, _ = wait(pending, return_when=FIRST_COMPLETED)
                for future in done:
                    yield pending.pop(future), future.result()
        finally:
            for future in pending:
                future.cancel()


def _import_ray() -> Any:
    try:
        import ray
    except ImportError:
        raise ConfigError('executor "ray" needs Ray, an optional extra of licrom: pip install "licrom[ray]" (or pip install ray)') from None
    return ray


def task_resources(cluster: dict[str, float]) -> dict[str, float]:
    """What one Ray task asks for on a cluster with ``cluster`` resources: a CPU, and a GPU if it has any."""
    return {"num_cpus": 1, "num_gpus": 1 if cluster.get("GPU", 0) > 0 else 0}


def _run_ray(fn: Callable[..., Any], args: Sequence[tuple[Any, ...]]) -> Iterator[tuple[int, Any]]:
    ray = _import_ray()
    if not args:  # nothing to run: no cluster to start
        return
    started = not ray.is_initialized()
    if started:
        ray.init(include_dashboard=False)
    try:
        remote = ray.remote(fn).options(**task_resources(ray.cluster_resources()))
        pending = {remote.remote(*a): i for i, a in enumerate(args)}
        try:
            while pending:
                done, _ = ray.wait(list(pending), num_returns=1)
                for ref in done:
                    yield pending.pop(ref), ray.get(ref)
        finally:
            for ref in pending:
                ray.cancel(ref)
    finally:
        if started:
            ray.shutdown()
