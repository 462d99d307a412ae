"""Reduced simulation in the body frame: rigid motion exact, learned modes in the body.

Positions are ``x_v = c + R (Xbar_v + W_v q)`` with ``Xbar = X - X_com``, ``c`` the
centre of mass, ``R`` a rotation and ``W`` body-frame modes that carry no linear
or angular momentum (every column mass-orthogonal to the six rigid modes). The
rigid motion is then exact and nonlinear, so one set of modes serves every
orientation of the body (see docs/design.md, "Reduced model in the body frame").

:class:`BodyFrameBasis` builds such modes on a mesh: the 6 symmetric affine modes
``S Xbar`` plus learned modes, orthogonalised against the rigid modes.
:class:`BodyFrameSim` prepares the mass moments, cubature Jacobians and contact
rows once and steps ``licrom._core.BodyFrameCore``, with the user API of
:class:`licrom.reduced.base.ReducedSim`.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from .. import _core
from .._blas import blas_threads, numpy_blas_threads
from ..errors import ConfigError
from ..geometry.mesh import Mesh
from ..records.trajectory import DeferredFrames, Trajectory
from ..rigid import center_of_mass, rigid_fit
from ..scene.scene import Scene
from ..stepping import record_run
from ..subspace.basis import Basis, ModalNorm, SubspaceProjector, check_basis, check_basis_output, strain_jacobians, weighted_gram
from ..subspace.body_basis import BodyFrameBasis, rigid_momenta
from ..subspace.cubature import ContactPoints, Cubature
from ..validity import check_start
from .base import ReducedSim, _fitted_cubature, mesh_and_scene, native_inputs, sampling, warn_off_resolution
from .cubature_error import CubatureError
from .error_estimate import ErrorMonitor, residual_stride

__all__ = ["BodyFrameSim"]

# Relative size of the linear and angular momentum a mode may carry on the mesh
# (round-off of the orthogonalisation on large meshes stays far below).
_ORTHOGONALITY = 1e-8
_KEPT_SHAPES = 4  # body shapes kept by q: BDF2 velocities read three poses, plus the next frame's
_FRAME_BLOCK = 64  # recorded frames whose body shapes are rebuilt in one matrix product (_RecordedFrames)

_Pose = tuple[np.ndarray, np.ndarray, np.ndarray]
"""``(c, R, q)``: centre of mass, rotation and modal coordinates."""


def _difference(x: Sequence[np.ndarray], dt: float, bdf2: bool) -> np.ndarray:
    """The integrator's velocity from positions now and one (backward Euler) or two (BDF2) steps back (``x[k]``: k steps back)."""
    if bdf2:
        return (1.5 * x[0] - 2.0 * x[1] + 0.5 * x[2]) / dt
    return (x[0] - x[1]) / dt


class _RecordedFrames:
    """The frames of a run recorded as poses (:meth:`BodyFrameSim._poses`), rebuilt in full space block by block.

    The run reads each frame's positions once, a block at a time (penetration at every vertex, the first touch);
    its trajectory's displacements and velocities are built when first read
    (:class:`~licrom.records.trajectory.DeferredFrames`): most readers read none, and on 104k tets and 2000 frames the
    positions alone took 1.9 s where the frames took 7.9 s (writing 2 x 1 GB and three poses a frame). Both rebuild a
    block's shapes with the same matrix product, so they read the same positions bit for bit. This keeps what the
    rebuild reads (the poses and the mode values), not the simulation: a later step or ``set_state`` leaves the frames.

    Args:
        poses: each frame's poses, now first and then the steps back that its velocity reads.
        values: (n, 3, r) body-frame mode values.
        xbar: (n, 3) body-frame rest positions.
        vertices: (n, 3) rest positions.
        dt: the time step, s.
        bdf2: whether the velocities are BDF2's difference (else backward Euler's).
    """

    def __init__(self, poses: Sequence[Sequence[_Pose]], values: np.ndarray, xbar: np.ndarray, vertices: np.ndarray, dt: float,
                 bdf2: bool) -> None:
        self.poses = poses
        self.modes = values.reshape(-1, values.shape[2]).T
        self.xbar, self.vertices = xbar, vertices
        self.dt, self.bdf2 = dt, bdf2
        # Fixed now, so that the frames built later split and multiply as the positions read by the run: OpenBLAS
        # rounds a product differently with another thread count.
        self.block, self.threads = _FRAME_BLOCK, numpy_blas_threads()

    def _shapes(self, block: Sequence[Sequence[_Pose]]) -> Callable[[np.ndarray], np.ndarray]:
        """The body shape ``Xbar + W q`` of each q in ``block``'s poses, by q.

        The distinct q of the block are reconstructed in one matrix product: on a 100k-tet mesh a shape reads
        all n x 3 x r mode values, and one product over a block reads them once where one per frame reads them
        every frame (measured: docs/results.md section 13); the blocks bound the shapes held at once.
        """
        index: dict[bytes, int] = {}
        for frame in block:
            for _, _, q in frame:
                index.setdefault(np.ascontiguousarray(q, dtype=np.float64).tobytes(), len(index))
        qs = np.frombuffer(b"".join(index), dtype=np.float64).reshape(len(index), -1)
        shapes = self.xbar + (qs @ self.modes).reshape(len(index), *self.xbar.shape)
        return lambda q: shapes[index[np.ascontiguousarray(q, dtype=np.float64).tobytes()]]

    def _blocks(self) -> Iterator[tuple[int, Callable[[np.ndarray], np.ndarray]]]:
        """Each block's first frame and the shapes of its poses (:meth:`_shapes`), in turn."""
        for first in range(0, len(self.poses), self.block):
            yield first, self._shapes(self.poses[first:first + self.block])

    def positions(self) -> Iterator[np.ndarray]:
        """(B, n, 3) positions of each block's frames in turn."""
        for first, shape in self._blocks():
            yield np.array([c + shape(q) @ r.T for (c, r, q), *_ in self.poses[first:first + self.block]])

    def build(self) -> tuple[np.ndarray, np.ndarray]:
        """(F, n, 3) displacements and velocities of every frame, as its trajectory reads them."""
        displacements = np.empty((len(self.poses), *self.xbar.shape))
        velocities = np.empty_like(displacements)
        with blas_threads(self.threads):
            for first, shape in self._blocks():
                for f, frame in enumerate(self.poses[first:first + self.block], start=first):
                    x = [c + shape(q) @ r.T for c, r, q in frame]
                    displacements[f] = x[0] - self.vertices
                    velocities[f] = _difference(x, self.dt, self.bdf2)
        return displacements, velocities


class BodyFrameSim(ReducedSim):
    """Simulate a solid as a rigid frame plus body-frame modes.

    The user API is that of :class:`licrom.reduced.world.WorldFrameSim`: ``step``, ``run``,
    ``positions``, ``velocities``, ``set_state``, ``contact_forces``, ``transfer``,
    ``step_many``, plus the pose ``center``, ``rotation`` and ``q``; threads are used as there.

    Args:
        basis: body-frame modes (a :class:`BodyFrameBasis`, or any basis whose
            columns carry no linear or angular momentum on ``mesh``).
        mesh: the mesh to simulate (default: the basis' mesh).
        scene: the scene (default: the learned model's default scene).
        cubature: cubature tets and weights, or a name (default: as ReducedSim, the learned
            model's fitted cubature).
        contact_points: where contact acts (default: :meth:`ContactPoints.default`, every boundary vertex up to
            :data:`~licrom.subspace.cubature.DEFAULT_CONTACT_POINTS`, a farthest-point subset of that many above).
        strain: ``"mesh"`` (default) or ``"field"``, as in ReducedSim
            (:func:`licrom.subspace.basis.strain_jacobians`).

    Raises:
        ConfigError: missing mesh/scene, modes that carry momentum, singular modal mass, unknown strain.
        ShapeError: the basis returns arrays of the wrong shape or with NaN/inf.
    """

    def __init__(
        self,
        basis: Basis,
        mesh: Mesh | None = None,
        scene: Scene | None = None,
        cubature: Cubature | str | None = None,
        contact_points: ContactPoints | None = None,
        strain: str = "mesh",
    ) -> None:
        check_basis(basis)
        mesh, scene = mesh_and_scene("BodyFrameSim", mesh, scene, basis, "a basis", (basis, getattr(basis, "learned", None)))
        self.basis, self.mesh, self.scene = basis, mesh, scene
        self.cubature, self.contact_points = sampling(mesh, cubature, contact_points, basis)
        k = int(basis.n_modes)
        n = mesh.n_vertices
        self._masses = mesh.vertex_masses(scene.material.density)
        total = float(self._masses.sum())
        self._xbar = mesh.vertices - center_of_mass(mesh.vertices, self._masses)
        self._values = check_basis_output("values", basis.values(mesh.vertices), (n, 3, k))
        t, w = rigid_momenta(self._values, self._xbar, self._masses)
        size = np.sqrt(self._masses @ np.einsum("vik,vik->v", self._values, self._values) / (total * max(k, 1)))
        if k and max(np.abs(t).max(), np.abs(w).max() * mesh.size) > _ORTHOGONALITY * max(size, 1e-300):
            raise ConfigError(
                "the modes carry linear or angular momentum on this mesh: wrap the basis in "
                "BodyFrameBasis(mesh, learned=basis) to orthogonalise it against the rigid modes"
            )
        self.strain = strain
        jac = check_basis_output("jacobians", strain_jacobians(basis, mesh, self.cubature.tets, strain, self._values), (self.cubature.count, 3, 3, k))
        self._jacobians = np.ascontiguousarray(jac.reshape(self.cubature.count, 9, k))
        a = self._values.reshape(n, 3 * k)
        products = weighted_gram(a, self._masses).reshape(3, k, 3, k).transpose(1, 3, 0, 2)
        self._modal_mass = np.einsum("klii->kl", products)
        self._modal_norm = ModalNorm(self._modal_mass)  # |u|_M^2 of the non-rigid deformation at q, for the error estimate
        self._projector = SubspaceProjector(self._values, self._masses, reduced_mass=self._modal_mass) if k else None
        self._core = _core.BodyFrameCore(
            total_mass=total,
            inertia_moments=np.einsum("v,vi,vj->ij", self._masses, self._xbar, self._xbar),
            mode_moments=np.ascontiguousarray((a.T @ (self._masses[:, None] * self._xbar)).reshape(3, k, 3).transpose(1, 0, 2)),
            mode_products=np.ascontiguousarray(products),
            gravity=np.asarray(scene.gravity, dtype=np.float64),
            **native_inputs(self, strain, self._xbar),
        )
        self._body = _core.Reconstruction(self._values, self._xbar) if k else None
        self._shapes: dict[bytes, np.ndarray] = {}
        self._monitor = ErrorMonitor(mesh, self._values, self._xbar, scene, stride=residual_stride(self.cubature.count, k),
                                     cubature_error=CubatureError(mesh, self._values, self._xbar, scene, self.cubature,
                                                                   self._jacobians if strain == "field" else None, self._modal_mass))
        warn_off_resolution(basis, mesh, "the body-frame simulation")
        self.time = 0.0
        self.set_state(*scene.initial.apply(mesh.vertices, self._masses))

    # --- state -------------------------------------------------------------------------
    @property
    def center(self) -> np.ndarray:
        """(3,) centre of mass, m."""
        return self._core.center

    @property
    def rotation(self) -> np.ndarray:
        """(3, 3) rotation from the body frame to the world."""
        return self._core.rotation

    @property
    def velocity(self) -> np.ndarray:
        """(3,) velocity of the centre of mass, m/s."""
        return self._core.velocity

    @property
    def angular_velocity(self) -> np.ndarray:
        """(3,) angular velocity in the world frame, rad/s."""
        return self._core.angular_velocity

    def _body_points(self, q: np.ndarray) -> np.ndarray:
        """(n, 3) body-frame shape ``Xbar + W q`` (read-only).

        The last few shapes are kept by ``q``: positions and velocities read between steps read the
        current pose and the one or two before it, which the reads before already reconstructed,
        and a reconstruction reads all n x 3 x r mode values (on 100k tets, more than the step).
        """
        if self._body is None:
            return self._xbar
        key = np.ascontiguousarray(q, dtype=np.float64).tobytes()
        shape = self._shapes.pop(key, None)
        if shape is None:
            shape = self._body.positions(q)
            shape.setflags(write=False)
        self._shapes[key] = shape
        while len(self._shapes) > _KEPT_SHAPES:
            del self._shapes[next(iter(self._shapes))]
        return shape

    @property
    def positions(self) -> np.ndarray:
        """(n, 3) vertex positions ``c + R (Xbar + W q)`` in m."""
        return self.center + self._body_points(self.q) @ self.rotation.T

    def _previous_positions(self, steps_back: int = 1) -> np.ndarray:
        """(n, 3) positions of the pose ``steps_back`` (1-3) steps before the current one, which the
        next step reads (after :meth:`set_state`: ``(c - k h v, exp(-k h [w]x) R, q - k h q_dot)``)."""
        c, r, q = self._core.previous_pose(steps_back)
        return c + self._body_points(q) @ r.T

    @property
    def velocities(self) -> np.ndarray:
        """(n, 3) vertex velocities in m/s: the integrator's backward difference of the vertex
        positions, as in :class:`licrom.FullSim`: ``(x - x_prev) / h`` for backward Euler,
        ``(3 x - 4 x_prev + x_prev2) / (2h)`` for BDF2 (for a spinning body the continuous
        ``v + w x R y`` differs from it by about ``h |w|^2 |R y| / 2``)."""
        x = [self.positions] + [self._previous_positions(k) for k in range(1, self._steps_back + 1)]
        return _difference(x, self.scene.dt, self.scene.integrator == "bdf2")

    @property
    def _steps_back(self) -> int:
        """Poses before the current one that a velocity reads (backward Euler 1, BDF2 2)."""
        return 2 if self.scene.integrator == "bdf2" else 1

    def _poses(self) -> list[_Pose]:
        """``(c, R, q)`` now and :attr:`_steps_back` steps back: what a recorded frame's positions and velocities read."""
        return [(self.center, self.rotation, self.q)] + [self._core.previous_pose(k) for k in range(1, self._steps_back + 1)]

    def _project(self, field: np.ndarray) -> np.ndarray:
        return np.zeros(0) if self._projector is None else self._projector.project(field)

    def _pose_of(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(c, R, q)`` of positions x: the best rigid fit and the least squares of the body-frame rest."""
        c, r = rigid_fit(x, self.mesh.vertices, self._masses)
        return c, r, self._project((x - c) @ r - self._xbar)

    def set_state(self, positions: np.ndarray | None = None, velocities: np.ndarray | None = None) -> None:
        """Set the state from full-space positions/velocities (either may be omitted).

        ``c`` is the centre of mass, ``R`` the rotation of the best rigid fit, ``q`` the
        mass-weighted least squares of the body-frame displacement. The velocities are
        read as backward Euler reads them, as the difference to the previous positions
        ``x - h v`` (:class:`licrom.FullSim` predicts the step from ``x + h v``): the
        previous pose is fitted to those the same way, and ``(v, w, q_dot)`` are the pose
        differences over h. With BDF2 the poses one to three steps back are fitted to the
        full simulation's start history, ``x - k h v + (k h)^2 g / 2``. (Read as the continuous ``v + w x R y``, a body spinning at
        ``|w|`` would start its first step ``h^2 |w|^2 |R y| / 2`` off the full solver's:
        0.4 mm for a box spinning at 12 rad/s with h = 10 ms, four times the 0.1 mm of the
        noise floor of docs/results.md.) Warns
        (:class:`~licrom.errors.PhysicsWarning`) when the state puts a vertex deeper inside
        a plane than ``licrom.validity.PENETRATION_LIMIT`` of the object's size.
        """
        x = self.positions if positions is None else self._check_field("positions", positions)
        vel = self.velocities if velocities is None else self._check_field("velocities", velocities)
        c, r, q = self._pose_of(x)
        h = self.scene.dt
        c0, r0, q0 = self._pose_of(x - h * vel)
        w = Rotation.from_matrix(r @ r0.T).as_rotvec() / h
        self._core.set_state(c, r, q, (c - c0) / h, w, (q - q0) / h)
        if self.scene.integrator == "bdf2":
            # BDF2 reads three poses back: those fitted to the full simulation's start, the free fall
            # x - k h v + (k h)^2 g / 2 (rust/core/src/integrator.rs), as the first is fitted to x - h v.
            g = np.asarray(self.scene.gravity)
            earlier = [self._pose_of(x - k * h * vel + 0.5 * (k * h) ** 2 * g) for k in (1, 2, 3)]
            self._core.set_history(*(np.array(part) for part in zip(*earlier)))
        if positions is not None:
            check_start(self.positions, self.scene.plane_array(), self.mesh.size, "the body-frame simulation")

    # --- stepping ----------------------------------------------------------------------
    def run(self, steps: int, record_every: int = 1, progress: bool = False) -> Trajectory:
        """Step ``steps`` times and record every ``record_every``-th state (frame 0 is now).

        With ``scene.solver.on_failure == "record"``, a step that does not converge is
        recorded as unconverged and the run continues from the last iterate. Each frame's
        smallest ``det F`` at the cubature points and deepest penetration of a vertex into
        a plane are recorded, with a :class:`~licrom.errors.PhysicsWarning` where they leave
        the valid range (:mod:`licrom.validity`).
        """
        monitor = self._monitor
        history = [self._previous_positions(k) for k in range(monitor.history_length - 1, 0, -1)] + [self.positions]
        monitor.start([x[monitor.vertices] for x in history], steps)

        def step() -> tuple[int, float, bool]:
            outcome = self.step_or_record()
            monitor.after_step(lambda: (self.q, self.center, self.rotation), self._modal_norm)
            return outcome

        rec = record_run(step, self._poses, lambda: self.time, steps, record_every, progress, "body frame", self._core.validity)
        monitor.finish(self.q, self._modal_norm)
        frames = _RecordedFrames(rec.frames, self._values, self._xbar, self.mesh.vertices, self.scene.dt, self.scene.integrator == "bdf2")
        deferred = DeferredFrames((len(rec.frames), self.mesh.n_vertices, 3), frames.build)
        return self._trajectory(rec, frames.positions(), deferred, deferred, np.array([frame[0][2] for frame in rec.frames]),
                                record_every, "the body-frame simulation", {"frame": "body", "solver": "newton"})

    # --- other meshes ------------------------------------------------------------------
    def transfer(self, mesh: Mesh, cubature: Cubature | None = None, contact_points: ContactPoints | None = None) -> BodyFrameSim:
        """The same state on another mesh of the same object.

        The new simulation has the new mesh's own ``Xbar`` and ``W`` (a
        :class:`BodyFrameBasis` is orthogonalised again on it); ``c``, ``R``, ``q``,
        ``v``, ``w`` and ``q_dot`` carry over (cubature: the learned model's fitted one refitted
        on ``mesh``, else the naive scheme with as many points as this one, unless given).
        """
        basis = self.basis.on(mesh) if isinstance(self.basis, BodyFrameBasis) else self.basis
        if cubature is None:
            cubature = _fitted_cubature(basis, mesh) or Cubature.naive(mesh, max(self.cubature.count, 1))
        other = BodyFrameSim(basis, mesh, self.scene, cubature=cubature, contact_points=contact_points, strain=self.strain)
        other._core.set_state(self.center, self.rotation, self.q, self.velocity, self.angular_velocity, self.qdot)
        other.time = self.time
        return other
