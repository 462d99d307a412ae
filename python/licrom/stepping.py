"""The run loop every simulator shares: step, time, record frames, show progress.

:class:`~licrom.full.FullSim`, :class:`~licrom.reduced.world.WorldFrameSim` and
:class:`~licrom.reduced.body.BodyFrameSim` differ in how they take a step and what a
frame is; the argument checks, the recording cadence, the timing and the progress bar
(closed also when a step raises) are one piece of code, and so is the rule that one
simulation serves one thread at a time (:func:`exclusive`).
"""

from __future__ import annotations

import contextlib
import functools
import math
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ._repr import concise_repr
from .errors import ConcurrencyError, ConfigError, ShapeError

__all__ = ["BUSY_MESSAGE", "IMPACT_FRAMES_PER_FRAME", "RunRecord", "ThreadGuard", "check_impact_window", "check_run_arguments", "exclusive", "record_run"]

StepOutcome = tuple[int, float, bool]
"""``(iterations, residual in m/s, converged)`` of one step."""

BUSY_MESSAGE = ("this simulation is busy in another thread (a step or evaluation is running there); a simulation serves one "
                "thread at a time: give each thread its own simulation, or guard a shared one with a threading.Lock")
"""What :class:`~licrom.errors.ConcurrencyError` says for a simulation in use by another thread (the reduced
simulations' native core says the same)."""


class ThreadGuard:
    """Exclusive use of one simulation by one thread at a time, as the reduced simulations' native core enforces.

    Entering it while another thread is inside raises :class:`~licrom.errors.ConcurrencyError` at once
    instead of waiting (waiting would interleave two threads' steps on one state); the thread inside may
    enter again (``run`` calls ``step``).
    """

    __slots__ = ("_lock",)

    def __init__(self) -> None:
        self._lock = threading.RLock()

    def __enter__(self) -> None:
        if not self._lock.acquire(blocking=False):
            raise ConcurrencyError(BUSY_MESSAGE)

    def __exit__(self, *exc: object) -> None:
        self._lock.release()


def exclusive(method: Callable[..., Any]) -> Callable[..., Any]:
    """Run a simulation's method inside its :class:`ThreadGuard` (the instance attribute ``_guard``).

    Raises:
        ConcurrencyError: (from the method) another thread is inside a guarded method of the same simulation.
    """

    @functools.wraps(method)
    def guarded(self: Any, *args: Any, **kwargs: Any) -> Any:
        with self._guard:
            return method(self, *args, **kwargs)

    return guarded


def check_field(name: str, a: Any, n: int) -> np.ndarray:
    """``a`` as a contiguous real (n, 3) float64 array of finite numbers (``set_state``'s positions/velocities).

    Raises:
        ShapeError: not an array of real numbers (strings, complex values, objects), the wrong shape, or NaN/inf.
    """
    what = f"{name} must be a real ({n}, 3) array of finite numbers"
    try:
        raw = np.asarray(a)
        if raw.dtype.kind not in "biufO":
            raise TypeError(f"dtype {raw.dtype}")
        arr = raw.astype(np.float64)
    except (TypeError, ValueError) as exc:
        raise ShapeError(f"{what}, got {type(a).__name__} ({exc})") from None
    if arr.shape != (n, 3):
        raise ShapeError(f"{name} must have shape ({n}, 3), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ShapeError(f"{name} hold NaN or inf")
    return np.ascontiguousarray(arr)


def check_run_arguments(steps: Any, record_every: Any) -> tuple[int, int]:
    """``steps`` (an integer >= 0) and ``record_every`` (an integer >= 1) as ints.

    Raises:
        ConfigError: anything else, booleans included.
    """
    if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) or steps < 0:
        raise ConfigError(f"steps must be an integer >= 0, got {steps!r}")
    if isinstance(record_every, bool) or not isinstance(record_every, (int, np.integer)) or record_every < 1:
        raise ConfigError(f"record_every must be an integer >= 1, got {record_every!r}")
    return int(steps), int(record_every)


IMPACT_FRAMES_PER_FRAME = 2
"""Impact frames a run keeps at most per regular frame (:func:`record_run`): its file at most triples. Within it the
training runs of results section 26 kept every impact (a cheese landing 45 frames of its 151, a ball's two
landings 190 of 101) but the two that tumble (341 and 360 of 151) and the box thrown to tumble (1124 of 151)."""


def check_impact_window(impact_window: Any) -> float:
    """``impact_window`` (a finite time >= 0, s) as a float.

    Raises:
        ConfigError: anything else, booleans included.
    """
    if isinstance(impact_window, bool) or not isinstance(impact_window, (int, float, np.integer, np.floating)) \
            or not 0.0 <= impact_window < math.inf:
        raise ConfigError(f"impact_window must be a finite time >= 0 in s, got {impact_window!r}")
    return float(impact_window)


@dataclass
class RunRecord:
    """What :func:`record_run` recorded: frame 0 and every ``record_every``-th step's frame.

    Attributes:
        frames: the snapshots, in order.
        times: simulated time of each frame, s.
        iterations, residuals, converged, seconds: per step (wall time in s).
        between: per frame, ``(min det F, deepest penetration in m)`` over the steps since the
            previous frame, this frame's included (``(inf, 0)`` for frame 0 and without a
            ``validity`` probe).
        trailing: the same over the steps after the last frame.
        impact_frames, impact_times: snapshots and times of the steps between frames inside an
            impact window (see :func:`record_run`).
    """

    frames: list[Any] = field(default_factory=list)
    times: list[float] = field(default_factory=list)
    iterations: list[int] = field(default_factory=list)
    residuals: list[float] = field(default_factory=list)
    converged: list[bool] = field(default_factory=list)
    seconds: list[float] = field(default_factory=list)
    between: list[tuple[float, float]] = field(default_factory=list)
    trailing: tuple[float, float] = (np.inf, 0.0)
    impact_frames: list[Any] = field(default_factory=list)
    impact_times: list[float] = field(default_factory=list)

    __repr__ = concise_repr

    def arrays(self) -> dict[str, np.ndarray]:
        """The per-step lists as the arrays :class:`~licrom.records.trajectory.Trajectory` takes."""
        return {
            "times": np.array(self.times, dtype=np.float64),
            "iterations": np.array(self.iterations, dtype=np.int32),
            "residuals": np.array(self.residuals, dtype=np.float64),
            "converged": np.array(self.converged, dtype=bool),
            "step_seconds": np.array(self.seconds, dtype=np.float64),
        }


@contextlib.contextmanager
def _progress(total: int, desc: str, enabled: bool) -> Iterator[Any]:
    if not enabled:
        yield None
        return
    from tqdm import tqdm

    bar = tqdm(total=total, desc=desc, unit="step", leave=False)
    try:
        yield bar
    finally:
        bar.close()


def record_run(
    step: Callable[[], StepOutcome],
    snapshot: Callable[[], Any],
    clock: Callable[[], float],
    steps: Any,
    record_every: Any = 1,
    progress: bool = False,
    desc: str = "steps",
    validity: Callable[[], tuple[float, float]] | None = None,
    impact_window: int = 0,
) -> RunRecord:
    """Take ``steps`` steps and record the state before the first and after every ``record_every``-th.

    With ``impact_window`` and a ``validity`` probe, the state after every other step is kept too, as an impact
    frame, for ``impact_window`` steps from each impact: a step that ends with a vertex inside a plane after one
    that ended with none (the start counts as none). An impact's fast transient falls between regular frames.
    A run keeps at most :data:`IMPACT_FRAMES_PER_FRAME` impact frames per regular frame, the first ones: one that keeps
    touching down (a tumble) would otherwise keep nearly every step.

    Args:
        step: takes one step; returns ``(iterations, residual, converged)``.
        snapshot: the state to record (any object).
        clock: the simulated time, s.
        steps: number of steps, an integer >= 0.
        record_every: record cadence, an integer >= 1.
        progress: show a progress bar.
        desc: the bar's label.
        validity: ``(min det F, deepest penetration)`` after a step, probed after every step
            (:mod:`licrom.validity`: a state between frames counts too).
        impact_window: steps kept as impact frames from each impact (0: none).

    Raises:
        ConfigError: bad ``steps`` or ``record_every``. Whatever ``step`` raises passes through.
    """
    steps, record_every = check_run_arguments(steps, record_every)
    if isinstance(impact_window, bool) or not isinstance(impact_window, (int, np.integer)) or impact_window < 0:
        raise ConfigError(f"impact_window must be an integer >= 0 (steps), got {impact_window!r}")
    rec = RunRecord(frames=[snapshot()], times=[clock()], between=[(np.inf, 0.0)])
    worst = (np.inf, 0.0)
    touching, window_left = False, 0
    with _progress(steps, desc, progress) as bar:
        for s in range(1, steps + 1):
            start = time.perf_counter()
            its, res, ok = step()
            rec.seconds.append(time.perf_counter() - start)
            rec.iterations.append(its)
            rec.residuals.append(res)
            rec.converged.append(ok)
            if validity is not None:
                det, depth = validity()
                worst = (min(worst[0], det), max(worst[1], depth))
                if depth > 0.0 and not touching:
                    window_left = impact_window
                touching = depth > 0.0
            if s % record_every == 0:
                rec.frames.append(snapshot())
                rec.times.append(clock())
                rec.between.append(worst)
                worst = (np.inf, 0.0)
            elif window_left > 0 and len(rec.impact_frames) < IMPACT_FRAMES_PER_FRAME * (steps // record_every + 1):
                rec.impact_frames.append(snapshot())
                rec.impact_times.append(clock())
            window_left = max(window_left - 1, 0)
            if bar is not None:
                bar.update(1)
                bar.set_postfix(iterations=its, refresh=False)
    rec.trailing = worst
    return rec
