"""Farthest-point sampling of point sets (licrom.geometry.points)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from licrom import ConfigError, ShapeError
from licrom.geometry.points import farthest_points


def test_points_on_a_line_are_taken_middle_then_ends_then_halves():
    line = np.linspace(0.0, 1.0, 9)[:, None]
    assert farthest_points(line, 5).tolist() == [4, 0, 8, 2, 6]
    assert farthest_points(line, 2, first=0).tolist() == [0, 8]


@settings(max_examples=30, deadline=None)
@given(st.integers(2, 40), st.integers(1, 3), st.integers(0, 1000))
def test_each_choice_is_the_farthest_from_those_before(n, dim, seed):
    points = np.random.default_rng(seed).normal(size=(n, dim))
    chosen = farthest_points(points, n)
    assert sorted(chosen.tolist()) == list(range(n))
    for k in range(1, n):
        gap = np.linalg.norm(points[:, None] - points[chosen[:k]][None], axis=2).min(axis=1)
        assert gap[chosen[k]] == gap.max()


@pytest.mark.parametrize(("points", "kwargs", "error"), [
    (np.zeros((0, 3)), {"count": 1}, ShapeError),
    (np.zeros(4), {"count": 1}, ShapeError),
    (np.array([[0.0], [np.nan]]), {"count": 1}, ShapeError),
    (np.zeros((3, 2)), {"count": 4}, ConfigError),
    (np.zeros((3, 2)), {"count": 0}, ConfigError),
    (np.zeros((3, 2)), {"count": 2.0}, ConfigError),
    (np.zeros((3, 2)), {"count": 2, "first": 3}, ConfigError),
])
def test_bad_input_is_a_named_error(points, kwargs, error):
    with pytest.raises(error, match="farthest_points"):
        farthest_points(points, **kwargs)
