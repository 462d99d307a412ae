"""Training data on the training device and the random points drawn from it (uniform in volume)."""

from __future__ import annotations

import numpy as np
import torch

from ..training_data import TrainingData


class _Bank:
    """The training data as tensors on one device (not part of any checkpoint).

    ``pod``: optional ``(modes (r, n, 3), latents (F, r), weights (r,))`` regression
    targets of the ``"pod"`` objective (see :func:`pod_targets`).
    """

    def __init__(self, data: TrainingData, device: torch.device, pod: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> None:
        f32 = dict(dtype=torch.float32, device=device)
        mesh = data.mesh
        self.device = device
        self.rest = torch.tensor(data.rest, **f32)
        self.rest64 = torch.tensor(data.rest, dtype=torch.float64, device=device)
        self.tets = torch.tensor(np.asarray(mesh.tets), dtype=torch.int64, device=device)
        vol = np.asarray(mesh.rest_volumes, dtype=np.float64)
        self.tet_cdf = torch.as_tensor(np.cumsum(vol) / vol.sum(), **f32)
        m = np.asarray(data.masses, dtype=np.float64)
        self.vertex_cdf = torch.as_tensor(np.cumsum(m) / m.sum(), **f32)
        self.masses = torch.as_tensor(m, dtype=torch.float64, device=device)
        self.train = torch.as_tensor(data.train.residuals, **f32)
        self.val = self.val_norm2_res = self.val_norm2_full = None
        if data.val is not None and len(data.val):
            self.val = torch.as_tensor(data.val.residuals, **f32)
            self.val_norm2_res = torch.as_tensor(data.val.norm2_residual, dtype=torch.float64, device=device)
            self.val_norm2_full = torch.as_tensor(data.val.norm2_full, dtype=torch.float64, device=device)
        self.pod_modes = self.pod_latents = self.pod_weights = None
        if pod is not None:
            self.pod_modes, self.pod_latents, self.pod_weights = (torch.as_tensor(a, **f32) for a in pod)


def _sample_points(bank: _Bank, points: int, mode: str, gen: torch.Generator) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Points (P, 3) with the vertices (P, k) and interpolation weights (P, k) that make them."""
    dev = bank.rest.device
    u01 = torch.rand(points, generator=gen, device=dev)
    if mode == "vertices":
        v = torch.searchsorted(bank.vertex_cdf, u01).clamp_(max=len(bank.rest) - 1)
        return bank.rest[v], v[:, None], torch.ones(points, 1, dtype=bank.rest.dtype, device=dev)
    t = torch.searchsorted(bank.tet_cdf, u01).clamp_(max=len(bank.tets) - 1)
    e = -torch.log(torch.rand(points, 4, generator=gen, device=dev).clamp_(min=1e-12))
    w = e / e.sum(dim=1, keepdim=True)  # uniform barycentric coordinates in a tet
    verts = bank.tets[t]  # (P, 4)
    return (bank.rest[verts] * w[..., None]).sum(dim=1), verts, w


def _interpolate(fields: torch.Tensor, frames: torch.Tensor | None, verts: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """Vertex fields (F, n, 3) of ``frames`` (B,) (None: all) at sampled points: (B, P, 3)."""
    sel = fields[:, verts] if frames is None else fields[frames[:, None, None], verts[None]]
    return torch.einsum("bpki,pk->bpi", sel, w)


def _sample(bank: _Bank, residuals: torch.Tensor, frames: torch.Tensor, points: int, mode: str, gen: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    """Points (P, 3), shared by the frames, and residual displacements (B, P, 3) of ``frames`` (B,).

    Sharing the points across the batch lets the field W be evaluated once per step.
    """
    x, verts, w = _sample_points(bank, points, mode, gen)
    return x, _interpolate(residuals, frames, verts, w)
