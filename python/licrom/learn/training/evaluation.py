"""Exact evaluation of a field or model on frames: projection and encoder errors, the POD bound."""

from __future__ import annotations

import copy
from typing import Any

import numpy as np
import torch

from ...errors import ConfigError
from ...subspace.affine import remove_affine_part
from ...subspace.basis import SubspaceProjector
from ..model import LicromNet, Model
from ..training_data import TrainingData
from .objectives import pod_targets
from .sampling import _Bank, _sample


def _orthogonalized_vertex_field(net: LicromNet, rest64: torch.Tensor, masses: torch.Tensor, affine: bool, chunk: int = 16384) -> torch.Tensor:
    """W' = W_raw - A C at the vertices, (3n, r) float64 (mass-orthogonal to the affine modes)."""
    rest = rest64.to(torch.float32)
    w = torch.cat([net.raw_field(rest[s : s + chunk]) for s in range(0, len(rest), chunk)]).to(torch.float64)
    r = w.shape[-1]
    w = w.reshape(-1, r)
    if affine:
        w, _ = remove_affine_part(rest64, w, masses)
    return w


def _pinv_solve(gram: torch.Tensor, rhs: torch.Tensor) -> torch.Tensor:
    lam, vec = torch.linalg.eigh(gram)
    keep = lam > lam.max().clamp(min=1e-300) * 1e-12
    inv = torch.where(keep, 1.0 / torch.where(keep, lam, torch.ones_like(lam)), torch.zeros_like(lam))
    return vec @ (inv[:, None] * (vec.T @ rhs))


@torch.no_grad()
def _evaluate_tensors(
    net: LicromNet,
    bank_rest64: torch.Tensor,
    masses: torch.Tensor,
    residuals: torch.Tensor,
    norm2_res: torch.Tensor,
    norm2_full: torch.Tensor,
    affine: bool,
    encoder_latents: tuple[torch.Tensor, torch.Tensor] | None = None,
    chunk_frames: int = 32,
) -> dict[str, float]:
    """Projection and encoder errors of residual frames (F, n, 3) (see :func:`evaluate`).

    ``encoder_latents``: optional ``(frame indices (E,), raw latents (E, r))`` from the
    encoder for a subset of the frames; the encoder errors are over that subset.
    """
    wp = _orthogonalized_vertex_field(net, bank_rest64, masses, affine)  # (3n, r)
    mw = masses.repeat_interleave(3)
    gram = wp.T @ (mw[:, None] * wp)
    err_proj = torch.zeros((), dtype=torch.float64, device=wp.device)
    for f0 in range(0, len(residuals), chunk_frames):
        res = residuals[f0 : f0 + chunk_frames].to(torch.float64).reshape(-1, wp.shape[0])  # (f, 3n)
        z = _pinv_solve(gram, wp.T @ (mw[:, None] * res.T))  # (r, f)
        d = res - (wp @ z).T
        err_proj += (d * d * mw).sum()
    out = {
        "proj_residual": float(torch.sqrt(err_proj / norm2_res.sum().clamp(min=1e-300))),
        "proj_full": float(torch.sqrt(err_proj / norm2_full.sum().clamp(min=1e-300))),
    }
    if encoder_latents is not None:
        idx, ze = encoder_latents
        err_enc = torch.zeros((), dtype=torch.float64, device=wp.device)
        for f0 in range(0, len(idx), chunk_frames):
            sel = idx[f0 : f0 + chunk_frames]
            res = residuals[sel].to(torch.float64).reshape(len(sel), -1)
            d = res - ze[f0 : f0 + chunk_frames].to(torch.float64) @ wp.T
            err_enc += (d * d * mw).sum()
        out["enc_residual"] = float(torch.sqrt(err_enc / norm2_res[idx].sum().clamp(min=1e-300)))
        out["enc_full"] = float(torch.sqrt(err_enc / norm2_full[idx].sum().clamp(min=1e-300)))
    return out


def _encoder_frames(count: int, limit: int) -> np.ndarray:
    """Evenly spaced frame indices, at most ``limit`` of them."""
    if count <= limit:
        return np.arange(count)
    return np.unique(np.linspace(0, count - 1, limit).round().astype(np.int64))


@torch.no_grad()
def _encode_frames(net: LicromNet, bank: _Bank, residuals: torch.Tensor, idx: torch.Tensor, points: int, gen: torch.Generator, chunk: int = 64) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Raw latents (E, r) of frames ``idx`` from ``points`` sampled points (one draw shared by
    the frames), plus those points (P, 3) and displacements (E, P, 3)."""
    x, u = _sample(bank, residuals, idx, points, "tets", gen)
    z = torch.cat([net.encode_normalized(x, u[s : s + chunk]) for s in range(0, len(idx), chunk)])
    return z, x, u


def evaluate(model: Model, data: TrainingData, split: str = "val", *, points: int = 2048, seed: int = 0, device: str = "cpu") -> dict[str, float]:
    """Reconstruction errors of a model on the training or validation frames of ``data``.

    Relative mass-weighted L2 errors over all frames of the split together,
    ``sqrt(sum_f ||u_f - u~_f||_M^2 / sum_f ||u_f||_M^2)``, of the residual alone
    (``*_residual``) and of the full displacement, affine part included (``*_full``):
    ``proj_*`` for the exact projection onto ``[affine | W]`` at all vertices,
    ``enc_*`` for the encoder's latent from ``points`` sampled points per frame
    (affine part from the exact fit in both cases). Also the frame count.
    """
    frames = data.train if split == "train" else data.val
    if split not in ("train", "val"):
        raise ConfigError(f"split must be 'train' or 'val', got {split!r}")
    if len(frames) == 0:
        return {"frames": 0}
    if model.mesh.n_vertices != data.mesh.n_vertices or not np.allclose(model.mesh.vertices, data.rest):
        raise ConfigError("evaluate needs data on the model's rest mesh")
    dev = torch.device(device)
    net = copy.deepcopy(model.net).to(dev).eval()
    bank = _Bank(_FramesView(data, frames), dev)
    gen = torch.Generator(device=dev)
    gen.manual_seed(seed)
    res = bank.train
    idx = torch.arange(len(frames), device=dev)
    z, _, _ = _encode_frames(net, bank, res, idx, points, gen)
    out = _evaluate_tensors(
        net, bank.rest64, bank.masses, res,
        torch.as_tensor(frames.norm2_residual, device=dev), torch.as_tensor(frames.norm2_full, device=dev),
        model.affine, (idx, z),
    )
    out["frames"] = len(frames)
    return out


def _projection_error2(residuals: np.ndarray, basis: np.ndarray, masses: np.ndarray, chunk_frames: int = 256) -> float:
    """Sum over frames of ``||u - P u||_M^2`` for residuals (F, n, 3), P the M-projection onto basis (n, 3, k)."""
    projector = SubspaceProjector(basis, masses)
    err = 0.0
    for f0 in range(0, len(residuals), chunk_frames):
        u = np.asarray(residuals[f0 : f0 + chunk_frames], dtype=np.float64)
        d = u - (projector.project(u) @ basis.reshape(-1, basis.shape[2]).T).reshape(u.shape)  # BLAS, not einsum's loops
        err += float(np.einsum("fni,fni,n->", d, d, masses))
    return err


def subspace_report(model: Model, data: TrainingData) -> dict[str, Any]:
    """The learned subspace against the POD bound of its own size, in the model's frame.

    Both subspaces hold the exact affine modes plus r more: the model's learned modes,
    or the first r mass-orthonormal POD modes of ``data``'s training residuals (plain POD,
    every frame weighted the same: the best r-dimensional subspace for those frames). For each split the error is
    ``sqrt(sum_f ||u_f - P u_f||_M^2 / sum_f ||u_f||_M^2)`` with ``u_f`` the displacement
    in the data's frame, i.e. in the body frame the non-rigid deformation only (the
    rigid part is exact there, and the affine part is exact in both subspaces).

    Args:
        model: a trained model on ``data``'s rest mesh and in ``data``'s frame.
        data: training data (the POD is fitted to its training frames; its held-out
            frames are the test).

    Returns:
        ``{"frame", "r", "train": {"frames", "model", "pod"}, "val": {...}, "ratio"}``
        where ``ratio`` is the held-out model error over the POD error (training
        frames when nothing is held out); the bound asks for ``ratio <= 1.2``.

    Raises:
        ConfigError: another mesh, frame or affine setting than the model's.
    """
    if model.mesh.n_vertices != data.mesh.n_vertices or not np.allclose(model.mesh.vertices, data.rest):
        raise ConfigError("subspace_report needs data on the model's rest mesh")
    if model.frame != data.frame or model.affine != data.affine:
        raise ConfigError(f"subspace_report needs data in the model's frame and affine setting: model {model.frame!r}/"
                          f"affine={model.affine}, data {data.frame!r}/affine={data.affine}")
    r = model.n_learned
    learned = model.values(data.rest)[:, :, model.n_affine :]
    pod = pod_targets(data, r, "frame")[0]  # the best r-dimensional subspace for the frames, whatever the training weighted
    out: dict[str, Any] = {"frame": data.frame, "r": r}
    for split, frames in (("train", data.train), ("val", data.val)):
        total = float(frames.norm2_full.sum()) if len(frames) else 0.0
        row: dict[str, Any] = {"frames": len(frames)}
        for name, basis in (("model", learned), ("pod", np.moveaxis(pod, 0, 2))):
            err = _projection_error2(frames.residuals, basis, data.masses) if len(frames) else 0.0
            row[name] = float(np.sqrt(err / total)) if total > 0 else float("nan")
        out[split] = row
    side = out["val"] if len(data.val) else out["train"]
    out["ratio"] = side["model"] / side["pod"] if side["pod"] > 0 else float("nan")
    return out


class _FramesView:
    """A TrainingData-like view holding one frame set as its training side (for :func:`evaluate`)."""

    def __init__(self, data: TrainingData, frames: Any) -> None:
        self.mesh = data.mesh
        self.rest = data.rest
        self.masses = data.masses
        self.train = frames
        self.val = None
