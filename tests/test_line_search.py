"""The line search of every Newton iteration (the Rust core's, which the full simulation calls too) on model problems."""

import math

import pytest
from licrom import ConfigError, _core

ARMIJO = _core.LINE_SEARCH["armijo"]
CURVATURE = _core.LINE_SEARCH["curvature"]


def _smooth_valley(x):
    return 0.5 * x * x, x


def _friction_kink(x):
    # Friction switching from slip to stick at x = 0.8: the full step lands past the minimum.
    return (50.0 * (x - 0.8) ** 2, 100.0 * (x - 0.8)) if x < 0.8 else (0.2 * (x - 0.8), 0.2)


def _rising(x):
    return 1.0 + (1.0 - x), -1.0  # a wrong direction: the energy rises along it


def _steep(x):
    return 1000.0 * (x - 0.999) ** 2, 2000.0 * (x - 0.999)


def _flat_within_round_off(x):
    return 1.0 + 1e-12 * (x - 0.5) ** 2, 2e-12 * (x - 0.5)


PROBLEMS = [_smooth_valley, _friction_kink, _rising, _steep, _flat_within_round_off]


def _along(f):
    """phi(a) = f(1 - a): from x = 1 towards x = 0 (and beyond), with the calls recorded."""
    calls = []

    def phi(a):
        calls.append(a)
        e, g = f(1.0 - a)
        return e, -g

    return phi, calls


@pytest.mark.parametrize("f", PROBLEMS, ids=lambda f: f.__name__)
def test_the_last_trial_is_the_step_taken(f):
    e0, g0 = f(1.0)
    d0 = -g0 if g0 > 0 else -1.0
    phi, calls = _along(f)
    step = _core.line_search(e0, d0, phi)
    if step is not None:
        alpha, energy = step
        assert calls[-1] == alpha  # the caller's trial point is the accepted one
        assert energy == f(1.0 - alpha)[0]


def test_newton_step_on_a_quadratic_is_taken_whole():
    phi, calls = _along(_smooth_valley)
    assert _core.line_search(0.5, -1.0, phi) == (1.0, 0.0) and calls == [1.0]


def test_overshoot_is_bracketed_near_the_line_minimum():
    phi, _ = _along(_friction_kink)
    e0, g0 = _friction_kink(1.0)
    alpha, e = _core.line_search(e0, -g0, phi)
    assert e <= e0 + ARMIJO * alpha * -g0
    assert abs(-_friction_kink(1.0 - alpha)[1]) <= CURVATURE * g0 or abs(alpha - 0.2) < 0.05


def test_a_rising_energy_gets_no_real_step():
    phi, calls = _along(_rising)
    step = _core.line_search(1.0, -1.0, phi)
    assert len(calls) > 10
    assert step is None or (step[0] < 1e-9 and step[1] - 1.0 <= 1e-13)


def test_an_exception_in_phi_reaches_the_caller_of_the_rust_search():
    def phi(a):
        raise ValueError("bad trial")

    with pytest.raises(ValueError, match="bad trial"):
        _core.line_search(1.0, -1.0, phi)


def test_a_slope_that_is_no_descent_is_refused():
    with pytest.raises(ConfigError, match="d0 must be a finite slope < 0"):
        _core.line_search(1.0, 0.5, lambda a: (1.0, 0.5))
    with pytest.raises(ConfigError, match="e0 must be a finite energy"):
        _core.line_search(math.nan, -1.0, lambda a: (1.0, -1.0))
