"""The line search of the Newton iterations: the Python twin against the Rust core on the same problems."""

import math

import pytest
from licrom import _core
from licrom.full_sim.line_search import ARMIJO, CURVATURE, line_search


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
def test_python_and_rust_take_the_same_step(f):
    e0, g0 = f(1.0)
    d0 = -g0 if g0 > 0 else -1.0
    phi_py, calls_py = _along(f)
    phi_rs, calls_rs = _along(f)
    alpha, energy, evals = line_search(e0, d0, phi_py)
    rust = _core.line_search(e0, d0, phi_rs)
    assert calls_py == calls_rs and evals == len(calls_py)
    if rust is None:
        assert energy is None
    else:
        assert (alpha, energy) == rust
        assert calls_py[-1] == alpha  # the caller's trial point is the accepted one


def test_newton_step_on_a_quadratic_is_taken_whole():
    phi, calls = _along(_smooth_valley)
    assert line_search(0.5, -1.0, phi) == (1.0, 0.0, 1) and calls == [1.0]


def test_overshoot_is_bracketed_near_the_line_minimum():
    phi, _ = _along(_friction_kink)
    e0, g0 = _friction_kink(1.0)
    alpha, e, _ = line_search(e0, -g0, phi)
    assert e is not None and e <= e0 + ARMIJO * alpha * -g0
    assert abs(-_friction_kink(1.0 - alpha)[1]) <= CURVATURE * g0 or abs(alpha - 0.2) < 0.05


def test_a_rising_energy_gets_no_real_step():
    phi, calls = _along(_rising)
    alpha, e, _ = line_search(1.0, -1.0, phi)
    assert len(calls) > 10
    assert e is None or (alpha < 1e-9 and e - 1.0 <= 1e-13)


def test_an_exception_in_phi_reaches_the_caller_of_the_rust_search():
    def phi(a):
        raise ValueError("bad trial")

    with pytest.raises(ValueError, match="bad trial"):
        _core.line_search(1.0, -1.0, phi)


def test_constants_come_from_the_core():
    assert ARMIJO == _core.LINE_SEARCH["armijo"] and CURVATURE == _core.LINE_SEARCH["curvature"]
    assert math.isfinite(_core.LINE_SEARCH["noise"])
