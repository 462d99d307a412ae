"""Placing bodies relative to planes: drop states, carried onto any plane and between planes."""

import numpy as np
import pytest
from licrom import Plane, meshes
from licrom.scene.placement import drop_state, initial_state_between_planes, initial_state_on_plane


def test_initial_state_is_carried_onto_the_plane():
    mesh = meshes.box((0.2, 0.1, 0.05), resolution=2)
    state = drop_state(mesh, 1000.0, height=0.03, rotation=(0.0, 0.0, 0.4), velocity=(1.0, 0.0, -0.5))
    for plane in (Plane.incline(30.0, 0.5), Plane((0.3, -0.2, 1.0), 0.1, 0.5)):
        placed = initial_state_on_plane(state, plane, mesh, 1000.0)
        x, v = placed.apply(mesh.vertices, mesh.vertex_masses(1000.0))
        n = np.array(plane.normal)
        assert (x @ n + plane.offset).min() == pytest.approx(0.03, abs=1e-12)
        # Velocity: 0.5 m/s into the plane, 1 m/s along it.
        assert v[0] @ n == pytest.approx(-0.5)
        assert np.linalg.norm(v[0] - (v[0] @ n) * n) == pytest.approx(1.0)


def test_a_state_carried_between_planes_keeps_its_pose_relative_to_them():
    mesh = meshes.box((0.2, 0.1, 0.05), resolution=2)
    state = drop_state(mesh, 1000.0, height=0.02, rotation=(0.1, 0.0, 0.3), velocity=(0.7, 0.0, -0.2))
    source, target = Plane.incline(10.0, 0.5), Plane((0.2, 0.4, 1.0), 0.05, 0.5)
    direct = initial_state_on_plane(state, target, mesh, 1000.0)
    carried = initial_state_between_planes(initial_state_on_plane(state, source, mesh, 1000.0), source, target, mesh, 1000.0)
    x0, v0 = direct.apply(mesh.vertices, mesh.vertex_masses(1000.0))
    x1, v1 = carried.apply(mesh.vertices, mesh.vertex_masses(1000.0))
    np.testing.assert_allclose(x1, x0, atol=1e-12)
    np.testing.assert_allclose(v1, v0, atol=1e-12)
