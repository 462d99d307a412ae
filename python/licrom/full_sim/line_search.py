"""Line search of the full-space Newton iterations: the reduced solvers' rule, with their constants.

Along a descent direction, ``phi(a)`` is the incremental potential at step length ``a``
and ``phi'(0) < 0`` its slope. The full Newton step is taken when it decreases the
energy enough (Armijo) and does not overshoot the minimum along the line by much
(``phi'(1) <= CURVATURE |phi'(0)|``). An overshoot, typical where friction switches
between stick and slip, is bracketed and the line minimum located by safeguarded secant
steps on ``phi'``; otherwise the step is halved until the energy decreases. Near
convergence the decrease hides in the round-off of the energy (positions minus
positions), and a step at the line minimum (small slope) within ``NOISE`` of the energy
is accepted.

The rule is ``rust/core/src/solver/line_search.rs``'s, step for step, and the constants
are read from it (``licrom._core.LINE_SEARCH``): one documented set for every solver.
``tests/test_line_search.py`` runs both on the same problems.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable

from .. import _core

__all__ = ["ARMIJO", "CURVATURE", "MAX_HALVINGS", "MAX_SECANT", "NOISE", "ROUNDOFF_ULPS", "line_search", "sufficient_decrease"]

ARMIJO = float(_core.LINE_SEARCH["armijo"])
CURVATURE = float(_core.LINE_SEARCH["curvature"])
MAX_SECANT = int(_core.LINE_SEARCH["max_secant"])
MAX_HALVINGS = int(_core.LINE_SEARCH["max_halvings"])
ROUNDOFF_ULPS = float(_core.LINE_SEARCH["roundoff_ulps"])
NOISE = float(_core.LINE_SEARCH["noise"])

Phi = Callable[[float], tuple[float, float]]


def sufficient_decrease(e0: float, d0: float, alpha: float, e: float) -> bool:
    """Armijo's test with ``ROUNDOFF_ULPS`` of the energy scale allowed for round-off."""
    return math.isfinite(e) and e <= e0 + ARMIJO * alpha * d0 + ROUNDOFF_ULPS * sys.float_info.epsilon * max(abs(e0), abs(e))


def line_search(e0: float, d0: float, phi: Phi) -> tuple[float, float | None, int]:
    """Find a step length along a descent direction.

    Args:
        e0: energy at step length 0, J.
        d0: slope ``phi'(0)`` (< 0), J per unit step length.
        phi: ``phi(a) -> (phi(a), phi'(a))``; the last call is always at the returned
            step length, so a caller that keeps the trial point keeps the accepted one.

    Returns:
        ``(alpha, phi(alpha), evaluations)``, with ``phi(alpha)`` None when no step
        decreases the energy.
    """

    def ok(a: float, e: float, d: float) -> bool:
        if sufficient_decrease(e0, d0, a, e):
            return True
        scale = max(abs(e0), abs(e))
        return math.isfinite(e) and e <= e0 + NOISE * scale and math.isfinite(d) and abs(d) <= CURVATURE * abs(d0)

    evals = 1
    e1, d1 = phi(1.0)
    good1 = ok(1.0, e1, d1)
    if good1 and d1 <= CURVATURE * abs(d0):
        return 1.0, e1, evals
    hi = 1.0
    if math.isfinite(d1) and d1 > 0.0:
        best: tuple[float, float] | None = (1.0, e1) if good1 else None
        lo, dlo, dhi = 0.0, d0, d1
        last = 1.0
        for _ in range(MAX_SECANT):
            width = hi - lo
            a = min(max(lo - dlo * width / (dhi - dlo), lo + 0.05 * width), hi - 0.05 * width)
            e, d = phi(a)
            evals += 1
            last = a
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
            if best[0] != last:
                phi(best[0])
                evals += 1
            return best[0], best[1], evals
    elif good1:
        return 1.0, e1, evals
    alpha = 0.5 * hi
    for _ in range(MAX_HALVINGS):
        e, d = phi(alpha)
        evals += 1
        if ok(alpha, e, d):
            return alpha, e, evals
        alpha *= 0.5
    return alpha, None, evals
