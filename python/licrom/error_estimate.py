"""Online error estimate of a reduced run: how far its state is from the full equations.

A reduced simulation satisfies the backward-Euler equations only inside its subspace. At a
small fixed sample of vertices, the full-space residual of the reconstructed state

    ``r_v = m_v (x_t - 2 x_{t-1} + x_{t-2}) / h^2 - m_v g - f_v(x_t)``

(inertia, gravity, elastic force of the vertex's one-ring tets; contact acts only on a
vertex inside a plane, and such a sample is left out of that frame) is zero for the full
solution. Divided by the vertex's own stiffness block (block Jacobi,
``K_vv = m_v / h^2 I + linear-elastic K_vv at rest``) it becomes a displacement,
``du_v = K_vv^-1 r_v``: the correction one full-space Jacobi sweep would make there. The
estimate compares it with the body's non-rigid deformation ``u`` (its body-frame
displacement) the way :func:`licrom.compare.nonrigid_error` compares the reduced run with
the full one, from the run's first contact on:

    ``e(t) = ERROR_SCALE * sqrt(sum_{s<=t} M/M_S sum_v m_v |du_v(s)|^2 / sum_{s<=t} |u(s)|_M^2)``

(``M/M_S``: total mass over the sample's, so the sample stands for the body). It is
recorded per frame in ``Trajectory.error_estimate``, and its last value is the run-level
estimate; an :class:`~licrom.errors.AccuracyWarning` is issued once when it passes
:data:`ERROR_THRESHOLD`.

Why a residual at vertices outside the solve: the reduced solver's own residual is zero by
construction (it is projected onto the subspace); the full-space residual sees what the
subspace cannot represent. The sample is spread over the body by farthest-point sampling,
interior vertices first (no contact force to model); its basis rows, one-ring shape
gradients and volumes are taken once, so a frame costs a few small numpy calls.
"""

from __future__ import annotations

import warnings
from collections import deque

import numpy as np

from . import _core
from .compare import CONTACT_TOLERANCE
from .errors import AccuracyWarning, ConfigError
from .mesh import Mesh
from .scene import Scene

__all__ = ["ERROR_SCALE", "ERROR_THRESHOLD", "SAMPLE_COUNT", "ErrorMonitor", "running_estimate", "warn_estimate"]

SAMPLE_COUNT = 32
"""Vertices where the residual is evaluated."""

ERROR_SCALE = 1.0
"""Factor from the Jacobi displacement ratio to the non-rigid error (dimensionless)."""

ERROR_THRESHOLD = 0.15
"""Run-level estimate above which :class:`~licrom.errors.AccuracyWarning` is issued (dimensionless)."""


def _farthest_points(points: np.ndarray, count: int) -> np.ndarray:
    """Indices of ``count`` well-spread rows of (p, 3) ``points``, from the one nearest their centroid."""
    chosen = [int(np.argmin(np.linalg.norm(points - points.mean(axis=0), axis=1)))]
    dist = np.linalg.norm(points - points[chosen[0]], axis=1)
    for _ in range(count - 1):
        nxt = int(np.argmax(dist))
        chosen.append(nxt)
        dist = np.minimum(dist, np.linalg.norm(points - points[nxt], axis=1))
    return np.array(chosen)


def sample_vertices(mesh: Mesh, count: int) -> np.ndarray:
    """(s,) well-spread vertices: interior ones first, boundary ones where there are too few."""
    boundary = np.zeros(mesh.n_vertices, dtype=bool)
    boundary[mesh.boundary_vertices] = True
    interior = np.flatnonzero(~boundary)
    if len(interior) >= count:
        return np.sort(interior[_farthest_points(mesh.vertices[interior], count)])
    outside = np.flatnonzero(boundary)
    extra = outside[_farthest_points(mesh.vertices[outside], min(count - len(interior), len(outside)))]
    return np.sort(np.concatenate([interior, extra]))


class ErrorMonitor:
    """The full-space residual at a fixed vertex sample of a reduced simulation.

    Positions of the sample are ``x = c + R (rest + W q)`` (world-frame models: ``c = 0``,
    ``R = I``, ``rest = X``; body-frame models: ``rest = Xbar``).

    Args:
        mesh: the simulated mesh.
        values: (n, 3, k) basis values at every vertex.
        rest: (n, 3) the rest term of the positions (``X`` or ``Xbar``), m.
        scene: the scene (material, gravity, dt, planes).
        count: sample size (all vertices on meshes with fewer).

    Attributes:
        vertices: (s,) the sample vertices.
        near: (u,) the corners of their one-ring tets (the samples included).
        masses: (n,) lumped vertex masses, kg.

    Raises:
        ConfigError: ``count`` not an integer >= 1.
    """

    def __init__(self, mesh: Mesh, values: np.ndarray, rest: np.ndarray, scene: Scene, count: int = SAMPLE_COUNT) -> None:
        if isinstance(count, bool) or not isinstance(count, (int, np.integer)) or count < 1:
            raise ConfigError(f"the error estimate's sample count must be an integer >= 1, got {count!r}")
        self.vertices = sample_vertices(mesh, min(int(count), mesh.n_vertices))
        k = values.shape[2]
        tets = mesh.tets
        rings = [np.flatnonzero((tets == v).any(axis=1)) for v in self.vertices]
        width = max(len(r) for r in rings)
        # Rings padded to one width with a zero-volume copy of their first tet: one einsum per quantity.
        ring = np.array([np.pad(r, (0, width - len(r)), mode="edge") for r in rings])
        volumes = np.where(np.arange(width)[None] < np.array([len(r) for r in rings])[:, None], mesh.rest_volumes[ring], 0.0)
        self.near, local = np.unique(np.concatenate([tets[ring].ravel(), self.vertices]), return_inverse=True)
        self._local = local[: ring.size * 4].reshape(len(self.vertices), width, 4)
        self._own = local[ring.size * 4:]
        grads = mesh.shape_gradients[ring]  # (s, w, 4, 3)
        corner = (tets[ring] == self.vertices[:, None, None]).argmax(axis=2)  # the sample's corner in each ring tet
        own_grad = np.take_along_axis(grads, corner[..., None, None], axis=2)[:, :, 0]
        self._grads = np.ascontiguousarray(grads)
        self._force_rows = -volumes[..., None] * own_grad  # f_v = sum_t P_t (-V_t grad_v)
        self._basis = np.ascontiguousarray(values[self.near].reshape(3 * len(self.near), k))
        self._rest = np.ascontiguousarray(rest[self.near])
        self._sample_basis = np.ascontiguousarray(values[self.vertices].reshape(3 * len(self.vertices), k))
        self._sample_rest = np.ascontiguousarray(rest[self.vertices])
        self.masses = mesh.vertex_masses(scene.material.density)
        self._m = self.masses[self.vertices]
        self._mass_ratio = float(self.masses.sum())
        h = scene.dt
        mu, lam = scene.material.lame
        gg = np.einsum("swi,swj->swij", own_grad, own_grad)
        stiffness = np.einsum("sw,swij->sij", volumes, mu * np.einsum("swkk->sw", gg)[..., None, None] * np.eye(3) + (mu + lam) * gg)
        self._jacobi = np.linalg.inv(stiffness + (self._m / h**2)[:, None, None] * np.eye(3))
        self._snh = scene.material.snh_parameters
        self._h2 = h * h
        self._weight = np.asarray(scene.gravity, dtype=np.float64) * self._m[:, None]
        planes = scene.plane_array()
        self._normals, self._offsets = planes[:, :3], planes[:, 3]
        self._tolerance = CONTACT_TOLERANCE * mesh.size
        self._history: deque[np.ndarray] = deque(maxlen=3)

    def sample_positions(self, q: np.ndarray, center: np.ndarray | None = None, rotation: np.ndarray | None = None) -> np.ndarray:
        """(s, 3) world positions of the sample vertices, m."""
        y = self._sample_rest + (self._sample_basis @ q).reshape(-1, 3)
        return y if rotation is None else center + y @ rotation.T

    def start(self, previous: np.ndarray, current: np.ndarray) -> None:
        """Begin a run from the sample positions of the previous and the current state."""
        self._history.clear()
        self._history.extend((previous, current))

    def observe(self, positions: np.ndarray) -> None:
        """Record the sample positions after a step."""
        self._history.append(positions)

    def elastic_forces(self, near_positions: np.ndarray) -> np.ndarray:
        """(s, 3) elastic force ``-dE/dx_v`` on each sample vertex, N, from (u, 3) positions of
        the vertices ``near`` (the samples' one-ring tets' corners)."""
        f = np.einsum("swai,swaj->swij", near_positions[self._local], self._grads)
        stress = _core.snh_pk1(f.reshape(-1, 3, 3), *self._snh).reshape(f.shape)
        return np.einsum("swij,swj->si", stress, self._force_rows)

    def weighted_error(self, q: np.ndarray, center: np.ndarray | None = None, rotation: np.ndarray | None = None) -> float:
        """``M/M_S sum_v m_v |du_v|^2`` (kg m^2) of the state just observed, over the samples outside every plane.

        Zero before the first step of a run (no acceleration to measure yet).
        """
        if len(self._history) < 3:
            return 0.0
        y = self._rest + (self._basis @ q).reshape(-1, 3)
        x = y if rotation is None else center + y @ rotation.T
        now = x[self._own]
        earlier, before = self._history[0], self._history[1]
        residual = self._m[:, None] * (now - 2.0 * before + earlier) / self._h2 - self._weight - self.elastic_forces(x)
        du = np.einsum("sij,sj->si", self._jacobi, residual)
        # A sample inside a plane now or at the start of the step (lagged friction) feels contact: left out.
        free = (np.minimum(now @ self._normals.T, before @ self._normals.T) + self._offsets >= 0.0).all(axis=1)
        m = self._m * free
        total = m.sum()
        return float(self._mass_ratio * np.einsum("s,si,si->", m, du, du) / total) if total > 0 else 0.0

    def contact_start(self, positions: np.ndarray) -> int | None:
        """First of (f, n, 3) frame positions where a vertex touches a plane (gap below
        ``licrom.compare.CONTACT_TOLERANCE`` of the size); None if none does."""
        if not len(self._offsets):
            return None
        touching = (np.einsum("fni,pi->fnp", positions, self._normals) + self._offsets < self._tolerance).any(axis=(1, 2))
        return int(np.argmax(touching)) if touching.any() else None


def running_estimate(weighted: np.ndarray, deformation: np.ndarray, start: int | None) -> np.ndarray:
    """(f,) running estimate ``ERROR_SCALE * sqrt(cumsum weighted / cumsum deformation)`` from frame ``start``.

    Args:
        weighted: (f,) ``M/M_S sum m |du|^2`` per frame, kg m^2.
        deformation: (f,) ``|u|_M^2`` of the non-rigid deformation per frame, kg m^2.
        start: first frame counted (the first contact); None: every frame.

    Returns:
        Zero before ``start`` and while nothing has deformed.
    """
    out = np.zeros(len(weighted))
    s = 0 if start is None else start
    num, den = np.cumsum(weighted[s:]), np.cumsum(deformation[s:])
    out[s:] = ERROR_SCALE * np.sqrt(np.divide(num, den, out=np.zeros_like(num), where=den > 0))
    return out


def warn_estimate(estimate: np.ndarray, what: str) -> None:
    """Warn (:class:`~licrom.errors.AccuracyWarning`) once when the run-level estimate (the last
    frame's) passes :data:`ERROR_THRESHOLD`."""
    if len(estimate) and estimate[-1] > ERROR_THRESHOLD:
        warnings.warn(
            f"{what}: estimated non-rigid error {100 * estimate[-1]:.3g} % exceeds the threshold "
            f"{100 * ERROR_THRESHOLD:.0f} % (Trajectory.error_estimate, licrom.error_estimate): the subspace "
            "misses this motion; use more modes, or retrain with runs like this scene",
            AccuracyWarning,
            stacklevel=3,
        )
