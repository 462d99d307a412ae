"""Line search of the Newton iterations: Armijo sufficient decrease plus a curvature test.

Along a descent direction, ``phi(a)`` is the incremental potential at step length ``a``
and ``phi'(0) < 0`` its slope. The full Newton step is taken when it decreases the
energy enough and does not overshoot the minimum along the line by much
(``phi'(1) <= CURVATURE |phi'(0)|``). An overshoot, typical where friction switches
between stick and slip, is bracketed and the line minimum located by safeguarded secant
steps on ``phi'``; otherwise the step is halved until the energy decreases. Near
convergence the decrease hides in the round-off of the energy (positions minus
positions), and a step at the line minimum (small slope) within ``ROUND_OFF`` of the
energy is accepted.

The reduced solvers use the same rule and constants (``rust/core/src/solver``).
"""

from __future__ import annotations

import math
from collections.abc import Callable

__all__ = ["ARMIJO", "CURVATURE", "MAX_HALVINGS", "MAX_SECANT", "ROUND_OFF", "line_search"]

ARMIJO = 1.0e-4  # sufficient-decrease constant
CURVATURE = 0.5  # |phi'(a)| <= CURVATURE |phi'(0)| accepts a step near the line minimum
MAX_HALVINGS = 40  # step halvings before giving up
MAX_SECANT = 8  # secant steps locating an overshot line minimum
ROUND_OFF = 1.0e-10  # relative energy change taken as round-off near convergence
_SLACK = 1.0e-13  # relative energy slack of the Armijo test itself

Trial = Callable[[float, bool], tuple[float, float]]


def line_search(e0: float, d0: float, trial: Trial) -> tuple[float, float | None, int]:
    """Find a step length along a descent direction.

    Args:
        e0: energy at step length 0, J.
        d0: slope ``phi'(0)`` (< 0), J per unit step length.
        trial: ``trial(a, with_slope) -> (phi(a), phi'(a))`` (the slope may be NaN when
            not asked for); the last call is always at the returned step length, so a
            caller that keeps the trial point keeps the accepted one.

    Returns:
        ``(alpha, phi(alpha), evaluations)``, with ``phi(alpha)`` None when no step
        decreases the energy.
    """
    slack = _SLACK * max(abs(e0), 1e-300)
    noise = ROUND_OFF * max(abs(e0), 1e-300)

    def ok(a: float, e: float, d: float = math.nan) -> bool:
        if not math.isfinite(e):
            return False
        if e <= e0 + ARMIJO * a * d0 + slack:
            return True
        return e <= e0 + noise and math.isfinite(d) and abs(d) <= CURVATURE * abs(d0)

    evals = 1
    e1, d1 = trial(1.0, True)
    if ok(1.0, e1, d1) and d1 <= CURVATURE * abs(d0):
        return 1.0, e1, evals
    hi = 1.0
    best: tuple[float, float] | None = (1.0, e1) if ok(1.0, e1, d1) else None
    if math.isfinite(d1) and d1 > 0.0:
        lo, dlo, dhi = 0.0, d0, d1
        a = hi
        for _ in range(MAX_SECANT):
            width = hi - lo
            a = lo - dlo * width / (dhi - dlo)
            a = min(max(a, lo + 0.05 * width), hi - 0.05 * width)
            e, d = trial(a, True)
            evals += 1
            good = ok(a, e, d)
            if good and (best is None or e < best[1]):
                best = (a, e)
            if good and abs(d) <= CURVATURE * abs(d0):
                return a, e, evals
            if good and d < 0.0:
                lo, dlo = a, d
            elif math.isfinite(d) and d > 0.0:
                hi, dhi = a, d
            else:
                break
        if best is not None:
            if best[0] != a:
                trial(best[0], False)
                evals += 1
            return best[0], best[1], evals
    elif best is not None:
        return 1.0, e1, evals
    alpha = 0.5 * hi
    for _ in range(MAX_HALVINGS):
        e, _ = trial(alpha, False)
        evals += 1
        if ok(alpha, e):
            return alpha, e, evals
        alpha *= 0.5
    return alpha, None, evals
