"""Where the reduced model samples elasticity (cubature tets) and contact (contact points).

Elastic energy is approximated as ``sum_k w_k Psi(F(X_k))`` over K cubature points,
the tet centroids of selected tets, with weights ``w_k`` in m^3 (a tet's own volume
gives the exact full-mesh energy). Contact acts at contact points, boundary
vertices carrying a share ``a_j`` of the boundary area in m^2.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from .._repr import concise_repr
from ..errors import ConfigError, ShapeError
from ..geometry.mesh import Mesh
from ..geometry.points import farthest_points
from ..scene.scene import Material
from .basis import Basis, strain_jacobians
from .body_basis import BodyFrameBasis

if TYPE_CHECKING:
    from ..learn.model import Model
    from ..records.trajectory import Trajectory

__all__ = ["DEFAULT_CONTACT_POINTS", "FIT_MEMORY", "FIT_TOLERANCE", "ContactPoints", "Cubature", "fit_candidates", "model_basis", "model_samples"]


FIT_TOLERANCE = 1e-2
"""Default relative force residual of a fitted cubature (:meth:`Cubature.fitted`), chosen by measurement (see docs/results.md)."""


FIT_MEMORY = 2**30
"""Bytes of candidate forces :meth:`Cubature.fitted` may hold where no candidate count is given: on large meshes
it draws fewer candidate tets (:func:`fit_candidates`)."""


def fit_candidates(samples: int, width: int) -> int:
    """Candidate tets :meth:`Cubature.fitted` draws by default for ``samples`` poses of ``width`` reduced
    coordinates: as many as :data:`FIT_MEMORY` holds (8 bytes per sample and coordinate each), 1000-20000.

    At high r on large meshes this is the fit's limit, not its count: the 104k-tet ball at r = 250 (256 poses)
    draws 2001 candidates and stops at 812 tets with a 19 % force residual however many it may take; from 8192
    candidates it reaches 3.9 % with 1858 (docs/results.md section 34).

    Raises:
        ConfigError: ``samples`` or ``width`` not an integer >= 1.
    """
    per_candidate = 8 * _count("fit_candidates samples", samples, 2**62) * _count("fit_candidates width", width, 2**62)
    return int(min(20000, max(1000, FIT_MEMORY // per_candidate)))


def _count(name: str, value: int, upper: int) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ConfigError(f"{name} must be an integer >= 1, got {value!r}")
    return int(min(value, upper))


def _indices(owner: str, name: str, value: object) -> np.ndarray:
    """``value`` as a 1-D array of integer indices >= 0, else a named error."""
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError) as exc:
        raise ShapeError(f"{owner} {name} must be a 1-D array of integer indices >= 0: {exc}") from None
    if arr.ndim != 1:
        raise ShapeError(f"{owner} {name} must be a 1-D array of integer indices >= 0, got shape {arr.shape}")
    if arr.size == 0 and arr.dtype.kind == "f":
        arr = arr.astype(np.int64)
    if arr.dtype.kind not in "iu":
        raise ConfigError(f"{owner} {name} must be integer indices >= 0, got dtype {arr.dtype}")
    if arr.size and int(arr.min()) < 0:
        raise ConfigError(f"{owner} {name} must be >= 0 (negative indices would wrap), got minimum {int(arr.min())}")
    return arr


def _amounts(owner: str, name: str, value: object, unit: str) -> np.ndarray:
    """``value`` as a 1-D array of finite reals >= 0, else a named error."""
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{owner} {name} must be a 1-D array of finite values >= 0 in {unit}: {exc}") from None
    if arr.ndim != 1:
        raise ShapeError(f"{owner} {name} must be a 1-D array of finite values >= 0 in {unit}, got shape {arr.shape}")
    if arr.size == 0 and arr.dtype.kind not in "biuf":
        arr = arr.astype(np.float64)
    if arr.dtype.kind not in "iuf":
        raise ConfigError(f"{owner} {name} must be finite real values >= 0 in {unit}, got dtype {arr.dtype}")
    if np.any(~np.isfinite(arr)) or np.any(arr < 0):
        raise ConfigError(f"{owner} {name} must be finite and >= 0 (in {unit})")
    return arr


@dataclass(frozen=True)
class Cubature:
    """Cubature tets and weights on a mesh.

    Attributes:
        tets: (K,) indices of the cubature tets.
        weights: (K,) non-negative weights in m^3.
        points: (K, 3) cubature points (tet centroids) in m.
        scheme: ``"full"``, ``"naive"`` or ``"optimized"``.
        fit_error: relative error of the fitted reduced forces on the training
            samples (``optimized`` only, else None).

    Arrays may be given as any sequences (lists, tuples); they are kept as arrays: tets int,
    weights and points float64.

    Raises:
        ShapeError: arrays of the wrong shape or lengths, points not finite real numbers.
        ConfigError: tets not integers >= 0, weights not finite reals >= 0.
    """

    tets: np.ndarray
    weights: np.ndarray
    points: np.ndarray
    scheme: str
    fit_error: float | None = field(default=None)

    __repr__ = concise_repr

    def __post_init__(self) -> None:
        tets = _indices("Cubature", "tets", self.tets)
        weights = _amounts("Cubature", "weights", self.weights, "m^3").astype(np.float64, copy=False)
        what = "Cubature points must be a (K, 3) array (or sequence) of finite real coordinates in m"
        try:
            points = np.asarray(self.points)
            if points.dtype.kind not in "iuf":
                raise TypeError(f"dtype {points.dtype}")
            points = points.astype(np.float64, copy=False)
        except (TypeError, ValueError) as exc:
            raise ShapeError(f"{what}, got {type(self.points).__name__} ({exc})") from None
        if points.size == 0 and points.ndim <= 2:
            points = points.reshape(0, 3)  # no points: [] as well as np.zeros((0, 3))
        if points.ndim != 2 or points.shape[1] != 3:
            raise ShapeError(f"{what}, got shape {points.shape}")
        if not np.all(np.isfinite(points)):
            raise ShapeError("Cubature points hold NaN or inf")
        if len(tets) != len(weights) or len(tets) != len(points):
            raise ShapeError("Cubature tets, weights and points must have the same length, got "
                             f"{len(tets)}, {len(weights)} and {len(points)}")
        object.__setattr__(self, "tets", tets)
        object.__setattr__(self, "weights", weights)
        object.__setattr__(self, "points", points)

    @property
    def count(self) -> int:
        return len(self.tets)

    @classmethod
    def full(cls, mesh: Mesh) -> Cubature:
        """Every tet with its own volume: the exact elastic energy of the mesh."""
        idx = np.arange(mesh.n_tets)
        return cls(idx, mesh.rest_volumes.copy(), mesh.centroids[idx], "full")

    @classmethod
    def naive(cls, mesh: Mesh, count: int = 1000, seed: int = 0) -> Cubature:
        """The report's scheme: ``count`` random tets, volume-scaled so the weights sum to the volume.

        Args:
            mesh: the mesh.
            count: number of cubature tets (all tets if the mesh has fewer).
            seed: random seed.
        """
        k = _count("Cubature count", count, mesh.n_tets)
        if k == mesh.n_tets:
            return cls.full(mesh)
        idx = np.sort(np.random.default_rng(seed).choice(mesh.n_tets, size=k, replace=False))
        vol = mesh.rest_volumes[idx]
        return cls(idx, vol * (mesh.volume / vol.sum()), mesh.centroids[idx], "naive")

    @classmethod
    def optimized(
        cls,
        mesh: Mesh,
        basis: Basis,
        material: Material,
        samples: np.ndarray,
        count: int = 1000,
        candidates: int = 20000,
        tolerance: float = 1e-3,
        seed: int = 0,
        strain: str = "mesh",
    ) -> Cubature:
        """Non-negative weights fitted to reduced elastic forces (An et al. 2008).

        Greedy selection: repeatedly add the tets whose force contributions best match the
        remaining residual, then solve a non-negative least-squares problem on the chosen
        tets; stop at ``count`` tets or when the relative residual is below ``tolerance``.
        The target is the reduced force of every tet of the mesh, also where the tets are
        chosen from a random pool of ``candidates`` (meshes larger than it): the residual
        (``fit_error``) is then the error against the whole mesh's forces.

        Args:
            mesh: the mesh.
            basis: the subspace basis (see :mod:`licrom.subspace.basis`).
            material: material of the forces.
            samples: (S, n_modes) reduced coordinates of training poses.
            count: maximum number of cubature tets.
            candidates: tets considered (a random subset on large meshes).
            tolerance: stop when the relative force residual falls below this.
            seed: random seed for the candidate subset.
            strain: ``"mesh"`` or ``"field"``: the deformation gradients of the simulation
                that will use the weights (:func:`licrom.subspace.basis.strain_jacobians`).
        """
        import scipy.linalg
        from scipy.optimize import nnls

        from .. import _core

        q = np.asarray(samples, dtype=np.float64)
        if q.ndim != 2 or q.shape[1] != basis.n_modes or len(q) < 1:
            raise ShapeError(f"samples must have shape (S, {basis.n_modes}) with S >= 1, got {q.shape}")
        k = _count("Cubature count", count, mesh.n_tets)
        pool = np.arange(mesh.n_tets)
        if mesh.n_tets > candidates:
            pool = np.sort(np.random.default_rng(seed).choice(mesh.n_tets, size=candidates, replace=False))
        mu, lam = material.snh_parameters
        values = basis.values(mesh.vertices) if strain == "mesh" else None
        # Per-tet reduced forces per unit volume for every sample: columns of A.
        g = strain_jacobians(basis, mesh, pool, strain, values).reshape(len(pool), 9, -1)  # (P, 9, n)
        eye = np.eye(3).reshape(9)
        cols = np.empty((len(q), basis.n_modes, len(pool)))
        for s, qs in enumerate(q):
            f = (eye + g @ qs).reshape(-1, 3, 3)
            stress = _core.snh_pk1(np.ascontiguousarray(f), mu, lam).reshape(-1, 9)
            cols[s] = np.einsum("pkn,pk->np", g, stress)
        # Target: the reduced forces of every tet of the mesh. Where the pool is a subset (large meshes), its
        # own forces rescaled to the mesh volume are a sampling estimate of them, and a fit to that estimate
        # carries its sampling error into every reduced run.
        if len(pool) == mesh.n_tets:
            target = cols @ (mesh.rest_volumes[pool] * (mesh.volume / mesh.rest_volumes[pool].sum()))  # (S, n)
        else:
            target = reduced_forces(mesh, basis, material, q, strain=strain, values=values)
        norms = np.linalg.norm(target, axis=1)
        keep = norms > 1e-12 * max(norms.max(), 1e-300)
        if not keep.any():
            raise ConfigError("optimized cubature needs samples with non-zero elastic forces (all samples are at rest)")
        if keep.all():  # in place: the columns are the fit's largest array (FIT_MEMORY bytes)
            cols /= norms[:, None, None]
            a = cols.reshape(-1, len(pool))
        else:
            a = (cols[keep] / norms[keep, None, None]).reshape(-1, len(pool))
        b = (target[keep] / norms[keep, None]).ravel()
        col_norm = np.maximum(np.linalg.norm(a, axis=0), 1e-300)
        chosen: list[int] = []
        weights = np.zeros(0)
        residual = b.copy()
        batch = max(1, k // 20)
        b_norm = float(np.linalg.norm(b))
        error = 1.0
        # NNLS on the chosen columns' Gram matrix G = A_c^T A_c = L L^T, grown by the new columns each round:
        # |A_c w - b|^2 = |L^T w - L^-1 A_c^T b|^2 + |b|^2 - |L^-1 A_c^T b|^2, a (c x c) problem in place of the
        # (S n x c) one (at r = 60, 256 poses: 0.05 s against 46 s for 300 columns).
        gram = np.zeros((0, 0))
        atb = np.zeros(0)
        while len(chosen) < k:
            score = (a.T @ residual) / col_norm
            score[chosen] = -np.inf
            new = [int(i) for i in np.argsort(score)[::-1][:batch] if score[i] > 0][: k - len(chosen)]
            if not new:
                break
            cross = a[:, chosen].T @ a[:, new]
            gram = np.block([[gram, cross], [cross.T, a[:, new].T @ a[:, new]]])
            atb = np.concatenate([atb, a[:, new].T @ b])
            chosen.extend(new)
            # a relative ridge of 1e-12 keeps the factor of nearly parallel columns finite; it moves the fit by less
            factor = np.linalg.cholesky(gram + 1e-12 * np.trace(gram) / len(chosen) * np.eye(len(chosen)))
            c = scipy.linalg.solve_triangular(factor, atb, lower=True)
            weights, _ = nnls(factor.T, c, maxiter=50 * len(chosen))
            residual = b - a[:, chosen] @ weights
            error = float(np.linalg.norm(residual)) / b_norm
            if error < tolerance:
                break
        sel = np.array(chosen)
        nz = weights > 0
        tets = pool[sel[nz]]
        order = np.argsort(tets)
        return cls(tets[order], weights[nz][order], mesh.centroids[tets[order]], "optimized", float(error))

    @classmethod
    def for_model(cls, model: Model, runs: Sequence[Trajectory], count: int = 1000, frame_stride: int = 5, tolerance: float = FIT_TOLERANCE,
                  strain: str = "mesh") -> Cubature:
        """:meth:`optimized` cubature for a trained model, fitted to the poses of its training runs.

        The basis and samples are those the simulation of ``model`` uses (:func:`model_basis`,
        :func:`model_samples`). :func:`licrom.train` already fits one and stores it in the model
        (:attr:`licrom.Model.cubature`); this refits it with other settings or runs.

        Args:
            model: a trained :class:`licrom.Model`.
            runs: trajectories on the model's rest mesh (its training runs), landing included.
            count: maximum number of cubature tets.
            frame_stride: every ``frame_stride``-th frame of each run is a sample, and of its impact frames.
            tolerance: stop when the relative force residual falls below this.
            strain: as in :meth:`optimized`.

        Raises:
            ShapeError: a run is not on the model's mesh.
            ConfigError: no run, a bad stride, or no sample with elastic forces.
        """
        from ..rigid import body_frame_displacements

        if not runs:
            raise ConfigError("Cubature.for_model needs at least one run")
        step = _count("frame_stride", frame_stride, 2**31)
        mesh = model.mesh
        for i, run in enumerate(runs):
            if run.rest_positions.shape != mesh.vertices.shape or not np.allclose(run.rest_positions, mesh.vertices):
                raise ShapeError(f"runs[{i}] is not on the model's rest mesh ({mesh.n_vertices} vertices)")
        frames = np.concatenate([np.concatenate([run.displacements[::step], run.impact_displacements[::step]]) for run in runs])
        if model.frame == "body":
            frames = body_frame_displacements(mesh.vertices + frames, mesh.vertices, mesh.vertex_masses(model.default_scene.material.density))
        return cls.fitted(model, model_samples(model, frames), count=count, tolerance=tolerance, strain=strain)

    @classmethod
    def fitted(cls, model: Model, samples: np.ndarray, mesh: Mesh | None = None, count: int = 1000, tolerance: float = FIT_TOLERANCE,
               strain: str = "mesh", candidates: int | None = None) -> Cubature:
        """:meth:`optimized` cubature of ``model`` on ``mesh`` (default its own) for reduced coordinates ``samples``.

        The reduced coordinates of a pose mean the same on every mesh of the object (the
        basis is continuous), so the samples of the training poses refit the cubature on
        another mesh (:meth:`licrom.Model.cubature_for`).

        Args:
            model: a trained :class:`licrom.Model`.
            samples: (S, n) reduced coordinates of :func:`model_basis` (see :func:`model_samples`).
            mesh: the mesh of the cubature tets (default: the model's).
            count: maximum number of cubature tets.
            tolerance: stop when the relative force residual falls below this.
            strain: as in :meth:`optimized`.
            candidates: tets the fit chooses from (a random pool of the mesh's); None: as many as
                :data:`FIT_MEMORY` holds (:func:`fit_candidates`). The fit holds ``8 * S * n`` bytes per candidate.

        Raises:
            ConfigError: ``candidates`` not an integer >= 1.
        """
        mesh = model.mesh if mesh is None else mesh
        q = np.asarray(samples)
        width = q.shape[1] if q.ndim == 2 else 1
        # an empty sample set is refused by optimized(), with its shape
        candidates = fit_candidates(max(len(q), 1), max(width, 1)) if candidates is None else _count("Cubature candidates", candidates, 2**31)
        return cls.optimized(mesh, model_basis(model, mesh), model.default_scene.material, samples, count=count, candidates=candidates,
                             tolerance=tolerance, strain=strain)


def reduced_forces(mesh: Mesh, basis: Basis, material: Material, q: np.ndarray, tets: np.ndarray | None = None,
                   weights: np.ndarray | None = None, strain: str = "mesh", values: np.ndarray | None = None,
                   chunk: int = 2048) -> np.ndarray:
    """(S, n) reduced elastic forces ``sum_k w_k G_k^T P(F_k)`` at each of the S rows of reduced coordinates ``q``.

    Args:
        mesh: the mesh.
        basis: the subspace basis.
        material: material of the forces.
        q: (S, n) reduced coordinates.
        tets: the tets summed over (default every tet of ``mesh``).
        weights: their weights, m^3 (default their rest volumes: the exact forces).
        strain: as in :meth:`Cubature.optimized`.
        values: the basis' values at the mesh vertices, when already evaluated.
        chunk: tets per pass (all poses at once: two matrix products per chunk, the stresses in one native call).

    Raises:
        ShapeError: ``q`` not (S, n) for the basis' n, or ``weights`` not one per tet.
        ConfigError: tet indices outside the mesh.
    """
    from .. import _core

    mu, lam = material.snh_parameters
    q = np.asarray(q, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != basis.n_modes:
        raise ShapeError(f"reduced_forces: q must have shape (S, {basis.n_modes}), got {q.shape}")
    tets = np.arange(mesh.n_tets) if tets is None else _indices("reduced_forces", "tets", tets)
    if len(tets) and tets.max() >= mesh.n_tets:
        raise ConfigError(f"reduced_forces: tet index {tets.max()} outside the mesh's {mesh.n_tets} tets")
    weights = mesh.rest_volumes[tets] if weights is None else np.asarray(weights, dtype=np.float64)
    if weights.shape != tets.shape:
        raise ShapeError(f"reduced_forces: weights must have shape {tets.shape} (one per tet), got {weights.shape}")
    if strain == "mesh" and values is None:
        values = basis.values(mesh.vertices)
    eye = np.eye(3).reshape(1, 9, 1)
    out = np.zeros((len(q), q.shape[1]))
    for first in range(0, len(tets), chunk):
        part = tets[first:first + chunk]
        g = strain_jacobians(basis, mesh, part, strain, values).reshape(len(part), 9, -1)  # (P, 9, n)
        f = eye + (g.reshape(-1, g.shape[2]) @ q.T).reshape(len(part), 9, len(q))  # (P, 9, S)
        stress = _core.snh_pk1(np.ascontiguousarray(f.transpose(0, 2, 1).reshape(-1, 3, 3)), mu, lam)
        stress = stress.reshape(len(part), len(q), 9) * weights[first:first + chunk, None, None]
        out += stress.transpose(1, 0, 2).reshape(len(q), -1) @ g.reshape(-1, g.shape[2])
    return out


def model_basis(model: Model, mesh: Mesh | None = None) -> Basis:
    """The basis the reduced simulation of ``model`` runs on ``mesh`` (default its own): the model itself
    (world frame) or :class:`licrom.BodyFrameBasis` around it (body frame)."""
    mesh = model.mesh if mesh is None else mesh
    if model.frame != "body":
        return model
    return BodyFrameBasis(mesh, learned=model, density=model.default_scene.material.density)


def model_samples(model: Model, displacements: np.ndarray) -> np.ndarray:
    """(S, n) reduced coordinates of :func:`model_basis` for (S, n_vertices, 3) displacements of the model's mesh in its frame.

    A world-frame model projects world-frame displacements; a body-frame model the body-frame
    displacements ``R^T (x - c) - Xbar`` (:func:`licrom.rigid.body_frame_displacements`).
    """
    from .basis import SubspaceProjector

    u = np.asarray(displacements, dtype=np.float64)
    if model.frame != "body":
        return model.project(u)
    mesh = model.mesh
    masses = mesh.vertex_masses(model.default_scene.material.density)
    return SubspaceProjector(model_basis(model).values(mesh.vertices), masses).project(u)


DEFAULT_CONTACT_POINTS = 2000
"""Most contact points a reduced simulation samples by default (:meth:`ContactPoints.default`)."""


@dataclass(frozen=True)
class ContactPoints:
    """Boundary vertices where contact is evaluated, each with its share of boundary area.

    Attributes:
        indices: (C,) vertex indices.
        areas: (C,) area carried by each point in m^2 (sums to the surface area).
    """

    indices: np.ndarray
    areas: np.ndarray

    __repr__ = concise_repr

    def __post_init__(self) -> None:
        indices = _indices("ContactPoints", "indices", self.indices)
        areas = _amounts("ContactPoints", "areas", self.areas, "m^2")
        if len(indices) != len(areas):
            raise ShapeError(f"ContactPoints indices and areas must have the same length, got {len(indices)} and {len(areas)}")
        object.__setattr__(self, "indices", indices)
        object.__setattr__(self, "areas", areas)

    @property
    def count(self) -> int:
        return len(self.indices)

    @classmethod
    def all(cls, mesh: Mesh) -> ContactPoints:
        """Every boundary vertex with its own area."""
        return cls(mesh.boundary_vertices.copy(), mesh.boundary_vertex_areas.copy())

    @classmethod
    def default(cls, mesh: Mesh) -> ContactPoints:
        """What the reduced simulations use unless told: every boundary vertex, or on a surface of more than
        :data:`DEFAULT_CONTACT_POINTS` vertices a farthest-point :meth:`subset` of that many (deterministic).

        A subset keeps the reduced step from growing with the mesh; on the 120k-tet cheese, 2000 of 6714 gave the
        error of every vertex (docs/results.md section 13).
        """
        return cls.subset(mesh, min(DEFAULT_CONTACT_POINTS, len(mesh.boundary_vertices)))

    @classmethod
    def subset(cls, mesh: Mesh, count: int, seed: int = 0) -> ContactPoints:
        """About ``count`` well-spread boundary vertices (farthest-point sampling).

        Every boundary vertex gives its area to the nearest chosen point, so the total
        area and its distribution over the surface are kept.
        """
        from scipy.spatial import cKDTree

        everyone = cls.all(mesh)
        k = _count("ContactPoints count", count, everyone.count)
        if k == everyone.count:
            return everyone
        pts = mesh.vertices[everyone.indices]
        chosen_arr = np.sort(farthest_points(pts, k, first=int(np.random.default_rng(seed).integers(len(pts)))))
        _, owner = cKDTree(pts[chosen_arr]).query(pts)
        areas = np.bincount(owner, weights=everyone.areas, minlength=k)
        return cls(everyone.indices[chosen_arr], areas)
