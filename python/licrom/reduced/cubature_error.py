"""The cubature's share of a reduced run's error, estimated online: every tet's reduced force against the cubature's.

A reduced step balances the elastic force of its cubature, ``g_K(q) = sum_k w_k G_k^T P(I + G_k q)``
(``G_k = dF/dq`` at cubature tet k, P the stable Neo-Hookean stress), against inertia, gravity and contact. The
full equations projected onto the subspace balance every tet's instead,

    ``g(q) = sum_t V_t G_t^T P(F_t(q)) = sum_v W_v^T dE/dy_v``,

which costs one reconstruction of the body ``y = rest + W q``, one pass over the tets and one product with the
mode values: the elastic force the full model would feel at the reduced state, through the subspace. Their
difference ``d = g(q) - g_K(q)`` is the force the cubature leaves out, and the displacement it would make in the
subspace, ``dq = K^-1 d`` (``K``: the reduced stiffness at rest over every tet, or a large sample of them), is the cubature's error of the
state. The estimate compares it with the body's non-rigid deformation ``u`` as :mod:`licrom.reduced.error_estimate`
compares its residual:

    ``e_K(t) = sqrt(sum_{s<=t} |W dq(s)|_M^2 / sum_{s<=t} |u(s)|_M^2)``

over the evaluated steps s. ``|W dq|_M^2 = dq^T M_r dq`` with ``M_r`` the exact reduced mass; in the modes ``phi``
of ``K phi = lambda M_r phi`` (mass-normalised) it is ``sum_i ((phi_i . d) / lambda_i)^2``, k^2 work a step. Modes
of no stiffness (the world-frame model's rigid motions) feel no elastic force and are left out.

Why: the residual the error estimate samples at vertices is the part of the full equations the subspace cannot
represent; a cubature that integrates the subspace's own forces wrongly leaves a state that satisfies the reduced
equations and is wrong inside the subspace, where that residual does not look (docs/results.md section 47: a fit of
587 tets made the 120k-tet cheese 10.7-15.1 % non-rigid where the same model with every tet lands 1.6-3.6 %, and the
residual read 4.6-6.8 % for both). With every tet as the cubature the term is zero to round-off. The material's
viscous stress, which the cubature integrates too, is left out: the term checks the elastic forces, which hold the
deformation.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import scipy.linalg
import scipy.sparse

from .. import _core
from .._blas import blas_threads
from ..geometry.mesh import Mesh
from ..scene.scene import Scene
from ..subspace.cubature import Cubature

__all__ = ["COST_SHARE", "RIGID_TOLERANCE", "STIFFNESS_TETS", "CubatureError", "evaluation_stride"]

RIGID_TOLERANCE = 1e-9
"""Stiffness eigenvalues below this fraction of the largest count as rigid motions (no elastic force acts on them)."""


STIFFNESS_TETS = 4000
"""Most tets the reduced stiffness at rest is summed over (:meth:`CubatureError._rest_stiffness`): every tet up to this
many, a volume-scaled random sample of this many above, so that on a 120k-tet mesh at r = 250 it costs about what the
rest of the setup does."""

COST_SHARE = 0.03
"""Share of a reduced run's time the term may take on average by :func:`evaluation_stride`'s model (dimensionless):
with the residual's 6 % (:data:`licrom.reduced.error_estimate.RESIDUAL_SHARE`) the estimate stays under 10 % of the
steps."""


def evaluation_stride(n_tets: int, n_cubature: int, k: int) -> int:
    """Steps between two evaluations of the term so that it costs about :data:`COST_SHARE` of the steps, from a cost
    model fitted to measurements on this project's 2-core machine (one evaluation inside a run, where it finds the
    caches cold and slows the steps after it: the run's time with the term less its time without, per evaluation,
    against the run's median step):

    | mesh, k, cubature tets | evaluation | step | ratio | model's ratio |
    |---|---|---|---|---|
    | the demo's 864-tet cheese, 18, 73 | 0.28-0.30 ms | 0.017 ms | 17 | 17 |
    | the 1638-tet cheese, 256, 908 | 3.2 ms | 0.34 ms | 9.2 | 9.0 |
    | the 120k-tet cheese, 246-256, 587-600 (before the step's product kernels, results section 54) | about 60 ms (47 ms alone) | 1.4 ms | about 40 | 190 |

    An evaluation costs a pass over the tets and a fixed part (numpy's and scipy's calls and cold caches, about 5700
    tets' worth); a step about the cubature's Hessian, ``K k^2``, and a fixed part. A run also evaluates the term
    once at its end (:meth:`licrom.reduced.error_estimate.ErrorMonitor.finish`), so that a run shorter than the
    stride has one value.
    """
    ratio = (n_tets + 5700.0) / (n_cubature * k * k / 1.38e5 + 385.0)
    return max(1, math.ceil(ratio / COST_SHARE))


class CubatureError:
    """The cubature's error of a reduced state, as a displacement in the subspace (module docstring).

    Args:
        mesh: the simulated mesh.
        values: (n, 3, k) mode values at every vertex.
        rest: (n, 3) the rest term of the body (``X`` or ``Xbar``), m.
        scene: the scene (its material).
        cubature: the reduced model's cubature.
        jacobians: (K, 9, k) ``dF/dq`` at the cubature tets where the reduced model takes them from the field
            (``strain="field"``); None for the mesh strain (the default), whose cubature F is every tet's F at
            the cubature tets, so that both forces come from one pass over the tets.
        modal_mass: (k, k) exact reduced mass ``W^T M W``, kg.

    Attributes:
        stride: steps between two evaluations (:func:`evaluation_stride`).
    """

    def __init__(self, mesh: Mesh, values: np.ndarray, rest: np.ndarray, scene: Scene, cubature: Cubature, jacobians: np.ndarray | None,
                 modal_mass: np.ndarray) -> None:
        n, _, k = values.shape
        self._mu, self._lam = scene.material.snh_parameters
        self._mesh, self._values, self._modal_mass = mesh, values, modal_mass
        self._volumes = mesh.rest_volumes
        self._modes = values.reshape(3 * n, k)
        self._body = _core.Reconstruction(values, rest)
        self._jacobians = jacobians
        self._weights = cubature.weights
        self._tet_weights = np.zeros(mesh.n_tets)  # the cubature's weight of every tet (0 off it)
        np.add.at(self._tet_weights, cubature.tets, cubature.weights)
        self.stride = evaluation_stride(mesh.n_tets, cubature.count, k)

    # Formed at the first evaluation, not with the simulation: step() and step_many() never evaluate the term, and on
    # the 120k-tet cheese the two cost 0.65 s beside a setup of 1.9 s.
    @functools.cached_property
    def _strain(self) -> scipy.sparse.csr_matrix:
        return _strain_matrix(self._mesh)

    @functools.cached_property
    def _scaled(self) -> np.ndarray:
        """(k, e): the reduced force -> each elastic mode's static displacement (mass-normalised modes over stiffness)."""
        stiffness = self._rest_stiffness()
        lam, phi = scipy.linalg.eigh(0.5 * (stiffness + stiffness.T), self._modal_mass)
        elastic = lam > RIGID_TOLERANCE * max(lam.max(initial=0.0), 1e-300)
        return phi[:, elastic] / lam[elastic]

    def _rest_stiffness(self) -> np.ndarray:
        """(k, k) reduced stiffness at rest, ``sum_t V_t G_t^T C G_t`` (N/m per unit q^2), over every tet of meshes of up
        to :data:`STIFFNESS_TETS` tets and over that many random tets, volume-scaled (:meth:`Cubature.naive`), on larger.

        Not the cubature's: a cubature that misintegrates the forces misintegrates the stiffness too, and one of a few
        tets leaves modes nearly free, which would read its error as a displacement without bound (measured: 25 random
        tets on the 864-tet demo cheese read 950-1010 % for a true 51-60 %). Formed through the vertices,
        ``W^T (S^T D S) W`` (S: the tets' strain rows of :func:`_strain_matrix`, D: their ``w_t C`` blocks, W: the mode
        values at the vertices they touch): on a whole mesh about 3 rows of W per 5 tets in place of 9 rows of ``G_t`` per
        tet, 11.6 against 250 ms on the 1638-tet cheese at k = 256 (2 cores), the first evaluation of a run.
        """
        mesh = self._mesh
        sample = Cubature.full(mesh) if mesh.n_tets <= STIFFNESS_TETS else Cubature.naive(mesh, STIFFNESS_TETS)
        c = _core.snh_hessian(np.eye(3)[None], self._mu, self._lam, False)[0]
        strain = self._strain[(9 * sample.tets[:, None] + np.arange(9)).ravel()]
        touched = np.unique(strain.indices)
        strain = strain[:, touched]
        blocks = scipy.sparse.kron(scipy.sparse.diags(sample.weights), scipy.sparse.csr_matrix(c), format="csr")
        modes = self._modes[touched]
        return modes.T @ ((strain.T @ blocks @ strain) @ modes)

    def forces(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(k,) reduced elastic forces ``dE/dq`` (N m per unit q) at ``q``: every tet's and the cubature's."""
        f = self._strain @ self._body.positions(q).ravel()  # every tet's F, row by row
        stress = _core.snh_pk1(f.reshape(-1, 3, 3), self._mu, self._lam).reshape(-1, 9)
        everything = self._modes.T @ (self._strain.T @ (self._volumes[:, None] * stress).ravel())
        if self._jacobians is None:
            return everything, self._modes.T @ (self._strain.T @ (self._tet_weights[:, None] * stress).ravel())
        at = np.eye(3).ravel() + self._jacobians @ q
        stress = _core.snh_pk1(at.reshape(-1, 3, 3), self._mu, self._lam).reshape(-1, 9)
        return everything, (self._weights[:, None] * stress).ravel() @ self._jacobians.reshape(-1, self._jacobians.shape[2])

    def displacement(self, q: np.ndarray) -> float:
        """``|W dq|_M^2`` (kg m^2): the cubature's error of the state ``q`` as a displacement, squared."""
        # One BLAS thread: its products are small, and a second thread left spinning after them slowed the run's
        # own steps (measured: a run of the 1638-tet cheese 5-52 % slower with it, 2 cores).
        with blas_threads(1):
            everything, cubature = self.forces(q)
            return float(np.sum(((everything - cubature) @ self._scaled) ** 2))


def _strain_matrix(mesh: Mesh) -> scipy.sparse.csr_matrix:
    """(9m, 3n) sparse map from the vertex positions to every tet's deformation gradient, ``F_t = sum_a y_a g_a^T``
    (row ``9 t + 3 i + j`` holds ``F_t[i, j]``); its transpose takes each tet's ``V_t P_t`` to the vertex forces
    ``dE/dy``. Two sparse products in place of a gather, batched 3 x 3 products and a scatter: 3-4x faster."""
    m = mesh.n_tets
    t, a, i, j = np.meshgrid(np.arange(m), np.arange(4), np.arange(3), np.arange(3), indexing="ij")
    rows = 9 * t + 3 * i + j
    cols = 3 * mesh.tets[t, a] + i
    values = mesh.shape_gradients[t, a, j]
    return scipy.sparse.csr_matrix((values.ravel(), (rows.ravel(), cols.ravel())), shape=(9 * m, 3 * mesh.n_vertices))
