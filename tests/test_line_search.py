"""The line search of the Newton iterations on one-dimensional problems."""

import math

from licrom.full_sim.line_search import ARMIJO, CURVATURE, line_search


def _along(f, df):
    """phi(a) = f(1 - a), a descent direction from x = 1 towards x = 0 (and beyond)."""
    calls = []

    def trial(a, with_slope):
        calls.append(a)
        x = 1.0 - a
        return f(x), (-df(x) if with_slope else math.nan)

    return trial, calls


def test_newton_step_on_a_quadratic_is_taken_whole():
    trial, calls = _along(lambda x: 0.5 * x * x, lambda x: x)
    alpha, e, evals = line_search(0.5, -1.0, trial)
    assert alpha == 1.0 and e == 0.0 and evals == 1 and calls == [1.0]


def test_overshoot_is_bracketed_and_the_line_minimum_found():
    # A kink like friction switching from slip to stick at x = 0.8: the full step lands far
    # past the minimum, where the slope has turned positive.
    f = lambda x: 0.5 * (x - 0.8) ** 2 * 100.0 if x < 0.8 else 0.2 * (x - 0.8)  # noqa: E731
    df = lambda x: 100.0 * (x - 0.8) if x < 0.8 else 0.2  # noqa: E731
    trial, calls = _along(f, df)
    e0, d0 = f(1.0), -df(1.0)
    alpha, e, _ = line_search(e0, d0, trial)
    assert e is not None and e <= e0 + ARMIJO * alpha * d0
    assert abs(-df(1.0 - alpha)) <= CURVATURE * abs(d0) or abs(alpha - 0.2) < 0.05
    assert calls[-1] == alpha  # the caller's trial point is the accepted one


def test_a_rising_energy_gets_no_real_step():
    # A wrong direction (the energy rises along it): at most a step lost in the round-off.
    trial, _ = _along(lambda x: 1.0 + (1.0 - x), lambda x: -1.0)
    alpha, e, evals = line_search(1.0, -1.0, trial)
    assert evals > 10
    assert e is None or (alpha < 1e-9 and e - 1.0 <= 1e-13)


def test_halving_finds_a_decrease_on_a_steep_valley():
    trial, _ = _along(lambda x: 1000.0 * (x - 0.999) ** 2, lambda x: 2000.0 * (x - 0.999))
    e0 = 1000.0 * 0.001**2
    alpha, e, _ = line_search(e0, -2.0, trial)
    assert e is not None and e < e0 and alpha < 0.01
