"""Subspace bases: displacement fields ``u(X) = W(X) q`` evaluated at any rest point.

A *basis* is any object with

- ``n_modes``: the number k of columns of W;
- ``values(points)``: (p, 3) rest points -> (p, 3, k) values of W;
- ``jacobians(points)``: (p, 3) -> (p, 3, 3, k) with ``J[p, i, j, c] = dW_ic/dX_j``,
  so the deformation gradient is ``F = I + sum_c J[..., c] q_c``.

:class:`AffineBasis` holds the 12 affine modes (rigid motion is exact),
:class:`MeshBasis` interpolates per-vertex modes linearly in each tet (POD bases,
the identity basis of a small mesh) and :class:`StackedBasis` concatenates bases,
e.g. affine + learned. A trained :class:`licrom.Model` is one more basis.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from ..errors import ConfigError, ShapeError
from ..geometry.mesh import Mesh, check_points
from .affine import AFFINE_JACOBIAN, N_AFFINE, affine_jacobians, affine_values

__all__ = [
    "AFFINE_JACOBIAN",
    "N_AFFINE",
    "RUN_BALANCE",
    "STRAINS",
    "AffineBasis",
    "Basis",
    "MeshBasis",
    "StackedBasis",
    "SubspaceProjector",
    "affine_jacobians",
    "affine_values",
    "check_basis",
    "check_basis_output",
    "mesh_strain_jacobians",
    "run_balanced_weights",
    "strain_jacobians",
    "vertex_strain_form",
    "weighted_gram",
]


@runtime_checkable
class Basis(Protocol):
    """What the reduced simulation needs of a subspace."""

    n_modes: int

    def values(self, points: np.ndarray) -> np.ndarray: ...

    def jacobians(self, points: np.ndarray) -> np.ndarray: ...


def check_basis(basis: object, what: str = "basis") -> Basis:
    """Return ``basis`` if it satisfies the :class:`Basis` protocol; raise ConfigError naming what it lacks."""
    if not isinstance(basis, Basis):
        missing = [name for name in ("n_modes", "values", "jacobians") if not hasattr(basis, name)]
        raise ConfigError(f"{what} ({type(basis).__name__}) is not a basis: it lacks {', '.join(repr(m) for m in missing)} (see licrom.subspace.basis.Basis)")
    return basis


def check_basis_output(name: str, array: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """Return ``array`` as float64 after checking its shape and finiteness.

    Raises:
        ShapeError: wrong shape, or NaN/inf values.
    """
    a = np.asarray(array, dtype=np.float64)
    if a.shape != shape:
        raise ShapeError(f"basis {name} must have shape {shape}, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ShapeError(f"basis {name} hold NaN or inf ({int((~np.isfinite(a)).sum())} entries)")
    return a


def weighted_gram(a: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """``a^T diag(weights) a`` of (rows, c) ``a`` and non-negative (rows,) ``weights``, by a symmetric rank update:
    half a general product's work (0.25 s at 120k tets and r = 250 for the body-frame mode products), exactly
    symmetric."""
    from scipy.linalg.blas import dsyrk

    if a.shape[1] == 0:
        return np.zeros((0, 0))
    b = np.sqrt(weights)[:, None] * a
    upper = dsyrk(1.0, b.T)  # b.T is Fortran-ordered: no copy; (c, c), its upper triangle
    return upper + np.triu(upper, 1).T


class ModalNorm:
    """``q^T M q`` for a symmetric positive definite reduced mass matrix M whose modes after a few leading ones are
    mass-orthogonal to every other (the body frame's learned modes, after its affine ones): with d one past the last
    mode coupled to another above round-off, ``q[:d]^T M[:d, :d] q[:d] + sum_{i >= d} M_ii q_i^2`` exactly, in
    ``O(d^2 + k)`` (d = k where the coupling is spread: the dense product). Read every few steps by a run's error
    estimate, where the dense product took 63 us at k = 256 (M out of cache after the steps) and this 21 us.

    Args:
        mass: (k, k) the reduced mass matrix.
    """

    ROUND_OFF = 1e-12
    """Off-diagonal entries at most this share of the largest diagonal one count as zero (dimensionless)."""

    def __init__(self, mass: np.ndarray) -> None:
        mass = np.asarray(mass, dtype=np.float64)
        off = np.abs(mass - np.diag(np.diag(mass)))
        coupled = np.flatnonzero(off.max(axis=1, initial=0.0) > self.ROUND_OFF * np.abs(np.diag(mass)).max(initial=0.0))
        self._d = int(coupled[-1]) + 1 if len(coupled) else 0
        self._block = mass[: self._d, : self._d].copy()
        self._diag = np.diag(mass)[self._d :].copy()

    def __call__(self, q: np.ndarray) -> float:
        """``q^T M q`` at the (k,) coordinates ``q``."""
        head, tail = q[: self._d], q[self._d :]
        return float(head @ (self._block @ head) + tail @ (self._diag * tail))


class SubspaceProjector:
    """Mass-weighted projection onto a basis sampled at the vertices of a mesh.

    ``q = M_r^-1 W^T M u`` with ``M_r = W^T M W``: the subspace displacement closest
    to ``u`` in the kinetic-energy norm.

    Args:
        values: (n, 3, k) basis values at the vertices.
        masses: (n,) lumped vertex masses in kg.
        reduced_mass: ``M_r`` (k, k), where the caller has already formed it (None: formed here).

    Raises:
        ConfigError: ``M_r`` is singular (modes linearly dependent on this mesh).
        ShapeError: ``reduced_mass`` is not (k, k).
    """

    def __init__(self, values: np.ndarray, masses: np.ndarray, reduced_mass: np.ndarray | None = None) -> None:
        from scipy.linalg import LinAlgError, cho_factor

        from ..errors import ConfigError

        w = np.asarray(values, dtype=np.float64)
        self._w = w.reshape(-1, w.shape[2])  # (3n, k)
        self._m3 = np.repeat(np.asarray(masses, dtype=np.float64), 3)
        if reduced_mass is None:
            self.reduced_mass = weighted_gram(self._w, self._m3)
        else:
            self.reduced_mass = np.asarray(reduced_mass, dtype=np.float64)
            if self.reduced_mass.shape != (w.shape[2], w.shape[2]):
                raise ShapeError(f"reduced_mass must have shape {(w.shape[2], w.shape[2])}, got {self.reduced_mass.shape}")
        scale = float(np.abs(np.diag(self.reduced_mass)).max())
        try:
            self._factor = cho_factor(self.reduced_mass)
            ok = bool(np.all(np.abs(np.diag(self._factor[0])) > 1e-7 * np.sqrt(scale)))
        except LinAlgError:
            ok = False
        if not ok:
            raise ConfigError(
                "the reduced mass matrix W^T M W is singular: some basis modes are linearly dependent "
                "(or zero) on this mesh; remove duplicate modes or use fewer modes"
            )

    def _flat(self, name: str, field: np.ndarray) -> np.ndarray:
        a = np.asarray(field, dtype=np.float64)
        n = len(self._m3) // 3
        if a.shape[-2:] != (n, 3):
            raise ShapeError(f"{name} must have shape (..., {n}, 3), got {a.shape}")
        return a.reshape(-1, 3 * n)

    def reduce(self, forces: np.ndarray) -> np.ndarray:
        """(..., n, 3) vertex forces -> (..., k) generalized forces ``W^T f``."""
        f = np.asarray(forces)
        return (self._flat("forces", f) @ self._w).reshape(*f.shape[:-2], -1)

    def project(self, displacements: np.ndarray) -> np.ndarray:
        """(..., n, 3) displacements -> (..., k) subspace coordinates."""
        from scipy.linalg import cho_solve

        u = np.asarray(displacements)
        rhs = self._w.T @ (self._m3[:, None] * self._flat("displacements", u).T)
        return cho_solve(self._factor, rhs).T.reshape(*u.shape[:-2], -1)


class AffineBasis:
    """The 12 affine modes ``u(X) = A X + t``; reproduces any rigid motion exactly."""

    n_modes = 12

    def values(self, points: np.ndarray) -> np.ndarray:
        return affine_values(points)

    def jacobians(self, points: np.ndarray) -> np.ndarray:
        return affine_jacobians(points)

    def __repr__(self) -> str:
        return "AffineBasis()"


STRAINS = ("mesh", "field")


def strain_jacobians(basis: Basis, mesh: Mesh, tets: np.ndarray, strain: str = "mesh", values: np.ndarray | None = None) -> np.ndarray:
    """``dF/dq`` of the basis in the given tets of ``mesh``, (p, 3, 3, k).

    Args:
        basis: the subspace.
        mesh: the simulated mesh.
        tets: (p,) tet indices (e.g. the cubature tets).
        strain: ``"mesh"``: the gradient of the basis' values at the vertices interpolated
            linearly in each tet, the deformation gradient of the linear FEM that made the
            training data, so that a basis spanning a run's vertex displacements reproduces
            its elastic forces exactly; ``"field"``: the basis' own ``jacobians`` at the tet
            centroids (LiCROM as published: the continuous field's gradient). The two agree
            for bases linear in each tet (mesh bases, affine modes). A learned field that
            matches POD at the vertices can still wiggle between them: on the soft cheese of
            docs/results.md section 10 (r = 40) its own gradient left 14-26 % non-rigid error
            where the mesh gradient of the same modes left 9-20 %.
        values: the basis' values at the mesh vertices (n, 3, k), when already evaluated.

    Raises:
        ConfigError: unknown ``strain``.
    """
    idx = np.asarray(tets, dtype=np.int64)
    if strain == "field":
        return basis.jacobians(mesh.centroids[idx])
    if strain != "mesh":
        raise ConfigError(f"strain must be one of {', '.join(repr(s) for s in STRAINS)}, got {strain!r}")
    return mesh_strain_jacobians(mesh, idx, basis.values(mesh.vertices) if values is None else values)


def mesh_strain_jacobians(mesh: Mesh, tets: np.ndarray, values: np.ndarray) -> np.ndarray:
    """(p, 3, 3, k) ``dF/dq = sum_a W_{v_a} (x) grad N_a`` in the tets ``tets`` of ``mesh`` from the (n, 3, k) mode
    ``values`` at its vertices: the ``"mesh"`` strain of :func:`strain_jacobians`."""
    idx = np.asarray(tets, dtype=np.int64)
    return np.einsum("paic,paj->pijc", values[mesh.tets[idx]], mesh.shape_gradients[idx])


def vertex_strain_form(mesh: Mesh, tets: np.ndarray, strain: str, values: np.ndarray) -> dict[str, np.ndarray]:
    """The ``"mesh"`` strain of :func:`strain_jacobians` in vertex form, as keyword arguments of the native cores.

    ``dF/dq`` of tet t is ``sum_a W_{v_a} (x) grad N_a`` over its four vertices, so the
    cores can form F from the vertex displacements ``W_v q`` and the gradient from vertex
    forces, which costs less than the 9 x k Jacobian of every cubature tet when the tets
    share their vertices (they check that both forms agree and pick the cheaper).

    Args:
        mesh: the simulated mesh.
        tets: (p,) tet indices (the cubature tets).
        strain: ``"mesh"`` or ``"field"`` (no vertex form: an empty dict).
        values: the basis' values at the mesh vertices (n, 3, k).
    """
    if strain != "mesh" or values.shape[2] == 0:
        return {}
    idx = np.asarray(tets, dtype=np.int64)
    return {
        "cubature_vertex_basis": np.ascontiguousarray(values, dtype=np.float64),
        "cubature_tet_vertices": np.ascontiguousarray(mesh.tets[idx], dtype=np.int64),
        "cubature_shape_gradients": np.ascontiguousarray(mesh.shape_gradients[idx], dtype=np.float64),
    }


class MeshBasis:
    """Per-vertex modes of a mesh, interpolated linearly inside each tet.

    Args:
        mesh: the mesh the modes live on.
        modes: (n_vertices, 3, k) mode values at the vertices.
    """

    def __init__(self, mesh: Mesh, modes: np.ndarray) -> None:
        m = np.asarray(modes, dtype=np.float64)
        if m.ndim != 3 or m.shape[:2] != (mesh.n_vertices, 3) or m.shape[2] < 1:
            raise ShapeError(f"MeshBasis modes must have shape ({mesh.n_vertices}, 3, k) with k >= 1, got {m.shape}")
        if not np.all(np.isfinite(m)):
            raise ShapeError("MeshBasis modes hold NaN or inf")
        self.mesh = mesh
        self.modes = m
        self.n_modes = m.shape[2]

    @classmethod
    def identity(cls, mesh: Mesh) -> MeshBasis:
        """The full-space basis: one mode per vertex coordinate (q is the displacement vector).

        Its size grows as ``9 n^2``: meant for small meshes (tests, reference runs).
        """
        n = mesh.n_vertices
        modes = np.zeros((n, 3, 3 * n))
        idx = np.arange(n)
        for i in range(3):
            modes[idx, i, 3 * idx + i] = 1.0
        return cls(mesh, modes)

    @classmethod
    def pod(cls, mesh: Mesh, displacements: np.ndarray, count: int, density: float = 1.0,
            weights: np.ndarray | None = None) -> tuple[MeshBasis, np.ndarray]:
        """Mass-orthonormal POD modes of displacement snapshots (numpy SVD).

        Args:
            mesh: the mesh of the snapshots.
            displacements: (f, n, 3) snapshots.
            count: number of modes kept.
            density: only scales the mass weighting (the subspace does not depend on it).
            weights: (f,) weights ``w_f >= 0`` of the snapshots: the modes minimise
                ``sum_f w_f |u_f - P u_f|_M^2`` (None: all 1). See :func:`run_balanced_weights`.

        Returns:
            ``(basis, singular_values)`` (of the weighted snapshots).

        Raises:
            ShapeError: wrong shapes, ``count`` out of range, or weights negative or not finite.
        """
        u = np.asarray(displacements, dtype=np.float64)
        if u.ndim != 3 or u.shape[1:] != (mesh.n_vertices, 3):
            raise ShapeError(f"displacements must have shape (f, {mesh.n_vertices}, 3), got {u.shape}")
        if not 1 <= count <= min(u.shape[0], 3 * mesh.n_vertices):
            raise ShapeError(f"POD count must be in [1, {min(u.shape[0], 3 * mesh.n_vertices)}], got {count}")
        sqrt_m = np.sqrt(np.repeat(mesh.vertex_masses(density), 3))
        snapshots = (u.reshape(len(u), -1) * sqrt_m).T  # (3n, f), mass-weighted
        if weights is not None:
            w = np.asarray(weights, dtype=np.float64)
            if w.shape != (len(u),) or not np.all(np.isfinite(w)) or np.any(w < 0):
                raise ShapeError(f"POD weights must be {len(u)} finite numbers >= 0 (one per snapshot), got shape {w.shape}")
            snapshots = snapshots * np.sqrt(w)
        left, sigma, _ = np.linalg.svd(snapshots, full_matrices=False)
        modes = (left[:, :count] / sqrt_m[:, None]).reshape(mesh.n_vertices, 3, count)
        return cls(mesh, modes), sigma

    def values(self, points: np.ndarray) -> np.ndarray:
        p = check_points(points)
        if p.shape == self.mesh.vertices.shape and np.array_equal(p, self.mesh.vertices):
            return self.modes.copy()
        tets, bary = self.mesh.locate(p)
        return np.einsum("pa,paic->pic", bary, self.modes[self.mesh.tets[tets]])

    def jacobians(self, points: np.ndarray) -> np.ndarray:
        tets, _ = self.mesh.locate(check_points(points))
        return mesh_strain_jacobians(self.mesh, tets, self.modes)

    def __repr__(self) -> str:
        return f"MeshBasis(n_vertices={self.mesh.n_vertices}, n_modes={self.n_modes})"


RUN_BALANCE = 0.75
"""Default exponent of :func:`run_balanced_weights` (why 3/4 there)."""


def run_balanced_weights(runs: np.ndarray, norm2: np.ndarray, floor: float = 1e-2, power: float = RUN_BALANCE) -> np.ndarray:
    """POD weights under which a run that deforms a lot counts little more than a gentle one.

    Plain POD minimises the summed squared error of all frames, so a few runs that deform
    a lot (a body tumbling end over end) take the modes that the many gentle runs (a slide,
    a stick) need; the error that matters, each run's own relative error, is then large on
    the gentle ones. Each frame of run ``k`` gets ``w = 1 / max(E_k, floor * max_j E_j)^power``
    with ``E_k = sum_{f in k} |u_f|_M^2``, so run k's frames sum to ``E_k^(1 - power)``:
    ``power = 1`` balances the runs in full (each sums to 1), 0 is plain POD. The floor
    keeps a run that hardly deforms (a free fall, whose residual is round-off) from being
    blown up into modes of noise: it counts in proportion to its energy, at most
    ``floor^-power`` times more than plain POD would count it.

    The default 3/4 is measured in docs/results.md section 10 ("Balanced POD"): balanced in
    full, a run that tumbles end over end lost more against plain POD than the 1.2x a
    subspace is allowed.

    Args:
        runs: (f,) integer run index of each frame.
        norm2: (f,) mass-weighted squared norm ``|u_f|_M^2`` of each frame.
        floor: smallest run energy balanced in full, as a share of the largest, in [0, 1].
        power: how far the runs are balanced, in [0, 1] (0: plain POD, 1: every run the same).

    Returns:
        (f,) weights for :meth:`MeshBasis.pod` (all 0 when no frame deforms).

    Raises:
        ShapeError: different lengths, or norms negative or not finite.
        ConfigError: ``floor`` or ``power`` outside [0, 1].
    """
    runs = np.asarray(runs)
    norm2 = np.asarray(norm2, dtype=np.float64)
    if runs.ndim != 1 or runs.shape != norm2.shape:
        raise ShapeError(f"runs and norm2 must be 1-D of one length, got shapes {runs.shape} and {norm2.shape}")
    if not np.all(np.isfinite(norm2)) or np.any(norm2 < 0):
        raise ShapeError("norm2 must hold finite numbers >= 0")
    if not 0.0 <= floor <= 1.0:
        raise ConfigError(f"floor must be in [0, 1], got {floor!r}")
    if not 0.0 <= power <= 1.0:
        raise ConfigError(f"power must be in [0, 1], got {power!r}")
    if len(runs) == 0:
        return np.zeros(0)
    _, inverse = np.unique(runs, return_inverse=True)
    energies = np.bincount(inverse, weights=norm2)
    totals = np.maximum(energies, floor * energies.max())
    per_run = np.divide(1.0, totals**power, out=np.zeros_like(totals), where=totals > 0)
    return per_run[inverse]


class StackedBasis:
    """Bases side by side: ``W = [W_1 | W_2 | ...]`` (e.g. affine + learned modes)."""

    def __init__(self, *bases: Basis) -> None:
        if not bases:
            raise ShapeError("StackedBasis needs at least one basis")
        for b in bases:
            if not isinstance(b, Basis):
                raise ShapeError(f"{type(b).__name__} is not a basis: it needs n_modes, values(points) and jacobians(points)")
        self.bases = tuple(bases)
        self.n_modes = sum(b.n_modes for b in bases)

    def values(self, points: np.ndarray) -> np.ndarray:
        return np.concatenate([b.values(points) for b in self.bases], axis=2)

    def jacobians(self, points: np.ndarray) -> np.ndarray:
        return np.concatenate([b.jacobians(points) for b in self.bases], axis=3)

    def __repr__(self) -> str:
        return f"StackedBasis({', '.join(map(repr, self.bases))})"
