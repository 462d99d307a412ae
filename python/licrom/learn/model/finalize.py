"""The exact linear post-processing of the trained field at the end of training (see :mod:`licrom.learn.model`)."""

from __future__ import annotations

import copy
from dataclasses import dataclass, field

import numpy as np
import torch

from ..._repr import concise_repr
from ...geometry.mesh import Mesh
from ...subspace.affine import N_AFFINE, remove_affine_part
from .config import _CHUNK
from .networks import LicromNet

__all__ = ["finalize_basis"]



@dataclass
class _Finalization:
    """Exact linear post-processing of the raw field: ``W = (W_raw - A C) T``."""

    affine_correction: np.ndarray  # (12, r) C (zeros without affine modes)
    transform: np.ndarray  # (r, r) T
    transform_inv: np.ndarray  # (r, r) T^-1
    mode_variance: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (r,) variance per final mode over training frames

    __repr__ = concise_repr


def finalize_basis(net: LicromNet, mesh: Mesh, residuals: np.ndarray | None = None, *, chunk_frames: int = 256) -> _Finalization:
    """Compute the exact post-processing ``W = (W_raw - A C) T`` (see the module docstring).

    Args:
        net: trained networks.
        mesh: rest mesh (its lumped masses weight everything).
        residuals: optional (f, n, 3) training residual displacements (affine part removed);
            when given, the modes are ordered by the variance they carry over these frames.
    """
    config = net.config
    r = config.latent_dim
    masses = mesh.vertex_masses(1.0)
    x = np.asarray(mesh.vertices)
    net64 = copy.deepcopy(net).to(device="cpu", dtype=torch.float64).eval()
    with torch.no_grad():
        wraw = np.concatenate(
            [net64.raw_field(torch.tensor(x[s : s + _CHUNK])).numpy() for s in range(0, len(x), _CHUNK)]
        )  # (n, 3, r)
    mw = np.repeat(masses, 3)
    if config.affine:
        wp, c = remove_affine_part(x, wraw.reshape(-1, r), masses)
    else:
        c = np.zeros((N_AFFINE, r))
        wp = wraw.reshape(-1, r)
    total = masses.sum()
    gram = wp.T @ (mw[:, None] * wp) / total
    lam, vec = np.linalg.eigh(gram)
    floor = max(float(lam.max()), 1e-300) * 1e-12
    if lam.min() <= floor:
        import warnings

        warnings.warn(
            f"the learned modes are (nearly) linearly dependent on the rest mesh (Gram eigenvalues {lam.min():.3e} .. {lam.max():.3e}); "
            "the reduced mass matrix will be ill-conditioned; train longer or use fewer modes",
            stacklevel=2,
        )
        lam = np.maximum(lam, floor)
    s = vec / np.sqrt(lam)  # W' s is mass-orthonormal with W^T M W = m_total I
    s_inv = (vec * np.sqrt(lam)).T
    variance = np.zeros(r)
    rot = np.eye(r)
    if residuals is not None and len(residuals):
        basis = wp @ s  # (3n, r)
        cov = np.zeros((r, r))
        for f0 in range(0, len(residuals), chunk_frames):
            res = np.asarray(residuals[f0 : f0 + chunk_frames], dtype=np.float64).reshape(-1, 3 * len(x))
            y = (res * mw) @ basis / total  # (f, r) coefficients (basis orthonormal)
            cov += y.T @ y
        cov /= len(residuals)
        mu, rot = np.linalg.eigh(cov)
        order = np.argsort(mu)[::-1]
        rot, variance = rot[:, order], np.maximum(mu[order], 0.0)
    t = s @ rot
    t_inv = rot.T @ s_inv
    return _Finalization(c, t, t_inv, variance)
