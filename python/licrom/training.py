"""Training of the learned subspace with PyTorch Lightning.

``licrom.train(data, "model.lcm")`` loads the trajectories, splits them by
trajectory, removes each frame's rigid part (body frame, the default) and its
affine part, and fits the PointNet encoder and the neural field W(X) (Adam,
exponentially decaying learning rate, float32). Each step draws
``batch_frames`` frames and ``points_per_frame`` points per frame, uniformly in
volume (random points in random tets, the displacement interpolated linearly),
so the loss estimates the mass-weighted L2 error of the continuous field. The
sampling runs on the training device from a generator seeded by (seed, step),
so a run is the same twice on the CPU and a resumed run draws the same points.

Two objectives (``TrainConfig.objective``):

* ``"pod"`` (default): the field is regressed onto the r mass-orthonormal POD
  modes of the training residuals (sampled at the same random points), and the
  encoder onto each frame's POD coordinates. The field stays continuous and
  differentiable in X, so the model still transfers to other meshes, and its
  span approaches POD(r) of the training frames, the best r-dimensional
  subspace for them: this is how the learned subspace reaches the POD bound
  (:func:`subspace_report`). Adam brings the field's hidden layers close, then the
  output layer (linear in its weights) is solved exactly by mass-weighted least
  squares at the vertices. On the demo data (r = 8, body frame, held-out scenes)
  this left 1.01x the projection error of POD(8) after 60 epochs and 1.02x after
  30, where the autoencoder left 1.9x (same field, 60 epochs): a supervised fit
  to a known target converges in CPU minutes, the autoencoder's search does not.
* ``"autoencoder"``: LiCROM's joint encoder/field training (plus the optional
  projection loss), kept for comparison.

Every epoch the held-out trajectories are evaluated exactly: the relative
mass-weighted L2 error of the projection onto ``[affine | W]`` at all vertices,
and of the encoder's reconstruction. Written next to the model file
``model.lcm``: ``model.losses.csv`` (one row per epoch), ``model.losses.png``,
and Lightning checkpoints in ``model.checkpoints/`` (``last.ckpt`` for resume).

Several GPUs train through Lightning's DDP (one process per GPU). Lightning
starts the other processes by re-running the command that called ``train``, so
call it from a script or the ``licrom train`` command, once per process.
"""

from __future__ import annotations

import copy
import csv
import dataclasses
import math
import os
import time
import warnings
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ._io import atomic_path
from .affine import remove_affine_part
from .basis import MeshBasis, SubspaceProjector
from .errors import ConfigError, ShapeError
from .model import LicromNet, Model, ModelConfig, finalize_basis
from .render import pyplot, save_png
from .rigid import check_frame
from .training_data import TrainingData, TrajectorySource

__all__ = ["OBJECTIVES", "TrainConfig", "evaluate", "output_paths", "plot_losses", "subspace_report", "train"]

OBJECTIVES = ("pod", "autoencoder")


@dataclass(frozen=True)
class TrainConfig:
    """Training options.

    Attributes:
        objective: ``"pod"`` (regress the field onto the POD modes of the training
            residuals, the encoder onto their coordinates; one SVD of the training
            residuals before the first step) or ``"autoencoder"`` (LiCROM's joint
            training); see the module docstring.
        epochs: passes over the training frames.
        batch_frames: frames per optimisation step (each frame is one point cloud).
        points_per_frame: points sampled per step, shared by the frames of the step
            (the loss points; the field is evaluated once per step).
        encoder_points: how many of those points each frame's encoder sees.
        lr: initial Adam learning rate (3e-3 beat LiCROM's 1e-3 in the sweep).
        lr_final_ratio: the learning rate decays exponentially, per epoch, to
            ``lr * lr_final_ratio`` at the last epoch.
        weight_decay: Adam weight decay (L2), 0 for none.
        projection_weight: weight of an extra loss term, the MSE of the least-squares
            projection of each frame onto the field at the step's points; it trains the
            span of W directly, next to LiCROM's encoder loss (0: plain LiCROM; the
            default 1 lowered the held-out projection error at equal epochs). Used by
            the ``"autoencoder"`` objective only.
        val_fraction: fraction of the trajectories held out whole for validation.
        val_indices: explicit held-out trajectory indices (into the sorted file list);
            overrides ``val_fraction``.
        val_points: points per frame fed to the encoder during validation (one fixed draw).
        val_encoder_frames: at most this many held-out frames (evenly spaced) are encoded
            each validation (the projection error always uses every held-out frame).
        val_every: validate every this many epochs (and after the last).
        frame_stride: keep every ``frame_stride``-th frame of each trajectory.
        sample: where points are drawn: ``"tets"`` (uniform in volume, displacement
            interpolated in the tet) or ``"vertices"`` (vertices with probability
            proportional to their lumped mass).
        seed: seed of the weights, the split and the point sampling.
        device: ``"auto"`` (CUDA if available), ``"cpu"`` or ``"cuda"``.
        devices: GPUs to use (``"auto"``: all visible); more than one trains with DDP.
        precision: Lightning precision string (``"32-true"``; ``"bf16-mixed"`` on GPUs).
        checkpoint_dir: Lightning checkpoints; default ``<model>.checkpoints`` beside the model.
        checkpoint_every: epochs between checkpoints (``last.ckpt`` is overwritten).
        resume: continue from ``last.ckpt`` in the checkpoint directory when it exists.
        progress: show Lightning's progress bar.
        num_threads: CPU threads for torch (None: leave torch's setting).
        max_time_s: stop (gracefully, after the current step) when training has run this
            many seconds; None: no limit. The schedule still assumes ``epochs``.
    """

    objective: str = "pod"
    epochs: int = 200
    batch_frames: int = 16
    points_per_frame: int = 2048
    encoder_points: int = 512
    lr: float = 3e-3
    lr_final_ratio: float = 0.05
    weight_decay: float = 0.0
    projection_weight: float = 1.0
    val_fraction: float = 0.2
    val_indices: tuple[int, ...] | None = None
    val_points: int = 512
    val_encoder_frames: int = 256
    val_every: int = 1
    frame_stride: int = 1
    sample: str = "tets"
    seed: int = 0
    device: str = "auto"
    devices: int | str = "auto"
    precision: str = "32-true"
    checkpoint_dir: str | None = None
    checkpoint_every: int = 1
    resume: bool = False
    progress: bool = True
    num_threads: int | None = None
    max_time_s: float | None = None

    def __post_init__(self) -> None:
        for name in ("epochs", "batch_frames", "points_per_frame", "encoder_points", "val_points", "val_encoder_frames", "val_every", "frame_stride", "checkpoint_every"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise ConfigError(f"TrainConfig.{name} must be an integer >= 1, got {v!r}")
            object.__setattr__(self, name, int(v))
        for name in ("lr", "lr_final_ratio"):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise ConfigError(f"TrainConfig.{name} must be a positive number, got {v!r}")
        for name in ("weight_decay", "projection_weight"):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not 0 <= v < math.inf:
                raise ConfigError(f"TrainConfig.{name} must be a number >= 0, got {v!r}")
        if not 0.0 <= self.val_fraction < 1.0:
            raise ConfigError(f"TrainConfig.val_fraction must be in [0, 1), got {self.val_fraction!r}")
        if self.val_indices is not None:
            object.__setattr__(self, "val_indices", tuple(int(i) for i in self.val_indices))
        if self.objective not in OBJECTIVES:
            raise ConfigError(f"TrainConfig.objective must be one of {', '.join(repr(o) for o in OBJECTIVES)}, got {self.objective!r}")
        if self.sample not in ("tets", "vertices"):
            raise ConfigError(f"TrainConfig.sample must be 'tets' or 'vertices', got {self.sample!r}")
        if self.device not in ("auto", "cpu", "cuda"):
            raise ConfigError(f"TrainConfig.device must be 'auto', 'cpu' or 'cuda', got {self.device!r}")
        if not (self.devices == "auto" or (isinstance(self.devices, int) and self.devices >= 1)):
            raise ConfigError(f"TrainConfig.devices must be 'auto' or an integer >= 1, got {self.devices!r}")
        if not isinstance(self.seed, (int, np.integer)) or isinstance(self.seed, bool) or self.seed < 0:
            raise ConfigError(f"TrainConfig.seed must be an integer >= 0, got {self.seed!r}")
        if self.max_time_s is not None and (not isinstance(self.max_time_s, (int, float)) or not self.max_time_s > 0):
            raise ConfigError(f"TrainConfig.max_time_s must be None or a positive number of seconds, got {self.max_time_s!r}")
        if self.num_threads is not None and (not isinstance(self.num_threads, int) or self.num_threads < 1):
            raise ConfigError(f"TrainConfig.num_threads must be None or an integer >= 1, got {self.num_threads!r}")

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        if d["val_indices"] is not None:
            d["val_indices"] = list(d["val_indices"])
        return d


def output_paths(out_path: str | os.PathLike) -> dict[str, Path]:
    """Files written beside a model file: loss CSV, loss plot, checkpoint directory."""
    p = Path(out_path)
    stem = p.with_suffix("") if p.suffix else p
    return {
        "model": p,
        "csv": stem.with_name(stem.name + ".losses.csv"),
        "png": stem.with_name(stem.name + ".losses.png"),
        "checkpoints": stem.with_name(stem.name + ".checkpoints"),
    }


# ----------------------------------------------------------------------------------------
# tensors on the training device
# ----------------------------------------------------------------------------------------
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


def pod_targets(data: TrainingData, count: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Regression targets of the ``"pod"`` objective from the training residuals of ``data``.

    Returns:
        ``(modes, latents, weights)``: the ``count`` POD modes (count, n, 3), scaled to a
        mass-weighted mean ``|phi|^2`` of 1 (the normalised field's target); each training
        frame's coordinates (F, count) divided by ``u_scale`` (the encoder's target, so
        that ``u ~ u_scale * sum_k z_k phi_k``); and the weight of each mode in the field
        loss (count,), proportional to the RMS of its coordinate, mean 1.

    Raises:
        ConfigError: ``count`` exceeds the number of training frames (or 3 n).
    """
    res = data.train.residuals
    try:
        basis, _ = MeshBasis.pod(data.mesh, res, count)
    except ShapeError as exc:
        raise ConfigError(f"the 'pod' objective needs latent_dim <= the number of training frames ({len(res)}): {exc}") from exc
    m = data.mesh.vertex_masses(1.0)
    modes = basis.modes * np.sqrt(m.sum())  # (n, 3, r): sum_v m_v |phi_v|^2 = m_total
    latents = np.einsum("fni,n,nic->fc", res.astype(np.float64), m, modes) / (m.sum() * data.u_scale)
    # sqrt(variance): the modes that carry more of the data count more, the small ones still
    # count (uniform weights left 2.1x, sqrt 1.6x, variance 2.1x the POD error on the demo data
    # at width 60, before the exact output-layer fit).
    weights = np.sqrt(np.mean(latents**2, axis=0))
    return np.ascontiguousarray(np.moveaxis(modes, 2, 0)), latents, weights * (count / max(weights.sum(), 1e-300))


@torch.no_grad()
def _refit_output_layer(net: LicromNet, data: TrainingData, modes: np.ndarray) -> None:
    """Solve the field's last linear layer for the POD modes (count, n, 3) at the vertices.

    The output layer is linear in its weights, so the mass-weighted least-squares fit
    of every mode on the trained hidden features is exact and cheap, where Adam on
    sampled points only approaches it; this finishes the ``"pod"`` objective.
    """
    field = net.field
    last = field.mlp[-1]
    dev, dtype = last.weight.device, last.weight.dtype
    hidden = field.hidden(net.normalize(torch.tensor(data.rest, dtype=dtype, device=dev))).double().cpu().numpy()
    design = np.concatenate([hidden, np.ones((len(hidden), 1))], axis=1)  # (n, width + 1)
    target = np.moveaxis(modes, 0, 2).reshape(len(hidden), -1)  # (n, 3 r): output i * r + c
    m = data.mesh.vertex_masses(1.0)
    gram = design.T @ (m[:, None] * design)
    gram += 1e-10 * np.trace(gram) / len(gram) * np.eye(len(gram))  # features may be (nearly) dependent
    coef = np.linalg.solve(gram, design.T @ (m[:, None] * target))
    last.weight.copy_(torch.as_tensor(coef[:-1].T, dtype=dtype, device=dev))
    last.bias.copy_(torch.as_tensor(coef[-1], dtype=dtype, device=dev))


def _pod_loss(net: LicromNet, points: torch.Tensor, displacements: torch.Tensor, mode_values: torch.Tensor,
              latents: torch.Tensor, weights: torch.Tensor, encoder_points: int) -> torch.Tensor:
    """Loss of the ``"pod"`` objective: weighted MSE of the normalised field against the POD
    modes at the points ``mode_values`` (r, P, 3), plus MSE of the encoder's latents (B, r)."""
    k = min(encoder_points, displacements.shape[1])
    z = net.encode_normalized(points[:k], displacements[:, :k])
    phi = net.field(net.normalize(points))  # (P, 3, r)
    field_loss = torch.mean((phi - mode_values.permute(1, 2, 0)) ** 2 * weights)
    return field_loss + torch.mean((z - latents) ** 2)


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
        d = u - np.einsum("nic,fc->fni", basis, projector.project(u))
        err += float(np.einsum("fni,fni,n->", d, d, masses))
    return err


def subspace_report(model: Model, data: TrainingData) -> dict[str, Any]:
    """The learned subspace against the POD bound of its own size, in the model's frame.

    Both subspaces hold the exact affine modes plus r more: the model's learned modes,
    or the first r mass-orthonormal POD modes of ``data``'s training residuals (the
    best r-dimensional subspace for those frames). For each split the error is
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
    pod = pod_targets(data, r)[0]
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


# ----------------------------------------------------------------------------------------
# Lightning pieces (imported lazily: lightning is heavy)
# ----------------------------------------------------------------------------------------
def _lightning_classes() -> dict[str, Any]:
    import lightning.pytorch as pl
    from torch.utils.data import Dataset, Sampler

    class Indices(Dataset):
        def __init__(self, n: int) -> None:
            self.n = n

        def __len__(self) -> int:
            return self.n

        def __getitem__(self, i: int) -> int:
            return i

    class EpochShuffle(Sampler):
        """A permutation drawn from (seed, epoch): the same order after a resume."""

        def __init__(self, n: int, seed: int) -> None:
            self.n, self.seed, self.epoch = n, seed, 0

        def set_epoch(self, epoch: int) -> None:
            self.epoch = epoch

        def __len__(self) -> int:
            return self.n

        def __iter__(self):
            g = torch.Generator()
            g.manual_seed(self.seed * 1_000_003 + self.epoch)
            return iter(torch.randperm(self.n, generator=g).tolist())

    class LicromModule(pl.LightningModule):
        def __init__(self, model_config: dict, train_config: dict) -> None:
            super().__init__()
            self.save_hyperparameters()
            self.mcfg = ModelConfig.from_dict(model_config)
            self.tcfg = TrainConfig(**{**train_config, "val_indices": train_config.get("val_indices")})
            self.net = LicromNet(self.mcfg)
            self._data: TrainingData | None = None
            self._pod: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
            self._bank: _Bank | None = None
            self._val_points: tuple[torch.Tensor, torch.Tensor] | None = None

        def attach(self, data: TrainingData) -> None:
            self._data = data
            if self.tcfg.objective == "pod":
                self._pod = pod_targets(data, self.mcfg.latent_dim)

        def setup(self, stage: str) -> None:
            self._bank = None  # built on the device at fit start

        def _ensure_bank(self) -> _Bank:
            if self._bank is None or self._bank.device != self.device:
                assert self._data is not None
                self._bank = _Bank(self._data, self.device, self._pod)
                self._val_points = None
            return self._bank

        def on_fit_start(self) -> None:
            self._ensure_bank()

        def training_step(self, batch: torch.Tensor, batch_idx: int) -> torch.Tensor:
            bank = self._ensure_bank()
            gen = torch.Generator(device=self.device)
            gen.manual_seed((self.tcfg.seed * 1_000_003 + self.global_step) * 64 + self.global_rank)
            x, verts, w = _sample_points(bank, self.tcfg.points_per_frame, self.tcfg.sample, gen)
            u = _interpolate(bank.train, batch, verts, w)
            if self.tcfg.objective == "pod":
                loss = _pod_loss(self.net, x, u, _interpolate(bank.pod_modes, None, verts, w), bank.pod_latents[batch],
                                 bank.pod_weights, self.tcfg.encoder_points)
            else:
                loss = self.net(x, u, self.tcfg.encoder_points, self.tcfg.projection_weight)
            self.log("train_loss", loss, on_step=False, on_epoch=True, prog_bar=True, batch_size=len(batch), sync_dist=True)
            return loss

        def validation_step(self, batch: Any, batch_idx: int) -> None:
            bank = self._ensure_bank()
            if bank.val is None:
                return
            if self.current_epoch % self.tcfg.val_every and self.current_epoch + 1 != self.tcfg.epochs:
                return
            if self._val_points is None:
                idx = torch.as_tensor(_encoder_frames(len(bank.val), self.tcfg.val_encoder_frames), device=self.device)
                self._val_points = (idx, self.tcfg.seed * 7 + 12345)
            idx, seed = self._val_points
            gen = torch.Generator(device=self.device)
            gen.manual_seed(seed)
            z, xs, us = _encode_frames(self.net, bank, bank.val, idx, self.tcfg.val_points, gen)
            phi = self.net.nonaffine_field(xs)
            val_loss = torch.mean((torch.einsum("pir,br->bpi", phi, z) - us / self.net.u_scale) ** 2)
            m = _evaluate_tensors(self.net, bank.rest64, bank.masses, bank.val, bank.val_norm2_res, bank.val_norm2_full, self.mcfg.affine, (idx, z))
            # Every rank evaluates the whole (small) validation set: identical values; the
            # sync (a mean of equal numbers) only keeps Lightning's bookkeeping consistent.
            sync = self.trainer.world_size > 1
            self.log("val_loss", val_loss, prog_bar=False, batch_size=1, sync_dist=sync)
            self.log("val_proj", m["proj_residual"], prog_bar=True, batch_size=1, sync_dist=sync)
            self.log("val_proj_full", m["proj_full"], batch_size=1, sync_dist=sync)
            self.log("val_enc", m["enc_residual"], prog_bar=True, batch_size=1, sync_dist=sync)
            self.log("val_enc_full", m["enc_full"], batch_size=1, sync_dist=sync)

        def configure_optimizers(self) -> Any:
            cfg = self.tcfg
            opt = torch.optim.Adam(self.net.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
            gamma = cfg.lr_final_ratio ** (1.0 / max(1, cfg.epochs - 1))
            sched = torch.optim.lr_scheduler.ExponentialLR(opt, gamma=gamma)
            return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "epoch"}}

    class History(pl.Callback):
        """Loss curves (one row per epoch), kept in checkpoints, written as CSV each epoch."""

        def __init__(self, csv_path: Path | None) -> None:
            self.csv_path = csv_path
            self.rows: list[dict[str, Any]] = []
            self._t0 = 0.0
            self._t_train = None
            self._lr = float("nan")

        @property
        def state_key(self) -> str:
            return "licrom.History"

        def state_dict(self) -> dict[str, Any]:
            return {"rows": self.rows}

        def load_state_dict(self, state: dict[str, Any]) -> None:
            self.rows = list(state.get("rows", []))

        def on_train_epoch_start(self, trainer, pl_module) -> None:
            self._t0 = time.perf_counter()
            self._t_train = None
            self._lr = float(trainer.optimizers[0].param_groups[0]["lr"])

        def on_validation_epoch_start(self, trainer, pl_module) -> None:
            if not trainer.sanity_checking and self._t_train is None:
                self._t_train = time.perf_counter() - self._t0

        def on_train_epoch_end(self, trainer, pl_module) -> None:
            now = time.perf_counter()
            m = trainer.callback_metrics
            get = lambda k: float(m[k]) if k in m else float("nan")  # noqa: E731
            row = {
                "epoch": trainer.current_epoch + 1,
                "train_loss": get("train_loss"),
                "val_loss": get("val_loss"),
                "val_proj_residual": get("val_proj"),
                "val_proj_full": get("val_proj_full"),
                "val_enc_residual": get("val_enc"),
                "val_enc_full": get("val_enc_full"),
                "lr": self._lr,
                "train_seconds": self._t_train if self._t_train is not None else now - self._t0,
                "epoch_seconds": now - self._t0,
            }
            self.rows = [r for r in self.rows if r["epoch"] < row["epoch"]] + [row]
            if trainer.is_global_zero and self.csv_path is not None:
                write_csv(self.csv_path, self.rows)

    return {"Indices": Indices, "EpochShuffle": EpochShuffle, "LicromModule": LicromModule, "History": History, "pl": pl}


CSV_COLUMNS = [
    "epoch", "train_loss", "val_loss", "val_proj_residual", "val_proj_full",
    "val_enc_residual", "val_enc_full", "lr", "train_seconds", "epoch_seconds",
]


def write_csv(path: Path, rows: Sequence[dict[str, Any]]) -> None:
    """Write loss-curve rows atomically."""
    with atomic_path(path) as tmp:
        with open(tmp, "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=CSV_COLUMNS)
            w.writeheader()
            for r in rows:
                w.writerow({k: r.get(k, "") for k in CSV_COLUMNS})


def plot_losses(rows: Sequence[dict[str, Any]], path: str | os.PathLike, title: str = "") -> Path:
    """PNG of the loss curves (train/val MSE and held-out relative errors) per epoch."""
    plt = pyplot()
    ep = [r["epoch"] for r in rows]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    ax = axes[0]
    ax.semilogy(ep, [r["train_loss"] for r in rows], label="train")
    if any(np.isfinite(r["val_loss"]) for r in rows):
        ax.semilogy(ep, [r["val_loss"] for r in rows], label="validation")
    ax.set_xlabel("epoch")
    ax.set_ylabel("MSE of normalised residual displacement")
    ax.legend()
    ax.grid(True, which="both", alpha=0.3)
    ax = axes[1]
    for key, label in (("val_proj_residual", "projection, residual"), ("val_enc_residual", "encoder, residual"),
                       ("val_proj_full", "projection, full"), ("val_enc_full", "encoder, full")):
        ys = [r[key] for r in rows]
        if any(np.isfinite(ys)):
            ax.semilogy(ep, ys, label=label)
    ax.axhline(0.01, color="k", lw=0.8, ls="--", label="1%")
    ax.set_xlabel("epoch")
    ax.set_ylabel("held-out relative L2 error")
    ax.legend()
    ax.grid(True, which="both", alpha=0.3)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return save_png(fig, path)


# ----------------------------------------------------------------------------------------
# the entry point
# ----------------------------------------------------------------------------------------
def _accelerator(cfg: TrainConfig) -> tuple[str, Any]:
    if cfg.device == "cpu":
        return "cpu", 1
    if cfg.device == "cuda" and not torch.cuda.is_available():
        raise ConfigError("TrainConfig.device is 'cuda' but no CUDA device is available (torch.cuda.is_available() is False)")
    if torch.cuda.is_available():
        return "gpu", cfg.devices
    return "cpu", 1


def train(
    data: TrajectorySource | TrainingData,
    out_path: str | os.PathLike | None,
    config: TrainConfig | None = None,
    model_config: ModelConfig | None = None,
    *,
    frame: str | None = None,
) -> Model:
    """Train a LiCROM subspace on full-simulation trajectories and save it.

    Args:
        data: a directory of trajectory files, a file, a list of files or
            :class:`~licrom.Trajectory` objects (one rest mesh), or a prepared
            :class:`~licrom.training_data.TrainingData` (its split is used as is).
        out_path: model file to write (``.lcm`` by convention), with the loss CSV, the
            loss plot and the checkpoint directory beside it (see :func:`output_paths`).
            ``None`` writes nothing (checkpoints off, no resume).
        config: training options.
        model_config: network sizes (r is ``model_config.latent_dim``) and the frame.
        frame: ``"body"`` or ``"world"``; when given it replaces ``model_config.frame``
            (default ``"body"``: the non-rigid deformation in the body frame).

    Returns:
        The trained :class:`~licrom.Model` (the same as ``Model.load(out_path)``).
    """
    cfg = config or TrainConfig()
    mcfg = model_config or ModelConfig()
    if not isinstance(cfg, TrainConfig):
        raise ConfigError(f"config must be a TrainConfig, got {type(cfg).__name__}")
    if not isinstance(mcfg, ModelConfig):
        raise ConfigError(f"model_config must be a ModelConfig, got {type(mcfg).__name__}")
    if frame is not None:
        mcfg = dataclasses.replace(mcfg, frame=check_frame(frame))
    if cfg.num_threads is not None:
        torch.set_num_threads(cfg.num_threads)
    t_start = time.perf_counter()
    if isinstance(data, TrainingData):
        if data.affine != mcfg.affine:
            raise ConfigError(f"TrainingData was prepared with affine={data.affine} but ModelConfig.affine is {mcfg.affine}")
        if data.frame != mcfg.frame:
            raise ConfigError(f"TrainingData is in the {data.frame!r} frame but the model is to be trained in the {mcfg.frame!r} frame")
        tdata = data
    else:
        tdata = TrainingData(data, val_fraction=cfg.val_fraction, seed=cfg.seed, val_indices=cfg.val_indices,
                             affine=mcfg.affine, frame_stride=cfg.frame_stride, frame=mcfg.frame)
    t_data = time.perf_counter() - t_start

    L = _lightning_classes()
    pl = L["pl"]
    paths = output_paths(out_path) if out_path is not None else None
    ckpt_dir = Path(cfg.checkpoint_dir) if cfg.checkpoint_dir else (paths["checkpoints"] if paths else None)

    pl.seed_everything(cfg.seed, workers=True, verbose=False)
    module = L["LicromModule"](mcfg.to_dict(), cfg.to_dict())
    module.net.set_normalization(tdata.x_center, tdata.x_scale, tdata.u_scale)
    module.attach(tdata)

    accelerator, devices = _accelerator(cfg)
    history = L["History"](paths["csv"] if paths else None)
    callbacks: list[Any] = [history]
    if ckpt_dir is not None:
        from lightning.pytorch.callbacks import ModelCheckpoint

        callbacks.append(ModelCheckpoint(dirpath=ckpt_dir, filename="epoch{epoch:04d}", auto_insert_metric_name=False,
                                         save_last=True, save_top_k=0, every_n_epochs=cfg.checkpoint_every))
    import logging

    quiet_loggers = [logging.getLogger(n) for n in ("lightning.pytorch.utilities.rank_zero", "lightning.pytorch.accelerators.cuda")]
    old_levels = [lg.level for lg in quiet_loggers]
    for lg in quiet_loggers:  # Lightning's notes on accelerators and add-ons say nothing about this run
        lg.setLevel(logging.WARNING)
    old_matmul = torch.get_float32_matmul_precision()
    if accelerator == "gpu":
        torch.set_float32_matmul_precision("high")
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*does not have many workers.*")
        warnings.filterwarnings("ignore", message=".*number of training batches.*")
        warnings.filterwarnings("ignore", message=".*LeafSpec.*")
        warnings.filterwarnings("ignore", message=".*no `val_dataloader`.*")
        trainer = pl.Trainer(
            accelerator=accelerator,
            devices=devices,
            strategy="auto",
            precision=cfg.precision,
            max_epochs=cfg.epochs,
            callbacks=callbacks,
            logger=False,
            enable_checkpointing=ckpt_dir is not None,
            enable_progress_bar=cfg.progress,
            enable_model_summary=False,
            num_sanity_val_steps=0,
            default_root_dir=str(ckpt_dir) if ckpt_dir else None,
            log_every_n_steps=1,
            max_time=None if cfg.max_time_s is None else {"seconds": float(cfg.max_time_s)},
        )
        n_train = len(tdata.train)
        from torch.utils.data import DataLoader

        batch = min(cfg.batch_frames, n_train)
        if trainer.world_size > 1:
            train_loader = DataLoader(L["Indices"](n_train), batch_size=batch, shuffle=True)
        else:
            train_loader = DataLoader(L["Indices"](n_train), batch_size=batch, sampler=L["EpochShuffle"](n_train, cfg.seed))
        val_loader = DataLoader(L["Indices"](1), batch_size=1) if len(tdata.val) else None
        ckpt_path = None
        if cfg.resume and ckpt_dir is not None and (ckpt_dir / "last.ckpt").is_file():
            ckpt_path = str(ckpt_dir / "last.ckpt")
        elif cfg.resume:
            warnings.warn(f"resume requested but no checkpoint found in '{ckpt_dir}'; training from scratch", stacklevel=2)
        t_fit = time.perf_counter()
        try:
            trainer.fit(module, train_dataloaders=train_loader, val_dataloaders=val_loader, ckpt_path=ckpt_path, weights_only=False)
        finally:
            torch.set_float32_matmul_precision(old_matmul)
            for lg, level in zip(quiet_loggers, old_levels):
                lg.setLevel(level)
        t_fit = time.perf_counter() - t_fit

    net = copy.deepcopy(module.net).to("cpu").float().eval()
    if cfg.objective == "pod":
        _refit_output_layer(net, tdata, module._pod[0])
    fin = finalize_basis(net, tdata.mesh, tdata.train.residuals)
    rows = history.rows
    last = rows[-1] if rows else {}
    train_secs = [r["train_seconds"] for r in rows if np.isfinite(r.get("train_seconds", np.nan))]
    reached = next((r["epoch"] for r in rows if r.get("val_proj_residual", np.inf) <= 0.01), None)
    metadata = {
        "data": tdata.summary(),
        "train_config": cfg.to_dict(),
        "epochs_trained": int(last.get("epoch", 0)),
        "final": {k: last.get(k) for k in CSV_COLUMNS if k != "epoch"},
        "epoch_to_1pct_val_projection": reached,
        "mean_train_seconds_per_epoch": float(np.mean(train_secs)) if train_secs else None,
        "fit_seconds": t_fit,
        "data_seconds": t_data,
        "accelerator": accelerator,
        "world_size": trainer.world_size,
        "torch_version": torch.__version__,
        "lightning_version": pl.__version__,
        "history": rows,
    }
    if cfg.objective == "pod" and len(tdata.val):
        # the output-layer fit changed the span after the last validation: report the final model's
        val = tdata.val
        metadata["final"].update({f"val_{k}": v for k, v in _evaluate_tensors(
            net, torch.tensor(tdata.rest), torch.tensor(tdata.masses), torch.as_tensor(val.residuals),
            torch.as_tensor(val.norm2_residual), torch.as_tensor(val.norm2_full), mcfg.affine).items()})
    model = Model(net, tdata.mesh, tdata.scenes, finalization=fin, default_scene_index=0 if not tdata.train_indices else tdata.train_indices[0], metadata=metadata)
    if paths is not None and trainer.is_global_zero:
        model.save(paths["model"])
        if rows:
            write_csv(paths["csv"], rows)
            try:
                plot_losses(rows, paths["png"], title=f"LiCROM r={mcfg.latent_dim}, {len(tdata.train_indices)} train / {len(tdata.val_indices)} held-out trajectories")
            except Exception as exc:  # a plot must never lose a trained model
                warnings.warn(f"could not write the loss plot: {exc}", stacklevel=2)
    return model
