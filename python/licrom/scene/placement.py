"""Placing a body relative to a ground plane: drop states and states carried between planes.

A state is described over the horizontal ground ``z = 0`` (a drop height, a tilt, velocities)
and carried onto any plane by the rigid motion that takes ``z = 0`` onto it, so "2 cm above
the ground, moving at 1 m/s along x" becomes "2 cm above the plane, moving along its downhill
direction". The CLI, the demo, the data sweeps, the benches and the examples all place bodies
with these.
"""

from __future__ import annotations

import numpy as np

from ..geometry.mesh import Mesh
from .scene import InitialState, Plane

__all__ = ["drop_state", "initial_state_between_planes", "initial_state_on_plane"]


def _plane_frame(plane: Plane) -> tuple[np.ndarray, np.ndarray]:
    """Rotation taking +z to the plane normal (smallest angle) and the plane point nearest the origin."""
    n = np.asarray(plane.normal)
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, n)
    s, c = float(np.linalg.norm(axis)), float(n @ z)
    if s < 1e-14:
        rot = np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    else:
        k = axis / s
        kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        rot = np.eye(3) + s * kx + (1.0 - c) * kx @ kx
    return rot, -plane.offset * n


def _rotation_vector(rot: np.ndarray) -> tuple[float, float, float]:
    from scipy.spatial.transform import Rotation

    return tuple(float(v) for v in Rotation.from_matrix(rot).as_rotvec())


def initial_state_on_plane(state: InitialState, plane: Plane, mesh: Mesh, density: float) -> InitialState:
    """Express ``state``, given for a horizontal ground ``z = 0``, on ``plane``.

    The placement and the velocities are carried by the rigid motion that takes the
    ground ``z = 0`` (normal +z) onto the plane, so "2 cm above the ground, moving at
    1 m/s along x" becomes "2 cm above the plane, moving at 1 m/s along its downhill
    direction" for an incline about y.
    """
    masses = mesh.vertex_masses(density)
    com = masses @ mesh.vertices / masses.sum()
    rot, origin = _plane_frame(plane)
    return InitialState(
        translation=tuple(rot @ (com + np.asarray(state.translation)) + origin - com),
        rotation=_rotation_vector(rot @ state.rotation_matrix()),
        velocity=tuple(rot @ np.asarray(state.velocity)),
        angular_velocity=tuple(rot @ np.asarray(state.angular_velocity)),
    )


def drop_state(mesh: Mesh, density: float, height: float, rotation=(0.0, 0.0, 0.0), velocity=(0.0, 0.0, 0.0),
               angular_velocity=(0.0, 0.0, 0.0)) -> InitialState:
    """Initial state over a horizontal ground ``z = 0``: the lowest point of the rotated mesh ``height`` above it."""
    masses = mesh.vertex_masses(density)
    com = masses @ mesh.vertices / masses.sum()
    rot = InitialState(rotation=rotation).rotation_matrix()
    lowest = float(((mesh.vertices - com) @ rot.T)[:, 2].min())
    return InitialState(translation=(-com[0], -com[1], height - lowest - com[2]), rotation=tuple(rotation),
                        velocity=tuple(velocity), angular_velocity=tuple(angular_velocity))



def initial_state_between_planes(state: InitialState, source: Plane, target: Plane, mesh: Mesh, density: float) -> InitialState:
    """Carry ``state``, given relative to ``source``, onto ``target`` (same pose relative to the plane).

    The inverse of :func:`initial_state_on_plane` for ``source``, followed by it for ``target``.
    """
    masses = mesh.vertex_masses(density)
    com = masses @ mesh.vertices / masses.sum()
    rot, origin = _plane_frame(source)
    flat = InitialState(
        translation=tuple(rot.T @ (com + np.asarray(state.translation) - origin) - com),
        rotation=_rotation_vector(rot.T @ state.rotation_matrix()),
        velocity=tuple(rot.T @ np.asarray(state.velocity)),
        angular_velocity=tuple(rot.T @ np.asarray(state.angular_velocity)),
    )
    return initial_state_on_plane(flat, target, mesh, density)
