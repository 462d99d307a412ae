"""Where independent tasks run: in this process, in a pool of local processes, or on a Ray cluster.

:func:`run_tasks` calls one module-level function on each of a list of arguments and
yields ``(index, result)`` as the tasks finish, whatever runs them:

- ``"local"`` with ``jobs=1``: one after the other in this process, in order;
- ``"local"`` with ``jobs=N``: a pool of N processes on this machine, started with the
  ``spawn`` method (warp and CUDA do not survive ``fork``);
- ``"ray"``: one Ray task each, on the cluster :func:`ray.init` finds (``RAY_ADDRESS``, or
  a cluster started on this machine by ``ray start``; else a local one for the call),
  with one GPU per task when the cluster has GPUs. Ray is an optional extra:
  ``pip install "licrom[ray]"``. A ``RAY_ADDRESS`` where nothing answers is refused after
  :data:`RAY_TIMEOUT` seconds (``ray_timeout``, or the ``LICROM_RAY_TIMEOUT`` environment
  variable) instead of Ray's retries for many minutes.

The function and its arguments must be picklable; the function must be importable where
the tasks run (licrom installed on every node of a cluster). Exceptions of a task pass
through to the caller; the tasks not yet finished are then cancelled.
"""

from __future__ import annotations

import math
import multiprocessing
import os
import socket
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from typing import Any

import numpy as np

from .errors import ConfigError

__all__ = ["EXECUTORS", "RAY_TIMEOUT", "check_executor", "check_ray_timeout", "run_tasks", "task_resources"]

EXECUTORS = ("local", "ray")
RAY_TIMEOUT = 30.0
"""Seconds the Ray executor waits for the cluster at ``RAY_ADDRESS`` to answer before a ConfigError
(``LICROM_RAY_TIMEOUT`` in the environment replaces it)."""


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


def check_ray_timeout(timeout: Any) -> float:
    """The seconds to wait for a Ray cluster: ``timeout``, else ``LICROM_RAY_TIMEOUT``, else :data:`RAY_TIMEOUT`.

    Raises:
        ConfigError: not a finite number of seconds > 0 (the environment variable named when it is the culprit).
    """
    name = "ray_timeout"
    if timeout is None:
        env = os.environ.get("LICROM_RAY_TIMEOUT", "").strip()
        if not env:
            return RAY_TIMEOUT
        name = "LICROM_RAY_TIMEOUT"
        try:
            timeout = float(env)
        except ValueError:
            timeout = env
    if (isinstance(timeout, bool) or not isinstance(timeout, (int, float, np.integer, np.floating))
            or not math.isfinite(timeout) or timeout <= 0):
        raise ConfigError(f"{name} must be a finite number of seconds > 0, got {timeout!r}")
    return float(timeout)


def run_tasks(fn: Callable[..., Any], args: Sequence[tuple[Any, ...]], executor: str = "local", jobs: int | None = None,
              ray_timeout: float | None = None) -> Iterator[tuple[int, Any]]:
    """Yield ``(i, fn(*args[i]))`` for every i, as the tasks finish.

    Args:
        fn: a module-level function.
        args: the arguments of each task.
        executor: ``"local"`` or ``"ray"``.
        jobs: processes of the local executor.
        ray_timeout: seconds to wait for the Ray cluster at ``RAY_ADDRESS`` to answer (default: see
            :func:`check_ray_timeout`).

    Raises:
        ConfigError: see :func:`check_executor`; Ray not installed; no Ray cluster answers at ``RAY_ADDRESS``
            within ``ray_timeout`` seconds.
    """
    executor, jobs = check_executor(executor, jobs)
    if executor == "ray":
        yield from _run_ray(fn, args, check_ray_timeout(ray_timeout))
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


def _check_ray_address(timeout: float) -> None:
    """Refuse a ``RAY_ADDRESS`` (``host:port`` or ``ray://host:port``) where nothing accepts a connection within ``timeout`` s.

    ``ray.init`` retries such an address for many minutes; one TCP connection tells at once (refused) or
    within ``timeout``. Without ``RAY_ADDRESS`` (or with ``auto`` / ``local``) Ray finds or starts a cluster
    on this machine, and there is nothing to check.
    """
    address = os.environ.get("RAY_ADDRESS", "").strip()
    if address in ("", "auto", "local"):
        return
    target = address.split("://", 1)[1] if "://" in address else address
    host, _, port = target.rstrip("/").rpartition(":")
    if not host or not port.isdigit():
        raise ConfigError(f"RAY_ADDRESS must be host:port or ray://host:port of a Ray cluster (or auto, local), got {address!r}")
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=timeout):
            pass
    except OSError as exc:
        why = f"nothing answered within {timeout:g} s" if isinstance(exc, TimeoutError) else (exc.strerror or str(exc))
        raise ConfigError(f"no Ray cluster at RAY_ADDRESS={address!r} ({why}); start one there (ray start --head), point "
                          f"RAY_ADDRESS at a running one, or unset it to run a local cluster; the wait is set by ray_timeout "
                          f"(licrom generate --ray-timeout, or LICROM_RAY_TIMEOUT), now {timeout:g} s") from None


def _run_ray(fn: Callable[..., Any], args: Sequence[tuple[Any, ...]], timeout: float = RAY_TIMEOUT) -> Iterator[tuple[int, Any]]:
    ray = _import_ray()
    if not args:  # nothing to run: no cluster to start
        return
    started = not ray.is_initialized()
    if started:
        _check_ray_address(timeout)
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
