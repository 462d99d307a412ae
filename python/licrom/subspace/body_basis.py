"""Body-frame modes: the 6 symmetric affine modes plus learned ones, carrying no linear or angular momentum.

The subspace of the body-frame model (:mod:`licrom.reduced.body`): positions are
``x_v = c + R (Xbar_v + W_v q)`` with ``Xbar = X - X_com``, and every column of ``W`` is made
mass-orthogonal to the six rigid modes on the mesh, so that the rigid motion ``(c, R)`` is
exact and ``c`` the centre of mass (see docs/design.md, "Reduced model in the body frame").
"""

from __future__ import annotations

import numpy as np

from ..errors import ConfigError
from ..geometry.mesh import Mesh, check_points
from ..rigid import center_of_mass
from .basis import Basis, check_basis, check_basis_output

__all__ = ["N_SYMMETRIC", "BodyFrameBasis", "rigid_momenta"]

N_SYMMETRIC = 6
"""Number of symmetric affine modes ``S Xbar`` (stretches and shears)."""

def _symmetric_matrices() -> np.ndarray:
    """(6, 3, 3) basis of symmetric matrices: three stretches, three shears."""
    out = np.zeros((N_SYMMETRIC, 3, 3))
    for k, (a, b) in enumerate([(0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)]):
        out[k, a, b] = out[k, b, a] = 1.0 if a == b else 0.5
    return out


def _skew(w: np.ndarray) -> np.ndarray:
    """(..., 3) -> (..., 3, 3) cross-product matrices ``[w]x``."""
    w = np.asarray(w)
    out = np.zeros(w.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2] = -w[..., 2], w[..., 1]
    out[..., 1, 0], out[..., 1, 2] = w[..., 2], -w[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -w[..., 1], w[..., 0]
    return out


def _inertia_tensor(arms: np.ndarray, masses: np.ndarray) -> np.ndarray:
    """``sum m (|r|^2 I - r r^T)`` of (n, 3) arms about the centre of mass."""
    second = np.einsum("v,vi,vj->ij", masses, arms, arms)
    return np.trace(second) * np.eye(3) - second


def rigid_momenta(values: np.ndarray, xbar: np.ndarray, masses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per column k of (n, 3, k) values: the mean ``t_k`` and the infinitesimal rotation
    ``w_k`` of the mass-weighted least-squares fit ``W^k ~ t_k + w_k x Xbar``."""
    total = masses.sum()
    t = (masses @ values.reshape(len(masses), -1)).reshape(3, -1).T / total
    # sum_v m_v Xbar_v x W_v^k, one matrix-vector product per term (np.cross copied (n, 3, k) twice: 0.45 s at 120k tets)
    mx = masses[:, None] * xbar
    moment = np.stack([mx[:, a] @ values[:, b] - mx[:, b] @ values[:, a] for a, b in ((1, 2), (2, 0), (0, 1))], axis=1)
    return t, np.linalg.solve(_inertia_tensor(xbar, masses), moment.T).T


def _rotation_fields(w: np.ndarray, xbar: np.ndarray) -> np.ndarray:
    """(p, 3, k) ``w_k x Xbar_p`` for (k, 3) ``w`` and (p, 3) ``Xbar``."""
    return np.stack([np.outer(xbar[:, b], w[:, a]) - np.outer(xbar[:, a], w[:, b]) for a, b in ((1, 2), (2, 0), (0, 1))], axis=1)


class BodyFrameBasis:
    """Body-frame modes on a mesh: 6 symmetric affine modes plus learned ones.

    Every column ``W^k`` is made mass-orthogonal to the rigid modes on this mesh by
    subtracting its least-squares translation ``t_k`` and infinitesimal rotation
    ``w_k x Xbar`` (the Jacobians change by ``-[w_k]x``). The symmetric affine modes
    need it too: on an anisotropic body a shear carries angular momentum.

    Args:
        mesh: the mesh that defines the masses (and ``X_com``).
        learned: a basis whose values are body-frame displacements at rest points
            (a body-frame :class:`licrom.Model`, a :class:`licrom.MeshBasis`, ...),
            or None for the affine modes alone. It must not contain affine modes.
        density: kg/m^3; only weights the masses (uniform density: no effect on W).

    Raises:
        ShapeError: the learned basis returns arrays of the wrong shape or NaN/inf.
        ConfigError: the learned basis is not a basis.
    """

    def __init__(self, mesh: Mesh, learned: Basis | None = None, density: float = 1000.0) -> None:
        if learned is not None:
            check_basis(learned, "learned")
        if not (np.isfinite(density) and density > 0):
            raise ConfigError(f"density must be a finite number > 0, got {density}")
        self.mesh = mesh
        self.learned = learned
        self.density = float(density)
        self.n_modes = N_SYMMETRIC + (int(learned.n_modes) if learned is not None else 0)
        masses = mesh.vertex_masses(self.density)
        self.center = center_of_mass(mesh.vertices, masses)
        self._t, self._w = rigid_momenta(self._raw_values(mesh.vertices), mesh.vertices - self.center, masses)

    def _raw_values(self, points: np.ndarray) -> np.ndarray:
        xbar = points - self.center
        sym = np.einsum("kij,pj->pik", _symmetric_matrices(), xbar)
        if self.learned is None:
            return sym
        learned = check_basis_output("values", self.learned.values(points), (len(points), 3, self.learned.n_modes))
        return np.concatenate([sym, learned], axis=2)

    def values(self, points: np.ndarray) -> np.ndarray:
        """(p, 3) rest points -> (p, 3, n) orthogonalised mode values."""
        p = check_points(points)
        xbar = p - self.center
        return self._raw_values(p) - (self._t.T[None] + _rotation_fields(self._w, xbar))

    def jacobians(self, points: np.ndarray) -> np.ndarray:
        """(p, 3) rest points -> (p, 3, 3, n) ``dW_ic/dX_j`` of the orthogonalised modes."""
        p = check_points(points)
        sym = np.broadcast_to(_symmetric_matrices().transpose(1, 2, 0), (len(p), 3, 3, N_SYMMETRIC))
        jac = sym
        if self.learned is not None:
            shape = (len(p), 3, 3, self.learned.n_modes)
            jac = np.concatenate([sym, check_basis_output("jacobians", self.learned.jacobians(p), shape)], axis=3)
        return jac - _skew(self._w).transpose(1, 2, 0)[None]

    def on(self, mesh: Mesh) -> BodyFrameBasis:
        """The same modes orthogonalised on another mesh of the object."""
        return BodyFrameBasis(mesh, self.learned, self.density)

    def __repr__(self) -> str:
        return f"BodyFrameBasis(n_modes={self.n_modes}, learned={self.learned!r})"
