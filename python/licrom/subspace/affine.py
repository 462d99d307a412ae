"""The 12 affine modes ``u(X) = A X + t``: values, derivatives, fits, and removing them from a field.

Mode ``c < 9`` is ``X_j e_i`` with ``(i, j) = divmod(c, 3)`` (entry ``A_ij`` of the linear
map); modes 9, 10, 11 are the translations ``e_0, e_1, e_2``. A rotation is an affine
map, so a world-frame subspace that holds these modes moves rigidly exactly. One copy
serves numpy and torch (the training loop and the exported basis use the same code).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import ShapeError
from ..geometry.mesh import check_points

__all__ = [
    "AFFINE_JACOBIAN",
    "N_AFFINE",
    "affine_jacobians",
    "affine_values",
    "apply_affine",
    "fit_affine",
    "remove_affine_part",
]

N_AFFINE = 12


def _affine_jacobian_constant() -> np.ndarray:
    out = np.zeros((3, 3, N_AFFINE))
    for c in range(9):
        i, j = divmod(c, 3)
        out[i, j, c] = 1.0
    out.setflags(write=False)
    return out


AFFINE_JACOBIAN = _affine_jacobian_constant()
"""(3, 3, 12) constant ``dW_ic/dX_j`` of the affine modes."""


def affine_values(points: Any) -> Any:
    """(p, 3, 12) values of the affine modes at (p, 3) points (numpy or torch in, same out)."""
    if hasattr(points, "new_zeros"):  # a torch tensor: stay on its device and dtype
        out = points.new_zeros((points.shape[0], 3, N_AFFINE))
    else:
        points = check_points(points)
        out = np.zeros((len(points), 3, N_AFFINE))
    for i in range(3):
        out[:, i, 3 * i : 3 * i + 3] = points
        out[:, i, 9 + i] = 1.0
    return out


def affine_jacobians(points: np.ndarray) -> np.ndarray:
    """(p, 3, 3, 12) spatial derivatives of :func:`affine_values` (constant)."""
    return np.broadcast_to(AFFINE_JACOBIAN, (len(check_points(points)), 3, 3, N_AFFINE)).copy()


def remove_affine_part(points: Any, field: Any, masses: Any) -> tuple[Any, Any]:
    """A field of r modes minus its mass-weighted least-squares affine part (numpy or torch).

    Args:
        points: (n, 3) rest points.
        field: (3n, r) mode values at them, rows ``3 v + i``.
        masses: (n,) lumped masses.

    Returns:
        ``(field - A C, C)``: the part mass-orthogonal to the affine modes, and the
        (12, r) coefficients removed.
    """
    a = affine_values(points).reshape(-1, N_AFFINE)
    if hasattr(masses, "repeat_interleave"):
        import torch

        mw = masses.repeat_interleave(3)
        solve = torch.linalg.solve
    else:
        mw = np.repeat(np.asarray(masses, dtype=np.float64), 3)
        solve = np.linalg.solve
    gram = a.T @ (mw[:, None] * a)
    c = solve(gram, a.T @ (mw[:, None] * field))
    return field - a @ c, c


def fit_affine(points: np.ndarray, displacements: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Weighted least-squares affine coefficients of displacement fields.

    Solves ``min_a sum_v w_v |u_v - A(X_v) a|^2`` for each frame (centred at the
    weighted centroid, so the solve stays well conditioned far from the origin).

    Args:
        points: (n, 3) points X.
        displacements: (n, 3) or (f, n, 3) displacements u at those points.
        weights: (n,) non-negative weights (lumped masses).

    Returns:
        (12,) or (f, 12) coefficients in the affine mode order.
    """
    x = np.asarray(points, dtype=np.float64)
    u = np.asarray(displacements, dtype=np.float64)
    single = u.ndim == 2
    if single:
        u = u[None]
    w = np.asarray(weights, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != 3 or u.shape[1:] != x.shape or w.shape != (len(x),):
        raise ShapeError(f"fit_affine needs points (n, 3), displacements (f, n, 3) and weights (n,); got {x.shape}, {u.shape}, {w.shape}")
    centre = (w @ x) / w.sum()
    xc = x - centre
    design = np.concatenate([xc, np.ones((len(x), 1))], axis=1)  # (n, 4)
    gram = design.T @ (w[:, None] * design)
    rhs = np.matmul((w[:, None] * design).T, u)  # (f, 4, 3); BLAS (einsum took 20x longer at 120k tets)
    coef = np.linalg.solve(gram[None], rhs)  # (f, 4, 3): coef[k, i]
    lin = np.transpose(coef[:, :3, :], (0, 2, 1))  # (f, 3, 3): F_ij
    trans = coef[:, 3, :] - np.einsum("fij,j->fi", lin, centre)
    a = np.concatenate([lin.reshape(len(u), 9), trans], axis=1)
    return a[0] if single else a


def apply_affine(points: np.ndarray, coefficients: np.ndarray) -> np.ndarray:
    """Displacements (n, 3) or (f, n, 3) of affine coefficients (12,) or (f, 12) at points (n, 3)."""
    a = np.asarray(coefficients, dtype=np.float64)
    x = np.asarray(points, dtype=np.float64)
    single = a.ndim == 1
    a2 = a[None] if single else a
    out = np.matmul(x, np.swapaxes(a2[:, :9].reshape(-1, 3, 3), -1, -2)) + a2[:, None, 9:]
    return out[0] if single else out
