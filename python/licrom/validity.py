"""When a simulation leaves the range where its physics holds, and what it says then.

The model (stable Neo-Hookean elements, penalty contact) keeps running outside its
valid range: inverted elements have finite energy, and a penalty contact that is too
soft for its load lets the body sink into the ground. Every simulator
(:class:`~licrom.full.FullSim`, :class:`~licrom.reduced.world.WorldFrameSim`,
:class:`~licrom.reduced.body.BodyFrameSim`) reports these cases the same way:

| case | signal | recorded in the trajectory |
|---|---|---|
| non-finite energy | :class:`~licrom.errors.SolverError` from the step, also with ``on_failure="record"`` (no finite iterate is left to keep) | nothing (the step is not taken) |
| inverted elements (``det F <= 0``) | :class:`PhysicsWarning` after ``run`` | ``Trajectory.min_det_f`` |
| penetration deeper than ``PENETRATION_LIMIT`` of the object's size | :class:`PhysicsWarning` after ``run`` | ``Trajectory.penetration`` |
| a start that deep inside a plane | :class:`PhysicsWarning` from the constructor or ``set_state`` | ``Trajectory.penetration[0]`` |

Why: a non-finite energy leaves nothing to continue from, so it stops the run.
Inversion and deep penetration leave a finite, continuable state (SNH recovers from
inversion; the body is pushed back out), so the run goes on, the frames say where it
happened, and the warning says that it did; ``Trajectory.valid`` marks the frames
inside the valid range, e.g. to keep invalid runs out of a training set. A start
inside a plane is usually a placement mistake, but the scene can still be simulated
(the body is thrown out), so it warns at once instead of refusing.

Both are checked after every step, not only at the recorded frames: each frame's
``min_det_f`` and ``penetration`` are the worst of its own state and of the steps since
the previous frame (a run recorded every 100 steps still sees what happened between). The
full simulation measures every step on its device; the reduced ones keep the values of
the evaluation at each step's accepted iterate, where their native solver forms every
cubature point's F and every contact point's gap anyway (the last correction of a step,
below the solver's tolerance, is not evaluated again), at the contact points; the
recorded frames are measured at every vertex.

Elements are the tets for the full simulation and the cubature points for the
reduced ones (where the reduced model evaluates its material); penetration is
measured at every vertex (an inverted body can sink with its inside), against
every plane.
"""

from __future__ import annotations

import warnings

import numpy as np

from .errors import PhysicsWarning

__all__ = [
    "PENETRATION_LIMIT",
    "PhysicsWarning",
    "check_start",
    "cubature_min_det",
    "determinants",
    "penetration",
    "tet_determinants",
    "warn_frames",
    "with_steps",
]

PENETRATION_LIMIT = 0.1
"""Deepest penetration of a contact point into a plane still in the valid range, as a
fraction of the object's size (its bounding-box diagonal, ``Mesh.size``). Penalty
contact at rest sinks by ``weight / (k_n area)``, typically far less than 1 %."""


def determinants(f: np.ndarray) -> np.ndarray:
    """``det F`` of (..., 9) row-major deformation gradients."""
    a, b, c, d, e, g, h, i, j = np.moveaxis(f, -1, 0)
    return a * (e * j - g * i) - b * (d * j - g * h) + c * (d * i - e * h)


def cubature_min_det(jacobians: np.ndarray, qs: np.ndarray) -> np.ndarray:
    """(f,) smallest ``det(I + G_k q)`` over the (K, 9, k) cubature Jacobians ``G`` for
    each of the (f, k) coordinates ``qs``; empty without cubature points."""
    if not len(jacobians):
        return np.zeros(0)
    points, _, k = jacobians.shape
    # one matrix product (BLAS): einsum's loop took 0.3 ms a step of a 1500-step run at r = 120 and 760 tets
    f = (qs @ jacobians.reshape(points * 9, k).T).reshape(len(qs), points, 9) + np.eye(3).reshape(9)
    return determinants(f).min(axis=1)


def tet_determinants(rest_shape_inverses: np.ndarray, tets: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """(m,) ``det F`` of each tet at (n, 3) ``positions`` (``F = Ds Dm^-1``)."""
    x = positions[tets]
    ds = np.stack([x[:, 1] - x[:, 0], x[:, 2] - x[:, 0], x[:, 3] - x[:, 0]], axis=2)
    return determinants((ds @ rest_shape_inverses).reshape(-1, 9))


CONTACT_TOLERANCE = 0.005
"""A vertex touches a plane when its gap is below this fraction of the object's size."""


TOUCH_BLOCK = 32
"""Frames :func:`first_touch` tests at once."""


def first_touch(positions: np.ndarray, planes: np.ndarray, tolerance: float) -> int | None:
    """First of (f, n, 3) frame positions where a vertex is within ``tolerance`` (m) of one of the
    (P, 5) ``planes``; None when none is, or there are no planes."""
    if not len(planes):
        return None
    # Block by block from the start: a run touches early, and at 100k vertices a pass over every frame of a
    # 2000-step run took 1.5 s (docs/results.md section 46).
    for first in range(0, len(positions), TOUCH_BLOCK):
        block = np.asarray(positions[first:first + TOUCH_BLOCK])
        touching = (block @ planes[:, :3].T + planes[:, 3] < tolerance).any(axis=(1, 2))
        if touching.any():
            return first + int(np.argmax(touching))
    return None


def penetration(points: np.ndarray, planes: np.ndarray) -> float:
    """Deepest penetration (m, >= 0) of (c, 3) ``points`` into the (P, 5) ``planes``
    ``[nx, ny, nz, offset, friction]``; zero without planes or points."""
    if not len(planes) or not len(points):
        return 0.0
    gaps = points @ planes[:, :3].T + planes[:, 3]
    return max(-float(gaps.min()), 0.0)


def check_start(points: np.ndarray, planes: np.ndarray, size: float, what: str) -> None:
    """Warn (:class:`PhysicsWarning`) when (n, 3) vertex ``points`` start deeper than
    ``PENETRATION_LIMIT * size`` inside a plane."""
    depth = penetration(points, planes)
    if depth > PENETRATION_LIMIT * size:
        warnings.warn(
            f"{what} starts {depth:.4g} m inside a plane ({100 * depth / size:.3g} % of the object's size "
            f"{size:.4g} m, more than {100 * PENETRATION_LIMIT:.0f} %): the penalty contact will throw it out; "
            "place it on or above the planes (licrom.scene.placement)",
            PhysicsWarning,
            stacklevel=3,
        )


def with_steps(min_det_f: np.ndarray, depth: np.ndarray, between: list[tuple[float, float]]) -> tuple[np.ndarray, np.ndarray]:
    """Each frame's (f,) ``min_det_f`` and ``depth`` combined with the worst of the steps since
    the previous frame (``RunRecord.between``): a frame is out of range when a state after the
    previous frame was. An empty ``min_det_f`` (no elements) stays empty."""
    steps = np.array(between, dtype=np.float64).reshape(-1, 2)
    det = np.minimum(min_det_f, steps[:, 0]) if len(min_det_f) else min_det_f
    return det, np.maximum(depth, steps[:, 1])


def warn_frames(times: np.ndarray, min_det_f: np.ndarray, depth: np.ndarray, size: float, what: str,
                trailing: tuple[float, float] = (np.inf, 0.0), stacklevel: int = 3) -> None:
    """Warn (:class:`PhysicsWarning`) about the frames after the first with inverted
    elements or penetration deeper than ``PENETRATION_LIMIT * size`` (an empty
    ``min_det_f`` is not checked), and about ``trailing`` ``(min det F, depth)``: the
    steps after the last frame. ``stacklevel`` as in :func:`warnings.warn` (3: the caller's caller)."""
    limit = PENETRATION_LIMIT * size
    for bad, late, message in (
        (min_det_f[1:] <= 0.0, len(min_det_f) > 0 and trailing[0] <= 0.0,
         f"inverted elements (min det F = {min(min_det_f.min(initial=np.inf), trailing[0]):.3g})"),
        (depth[1:] > limit, trailing[1] > limit,
         f"penetration up to {max(depth.max(), trailing[1]):.4g} m ({100 * max(depth.max(), trailing[1]) / size:.3g} % of the "
         f"object's size, limit {100 * PENETRATION_LIMIT:.0f} %)"),
    ):
        parts = [f"in {int(bad.sum())} of {len(bad)} frames (or the steps before them), first at t = {float(times[1:][bad][0]):.4g} s"] if bad.any() else []
        parts += [f"in the steps after the last frame (t > {float(times[-1]):.4g} s)"] if late else []
        if parts:
            where = " and ".join(parts)
            warnings.warn(
                f"{what} left the valid range of its physics: {message} {where}; a smaller dt, a stiffer material or "
                "stiffer contact keeps it in range (see Trajectory.min_det_f, Trajectory.penetration)",
                PhysicsWarning,
                stacklevel=stacklevel,
            )
