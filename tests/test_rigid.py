"""Rigid fits: exact on rigid motions, and the body-frame part is what is left."""

import numpy as np
import pytest
from licrom.errors import ShapeError
from licrom.rigid import (
    best_rotation,
    body_frame_displacements,
    nonrigid_displacements,
    rigid_fit,
    rotation_angle,
)


def _rotation(axis, angle):
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def test_rigid_motion_is_recovered_exactly():
    rng = np.random.default_rng(0)
    rest = rng.normal(size=(30, 3))
    m = rng.uniform(0.5, 2.0, 30)
    r = _rotation([1, 2, -0.5], 2.5)  # beyond 90 degrees: no small-angle shortcut
    x = (rest - rest.mean(0)) @ r.T + np.array([3.0, -1.0, 0.5])
    c, rot = rigid_fit(x, rest, m)
    np.testing.assert_allclose(rot, r, atol=1e-12)
    np.testing.assert_allclose(c, np.einsum("ni,n->i", x, m) / m.sum(), atol=1e-12)
    assert np.abs(body_frame_displacements(x, rest, m)).max() < 1e-12
    assert abs(rotation_angle(rot) - 2.5) < 1e-12


def test_body_frame_part_of_a_rotated_stretch():
    # A cube grid has an isotropic second moment J, so for a symmetric positive stretch S the
    # Kabsch matrix R S J is a rotation times a symmetric positive matrix: its rotation is R.
    g = np.linspace(-1.0, 1.0, 3)
    rest = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3) + 0.3
    m = np.ones(len(rest))
    xbar = rest - rest.mean(0)
    stretch = np.array([[1.1, 0.05, 0.0], [0.05, 0.95, 0.0], [0.0, 0.0, 1.0]])
    r = _rotation([0, 0, 1], 0.7)
    frames = np.stack([xbar @ stretch.T @ r.T + 1.0, xbar])
    u = body_frame_displacements(frames, rest, m)
    np.testing.assert_allclose(u[0], xbar @ (stretch - np.eye(3)).T, atol=1e-12)
    assert np.abs(u[1]).max() < 1e-12
    world = nonrigid_displacements(frames, rest, m)
    np.testing.assert_allclose(np.linalg.norm(world[0]), np.linalg.norm(u[0]), rtol=1e-12)


def test_reflection_is_never_returned():
    a = np.diag([1.0, 1.0, -1.0])
    assert np.linalg.det(best_rotation(a)) > 0


def test_shapes_are_checked():
    with pytest.raises(ShapeError, match="positions"):
        rigid_fit(np.zeros((5, 2)), np.zeros((5, 3)), np.ones(5))
    with pytest.raises(ShapeError, match="masses"):
        rigid_fit(np.zeros((5, 3)), np.zeros((5, 3)), np.ones(4))
