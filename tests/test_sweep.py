"""Sweeps: the product order of their axes, their count, the default friction, the friction check, held-out pairs."""

import itertools
import math

import numpy as np
import pytest
from licrom import ConfigError, InitialState, Plane, Scene, meshes
from licrom.data.dataset import DatasetSpec, sweep_runs
from licrom.data.scene_file import load_scene
from licrom.scene.sweep import (
    DEFAULT_FRICTION,
    check_friction,
    held_out_pairs,
    in_sweep,
    slope_friction_pairs,
    sweep,
    sweep_axis,
    sweep_count,
    tilted,
    with_friction,
)


def test_the_default_friction_is_the_planes():
    assert DEFAULT_FRICTION == Plane().friction == 0.5
    assert Plane.incline(10.0, DEFAULT_FRICTION).friction == Plane().friction


def test_the_first_axis_is_outermost():
    assert sweep((0.1, 0.2), (10.0, 20.0, 30.0), ("a", "b")) == [
        (0.1, 10.0, "a"), (0.1, 10.0, "b"), (0.1, 20.0, "a"), (0.1, 20.0, "b"), (0.1, 30.0, "a"), (0.1, 30.0, "b"),
        (0.2, 10.0, "a"), (0.2, 10.0, "b"), (0.2, 20.0, "a"), (0.2, 20.0, "b"), (0.2, 30.0, "a"), (0.2, 30.0, "b"),
    ]
    assert sweep([1, 2], [3]) == list(itertools.product([1, 2], [3]))


def test_an_axis_not_given_is_one_value():
    assert sweep(None, (1, 2), ()) == [(None, 1, None), (None, 2, None)]
    assert sweep_axis(None) == sweep_axis(()) == (None,)
    assert sweep_axis(None, 0.3) == sweep_axis([], 0.3) == (0.3,)
    assert sweep_axis(np.array([0.1, 0.2]), 0.3) == (0.1, 0.2)  # arrays too (no truth value asked of them)


@pytest.mark.parametrize("axes", [
    (), ((0.1, 0.2),), ((0.1, 0.2), (10.0, 20.0, 30.0), ("a", "b")), (None, (1, 2), None), ((), (), ()),
    (np.linspace(0.0, 1.0, 4), [Plane(), (Plane(), Plane())], [InitialState()] * 3),
])
def test_the_count_is_the_length_of_the_sweep(axes):
    assert sweep_count(*axes) == len(sweep(*axes))


@pytest.mark.parametrize("value", [0, 0.0, 0.5, 2, 1e9, np.float32(0.25), np.int64(1)])
def test_a_friction_coefficient_is_a_finite_number_at_least_zero(value):
    assert check_friction(value) == float(value) and type(check_friction(value)) is float


@pytest.mark.parametrize("value", [-0.1, -1, math.nan, math.inf, True, "0.3", None, [0.3], 10**400])
def test_bad_frictions_are_refused_naming_the_value(value):
    with pytest.raises(ConfigError, match=r"^planes\[2\]\.friction must be a number >= 0, got "):
        check_friction(value, "planes[2].friction")


def test_slope_friction_pairs_take_slopes_outermost_and_the_planes_values_where_none_are_given():
    plane = Plane.incline(15.0, 0.4)
    assert slope_friction_pairs((10.0, 20.0), (0.1, 0.2), plane) == [(10.0, 0.1), (10.0, 0.2), (20.0, 0.1), (20.0, 0.2)]
    assert slope_friction_pairs((), (0.1, 0.2), plane) == [(pytest.approx(15.0), 0.1), (pytest.approx(15.0), 0.2)]
    assert slope_friction_pairs((10.0,), None, plane) == [(10.0, 0.4)]
    assert slope_friction_pairs(None, None, None) == [(0.0, DEFAULT_FRICTION)]  # no plane: a horizontal one


def test_held_out_pairs_take_the_planes_values_for_those_left_out():
    plane = Plane.incline(15.0, 0.4)
    assert held_out_pairs([(20.0, None), (None, 0.1), (5.0, 0.9)], plane) == [
        (20.0, 0.4), (pytest.approx(15.0), 0.1), (5.0, 0.9)]
    assert held_out_pairs([(None, None)], None) == [(0.0, DEFAULT_FRICTION)]


def test_in_sweep_is_each_value_close_to_one_of_its_axis():
    assert in_sweep((20.0, 0.3), (10.0, 20.0), (0.1, 0.1 + 0.2))  # 0.1 + 0.2 != 0.3, but close
    assert not in_sweep((20.0, 0.4), (10.0, 20.0), (0.1, 0.3))
    assert not in_sweep((15.0, 0.3), (10.0, 20.0), (0.1, 0.3))
    assert not in_sweep((10.0,), (10.0,), (0.1,))  # a point of another sweep


def test_tilted_inclines_the_first_plane_and_keeps_the_others():
    first, second = Plane((0.0, 0.5, 1.0), 0.1, 0.3), Plane((1.0, 0.0, 0.0), 2.0, 0.7)
    planes = tilted((first, second), 25.0)
    assert planes[1] is second and planes[0].friction == 0.3 and planes[0].offset == pytest.approx(first.offset)
    assert planes[0].slope_deg == pytest.approx(25.0) and planes[0].azimuth_deg == pytest.approx(first.azimuth_deg)
    assert tilted((first,), 25.0, 0.9)[0].friction == 0.9
    assert with_friction((first, second), 0.2) == (Plane(first.normal, first.offset, 0.2), Plane(second.normal, second.offset, 0.2))
    assert with_friction([first], None) == (first,)


def test_the_callers_sweep_in_its_order():
    mesh = meshes.box(resolution=2)
    states = (InitialState(), InitialState(translation=(0.0, 0.0, 0.1)))
    runs = sweep_runs(mesh, Scene(), (0.2, 0.6), (10.0, 30.0, 20.0), states)
    assert [(mu, round(planes[0].slope_deg, 6), k) for mu, planes, k, _, _ in runs] == [
        (mu, slope, k) for mu, slope, (k, _) in sweep((0.2, 0.6), (10.0, 30.0, 20.0), enumerate(states))]
    spec = DatasetSpec("s", mesh, Scene(), (0.2, 0.6), (10.0, 30.0, 20.0), states, steps=1, record_every=1, initial_frame="world")
    assert spec.n_trajectories == len(spec.scenes()) == len(runs) == 12
    cheese = load_scene("cheese")
    assert cheese.n_runs == sweep_count(cheese.frictions, cheese.slopes, cheese.initial) == len(cheese.dataset_spec(mesh).scenes())
    # Compared over every run of its sweep (no held-out scenes): frictions outermost, as the runs are.
    labels = [label for label, _ in cheese.replace(held_out=()).cases(mesh)]
    assert labels == [f"slope {s:g} deg, mu {m:g}" for m, s in sweep(cheese.frictions, cheese.slopes)]
    # Given slopes and frictions: slopes outermost.
    labels = [label for label, _ in cheese.cases(mesh, (10.0, 20.0), (0.1, 0.2))]
    assert labels == [f"slope {s:g} deg, mu {m:g}" for s, m in sweep((10.0, 20.0), (0.1, 0.2))]
