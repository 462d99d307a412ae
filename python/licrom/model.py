"""Learned continuous subspaces (LiCROM): PointNet encoder, neural field W(X), the model file.

A trained :class:`Model` is a *basis* for the reduced simulation: the displacement
of any material point ``X`` of the rest shape is ``u(X) = B(X) q`` with

    B(X) = [A(X) | W(X)]    (3 x (12 + r)),

where ``A`` holds the 12 affine modes and ``W`` the ``r`` learned modes. The
column order of the affine modes is fixed: for ``c`` in ``0..8`` mode ``c`` is
``X_j e_i`` with ``(i, j) = divmod(c, 3)`` (entry ``F_ij`` of a linear map),
then modes 9, 10, 11 are the translations ``e_0, e_1, e_2``.

The learned modes are the network's field after two exact linear changes made
once at the end of training (they do not change the span of ``[A | W]``):

* the part of each learned column that the affine modes explain on the rest
  mesh is removed (``W' = W_net - A C``), so the learned modes are
  mass-orthogonal to the affine ones;
* the columns are rotated and scaled (``W = W' T``) to be mass-orthogonal with
  ``W^T M W = m_total I`` and ordered by the variance they carry over the
  training frames (mode 0 first). A latent coordinate is then the mass-weighted
  RMS displacement, in m, that its mode contributes.

This keeps the reduced mass matrix ``M_r = B^T M B`` well conditioned.

A model lives in one of two frames (:attr:`Model.frame`):

* ``"world"`` (LiCROM as published): the modes are world-frame displacement
  fields and the basis is ``[A | W]`` as above;
* ``"body"`` (the default for new models): each training frame's rigid part
  (centre of mass and polar rotation) was removed first, so ``W`` spans the
  non-rigid deformation seen in the body frame. :meth:`Model.values` and
  :meth:`Model.jacobians` then return the ``r`` learned modes only; the rigid
  motion and the symmetric affine modes are added by
  :class:`licrom.body_frame.BodyFrameBasis`, which the reduced simulation of a
  body-frame model uses. The learned modes are still mass-orthogonal to all 12
  affine modes, hence to the 6 rigid ones.

Torch is needed to evaluate a model; the file itself is a plain ``.npz`` with a
JSON header (no pickle) and loads without the training data.
"""

from __future__ import annotations

import copy
import math
import os
import time
import warnings
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from ._io import load_npz, save_npz
from .affine import AFFINE_JACOBIAN, N_AFFINE, affine_values, apply_affine, fit_affine, remove_affine_part
from .errors import ConfigError, FileFormatError, ShapeError
from .mesh import Mesh
from .rigid import check_frame
from .scene import Scene

__all__ = [
    "MODEL_FORMAT_VERSION",
    "LicromNet",
    "Model",
    "ModelConfig",
    "NeuralField",
    "PointNetEncoder",
]

# Version 2 records the frame; version 1 files are world-frame models.
MODEL_FORMAT_VERSION = 2
_READABLE_VERSIONS = (1, 2)
# Points evaluated per batch by values()/jacobians() (bounds peak memory, not speed).
_CHUNK = 16384


# ----------------------------------------------------------------------------------------
# configuration
# ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ModelConfig:
    """Sizes of the LiCROM networks.

    Attributes:
        latent_dim: r, the number of learned modes (the latent size), >= 1.
        field_layers: number of linear layers of the neural field W(X) (input 3, then
            ``field_layers - 1`` hidden ELU layers, then the 3 r output), >= 2.
            5 layers of width 60 is LiCROM's network.
        field_width: width of the hidden layers of W(X). The default 256: every learned
            mode is a combination of the last hidden layer's functions, and with the
            POD objective (whose output layer is solved exactly) width 60 left 1.6x and
            width 128 1.2x the held-out projection error of POD(8) on the demo data,
            width 256 1.01x (body frame, 60 epochs).
        fourier_features: F, random Fourier features of X fed to W(X) beside X itself
            (0: LiCROM's plain input). The default 32 learned the cheese set's subspace
            2-3x more accurately per epoch than 0 (benches/training_report.py sweep).
        fourier_scale: standard deviation of the Fourier frequencies, in cycles per unit
            of normalised coordinate (the object spans about [-1, 1]).
        encoder_point_widths: widths of the shared per-point MLP of the PointNet
            encoder (applied to each sampled (X, u) point, ELU after each layer),
            before max pooling over the points.
        encoder_fc_widths: widths of the fully connected ELU layers after pooling;
            a last linear layer maps to r.
        affine: remove the affine part of every training frame and keep the learned
            modes mass-orthogonal to the 12 affine modes (True), or learn the whole
            displacement (False). In the world frame the 12 affine modes are stacked in
            front of the learned ones.
        frame: ``"body"``: the modes learn the non-rigid deformation in the body frame
            (rigid motion exact, see :mod:`licrom.body_frame`); ``"world"``: LiCROM's
            world-frame displacement modes.
    """

    latent_dim: int = 20
    field_layers: int = 5
    field_width: int = 256
    fourier_features: int = 32
    fourier_scale: float = 1.0
    encoder_point_widths: tuple[int, ...] = (64, 128, 256)
    encoder_fc_widths: tuple[int, ...] = (128,)
    affine: bool = True
    frame: str = "body"

    def __post_init__(self) -> None:
        def positive_int(name: str, v: Any, minimum: int = 1) -> int:
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < minimum:
                raise ConfigError(f"ModelConfig.{name} must be an integer >= {minimum}, got {v!r}")
            return int(v)

        object.__setattr__(self, "latent_dim", positive_int("latent_dim", self.latent_dim))
        object.__setattr__(self, "field_layers", positive_int("field_layers", self.field_layers, 2))
        object.__setattr__(self, "field_width", positive_int("field_width", self.field_width))
        object.__setattr__(self, "fourier_features", positive_int("fourier_features", self.fourier_features, 0))
        fs = self.fourier_scale
        if isinstance(fs, bool) or not isinstance(fs, (int, float, np.floating)) or not np.isfinite(fs) or fs <= 0:
            raise ConfigError(f"ModelConfig.fourier_scale must be a positive number, got {fs!r}")
        object.__setattr__(self, "fourier_scale", float(fs))
        for name in ("encoder_point_widths", "encoder_fc_widths"):
            v = getattr(self, name)
            try:
                widths = tuple(v)
            except TypeError:
                raise ConfigError(f"ModelConfig.{name} must be a sequence of integers, got {v!r}") from None
            widths = tuple(positive_int(name, w) for w in widths)
            if name == "encoder_point_widths" and not widths:
                raise ConfigError("ModelConfig.encoder_point_widths needs at least one layer")
            object.__setattr__(self, name, widths)
        if not isinstance(self.affine, (bool, np.bool_)):
            raise ConfigError(f"ModelConfig.affine must be True or False, got {self.affine!r}")
        object.__setattr__(self, "affine", bool(self.affine))
        check_frame(self.frame, "ModelConfig.frame")

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["encoder_point_widths"] = list(self.encoder_point_widths)
        d["encoder_fc_widths"] = list(self.encoder_fc_widths)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ModelConfig:
        try:
            return cls(**d)
        except TypeError as exc:
            raise ConfigError(f"unknown or missing ModelConfig fields: {exc}") from exc


# ----------------------------------------------------------------------------------------
# networks
# ----------------------------------------------------------------------------------------
def _xavier(module: nn.Module) -> None:
    for m in module.modules():
        if isinstance(m, nn.Linear):
            nn.init.xavier_uniform_(m.weight)
            nn.init.zeros_(m.bias)


class NeuralField(nn.Module):
    """W(X): an MLP ``R^3 -> R^(3 r)`` with ELU activations (C^1 in X), Xavier initialised.

    Takes normalised points (..., 3) and returns (..., 3, r). With ``fourier_features``
    F > 0 the MLP reads ``[X, sin(2 pi B X), cos(2 pi B X)]`` (3 + 2F inputs) with a fixed
    random ``B`` (F x 3, entries N(0, fourier_scale^2), a buffer saved with the weights):
    smooth (C^inf) and a remedy for the MLP's bias towards low frequencies.
    """

    def __init__(self, latent_dim: int, layers: int = 5, width: int = 60, fourier_features: int = 0, fourier_scale: float = 1.0) -> None:
        super().__init__()
        self.latent_dim = latent_dim
        self.register_buffer("fourier_matrix", torch.randn(fourier_features, 3) * fourier_scale)
        dims = [3 + 2 * fourier_features] + [width] * (layers - 1) + [3 * latent_dim]
        mods: list[nn.Module] = []
        for k in range(layers):
            mods.append(nn.Linear(dims[k], dims[k + 1]))
            if k < layers - 1:
                mods.append(nn.ELU())
        self.mlp = nn.Sequential(*mods)
        _xavier(self)

    def hidden(self, x: torch.Tensor) -> torch.Tensor:
        """The last hidden layer's output (..., width) at normalised points (..., 3)."""
        if self.fourier_matrix.shape[0]:
            p = (2.0 * math.pi) * (x @ self.fourier_matrix.T)
            x = torch.cat([x, torch.sin(p), torch.cos(p)], dim=-1)
        return self.mlp[:-1](x)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        out = self.mlp[-1](self.hidden(x))
        return out.reshape(*x.shape[:-1], 3, self.latent_dim)


class PointNetEncoder(nn.Module):
    """PointNet without input/feature transform nets: shared per-point MLP, max pooling, FC.

    Takes a batch of point clouds (B, P, 6) of normalised (X, u) and returns z (B, r).
    The per-point layers are ``nn.Linear`` applied to the last axis (the same as a
    kernel-1 ``Conv1d``).
    """

    def __init__(self, latent_dim: int, point_widths: Sequence[int] = (64, 128, 256), fc_widths: Sequence[int] = (128,), in_dim: int = 6) -> None:
        super().__init__()
        pts: list[nn.Module] = []
        d = in_dim
        for w in point_widths:
            pts += [nn.Linear(d, w), nn.ELU()]
            d = w
        self.point_mlp = nn.Sequential(*pts)
        fc: list[nn.Module] = []
        for w in fc_widths:
            fc += [nn.Linear(d, w), nn.ELU()]
            d = w
        fc.append(nn.Linear(d, latent_dim))
        self.head = nn.Sequential(*fc)
        _xavier(self)

    def forward(self, cloud: torch.Tensor) -> torch.Tensor:
        feat = self.point_mlp(cloud)  # (B, P, C)
        return self.head(feat.amax(dim=-2))


class LicromNet(nn.Module):
    """Encoder + neural field, with the normalisation statistics as buffers.

    Normalised coordinates: ``X^ = (X - x_center) / x_scale``, ``u^ = u / u_scale``.
    The raw learned field in metres is ``W_raw(X) = u_scale * field(X^)`` and the
    encoder maps a cloud of ``(X^, u^)`` to ``z`` with ``u ~ W_raw(X) z``.
    """

    def __init__(self, config: ModelConfig) -> None:
        super().__init__()
        self.config = config
        self.encoder = PointNetEncoder(config.latent_dim, config.encoder_point_widths, config.encoder_fc_widths)
        self.field = NeuralField(config.latent_dim, config.field_layers, config.field_width, config.fourier_features, config.fourier_scale)
        self.register_buffer("x_center", torch.zeros(3))
        self.register_buffer("x_scale", torch.ones(()))
        self.register_buffer("u_scale", torch.ones(()))

    def set_normalization(self, x_center: np.ndarray, x_scale: float, u_scale: float) -> None:
        with torch.no_grad():
            self.x_center.copy_(torch.as_tensor(np.asarray(x_center), dtype=self.x_center.dtype))
            self.x_scale.fill_(float(x_scale))
            self.u_scale.fill_(float(u_scale))

    def normalize(self, points: torch.Tensor) -> torch.Tensor:
        return (points - self.x_center) / self.x_scale

    def encode_normalized(self, points: torch.Tensor, displacements: torch.Tensor) -> torch.Tensor:
        """z (B, r) from raw points (B, P, 3) or (P, 3) shared by the batch, and residual
        displacements (B, P, 3) in m."""
        xh = self.normalize(points)
        if xh.dim() == 2:
            xh = xh.expand(displacements.shape[0], -1, -1)
        cloud = torch.cat([xh, displacements / self.u_scale], dim=-1)
        return self.encoder(cloud)

    def reconstruct_normalized(self, points: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        """Normalised displacement ``field(X^) z`` (B, P, 3) for points (B, P, 3) or (P, 3), z (B, r)."""
        phi = self.field(self.normalize(points))
        if phi.dim() == 3:  # points shared by the batch: one field evaluation
            return torch.einsum("pir,br->bpi", phi, z)
        return torch.einsum("bpir,br->bpi", phi, z)

    def nonaffine_field(self, points: torch.Tensor) -> torch.Tensor:
        """field(X^) (P, 3, r) at points (P, 3) minus its least-squares affine part over those points.

        With the affine modes on, the targets have no affine part, and a learned column
        that is (nearly) affine would get no gradient: it would stay a dead mode. Taking
        the affine part out of the field at the loss points removes that plateau and
        matches the final basis, whose learned modes are made mass-orthogonal to the
        affine modes (the points are drawn uniformly in volume, so the uniform
        least squares here estimates the mass-weighted one).
        """
        xh = self.normalize(points)
        phi = self.field(xh)
        if not self.config.affine:
            return phi
        r = phi.shape[-1]
        a = affine_values(xh).reshape(-1, N_AFFINE)
        gram = a.T @ a + 1e-9 * len(xh) * torch.eye(N_AFFINE, dtype=a.dtype, device=a.device)
        c = torch.linalg.solve_ex(gram, a.T @ phi.reshape(-1, r))[0]
        return (phi.reshape(-1, r) - a @ c).reshape(phi.shape)

    def forward(self, points: torch.Tensor, displacements: torch.Tensor, encoder_points: int | None = None, projection_weight: float = 0.0) -> torch.Tensor:
        """Training loss: MSE of the reconstructed normalised residual displacement.

        Args:
            points: (P, 3) loss points, shared by every frame of the batch.
            displacements: (B, P, 3) residual displacements at those points, m.
            encoder_points: feed only the first this many points to the encoder
                (the loss still uses all P); None: all.
            projection_weight: add this times the MSE of the least-squares projection
                of the targets onto the field at the loss points (trains the span of W
                directly; 0 is plain LiCROM).
        """
        k = displacements.shape[1] if encoder_points is None else min(encoder_points, displacements.shape[1])
        z = self.encode_normalized(points[:k], displacements[:, :k])
        phi = self.nonaffine_field(points)
        target = displacements / self.u_scale
        loss = torch.mean((torch.einsum("pir,br->bpi", phi, z) - target) ** 2)
        if projection_weight > 0:
            flat = phi.reshape(-1, phi.shape[-1])
            gram = flat.T @ flat
            gram = gram + 1e-8 * gram.diagonal().mean().clamp(min=1e-30) * torch.eye(len(gram), dtype=gram.dtype, device=gram.device)
            zp = torch.linalg.solve_ex(gram, flat.T @ target.reshape(len(target), -1).T)[0].T
            loss = loss + projection_weight * torch.mean((torch.einsum("pir,br->bpi", phi, zp) - target) ** 2)
        return loss

    def raw_field(self, points: torch.Tensor) -> torch.Tensor:
        """W_raw (p, 3, r) in metres per unit z at raw points (p, 3)."""
        return self.u_scale * self.field(self.normalize(points))


# ----------------------------------------------------------------------------------------
# the model: a basis, an encoder, a file
# ----------------------------------------------------------------------------------------
def _as_points(points: Any, name: str = "points") -> np.ndarray:
    x = np.asarray(points, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != 3:
        raise ShapeError(f"{name} must have shape (p, 3), got {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ShapeError(f"{name} holds NaN or inf")
    return x


@dataclass
class _Finalization:
    """Exact linear post-processing of the raw field: ``W = (W_raw - A C) T``."""

    affine_correction: np.ndarray  # (12, r) C (zeros without affine modes)
    transform: np.ndarray  # (r, r) T
    transform_inv: np.ndarray  # (r, r) T^-1
    mode_variance: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (r,) variance per final mode over training frames


class Model:
    """A trained LiCROM subspace; also a basis for the reduced simulation.

    Build one with :func:`licrom.train` or :meth:`Model.load`. Evaluation runs in
    float64 on the CPU by default (:meth:`to` moves it to a GPU).

    Attributes:
        config: the network sizes.
        mesh: the rest mesh trained on.
        scenes: the scenes of the training trajectories.
        default_scene: the scene a reduced simulation of this model uses by default.
        metadata: JSON-ready training information (data, split, losses, timings, ...).
    """

    def __init__(
        self,
        net: LicromNet,
        mesh: Mesh,
        scenes: Sequence[Scene] = (),
        *,
        finalization: _Finalization | None = None,
        default_scene_index: int = 0,
        metadata: dict[str, Any] | None = None,
    ) -> None:
        if not isinstance(net, LicromNet):
            raise ConfigError(f"Model needs a LicromNet, got {type(net).__name__}")
        if not isinstance(mesh, Mesh):
            raise ConfigError(f"Model needs a Mesh, got {type(mesh).__name__}")
        self.config: ModelConfig = net.config
        r = self.config.latent_dim
        self.mesh = mesh
        self.scenes: list[Scene] = list(scenes)
        if self.scenes and not 0 <= default_scene_index < len(self.scenes):
            raise ConfigError(f"default_scene_index {default_scene_index} out of range for {len(self.scenes)} scenes")
        self._default_index = int(default_scene_index)
        self.metadata: dict[str, Any] = dict(metadata or {})
        if finalization is None:
            finalization = _Finalization(np.zeros((N_AFFINE, r)), np.eye(r), np.eye(r), np.zeros(r))
        if finalization.affine_correction.shape != (N_AFFINE, r) or finalization.transform.shape != (r, r):
            raise ShapeError("model finalization arrays do not match the latent size")
        self._fin = finalization
        self._device = torch.device("cpu")
        self._net32 = net  # as trained (float32), kept for saving
        self._build_eval_net()
        self._vertex_cache: dict[str, Any] = {}

    # --- construction helpers -------------------------------------------------------
    def _build_eval_net(self) -> None:
        net = copy.deepcopy(self._net32).to(device=self._device, dtype=torch.float64)
        net.eval()
        for p in net.parameters():
            p.requires_grad_(False)
        self._net = net
        dev = self._device
        self._C = torch.as_tensor(self._fin.affine_correction, dtype=torch.float64, device=dev)
        self._T = torch.as_tensor(self._fin.transform, dtype=torch.float64, device=dev)
        self._Tinv = torch.as_tensor(self._fin.transform_inv, dtype=torch.float64, device=dev)
        self._dA = torch.tensor(AFFINE_JACOBIAN, dtype=torch.float64, device=dev)

    def to(self, device: str | torch.device) -> Model:
        """Evaluate on ``device`` ("cpu", "cuda", ...) from now on; returns self."""
        self._device = torch.device(device)
        self._build_eval_net()
        return self

    # --- basic properties -----------------------------------------------------------
    @property
    def affine(self) -> bool:
        """Whether the learned modes are mass-orthogonal to the 12 affine modes (affine part removed in training)."""
        return self.config.affine

    @property
    def frame(self) -> str:
        """``"world"`` or ``"body"``: the frame the modes live in (see the module docstring)."""
        return self.config.frame

    @property
    def n_learned(self) -> int:
        """r, the number of learned modes."""
        return self.config.latent_dim

    @property
    def n_affine(self) -> int:
        """Affine modes stacked in front of the learned ones: 12 for an affine world-frame model, else 0."""
        return N_AFFINE if self.affine and self.frame == "world" else 0

    @property
    def n_modes(self) -> int:
        """Total number of modes: 12 + r (affine world-frame model) or r."""
        return self.n_affine + self.n_learned

    @property
    def default_scene(self) -> Scene:
        """The scene a reduced simulation uses unless told otherwise (the first training scene)."""
        if not self.scenes:
            return Scene()
        return self.scenes[self._default_index]

    @property
    def normalization(self) -> dict[str, Any]:
        """Input centre (m), input scale (m) and output scale (m) used by the networks."""
        return {
            "x_center": self._net32.x_center.detach().cpu().numpy().astype(np.float64).tolist(),
            "x_scale": float(self._net32.x_scale),
            "u_scale": float(self._net32.u_scale),
        }

    @property
    def mode_variance(self) -> np.ndarray:
        """(r,) mean squared latent coordinate of each learned mode over the training frames, m^2."""
        return self._fin.mode_variance.copy()

    @property
    def net(self) -> LicromNet:
        """The trained float32 networks (encoder and field)."""
        return self._net32

    def __repr__(self) -> str:
        return f"Model(frame={self.frame!r}, n_learned={self.n_learned}, affine={self.affine}, n_modes={self.n_modes}, mesh={self.mesh!r})"

    # --- the learned field ------------------------------------------------------------
    def _learned_values_t(self, x: torch.Tensor) -> torch.Tensor:
        w = self._net.raw_field(x)
        if self.affine:
            w = w - torch.einsum("pic,cr->pir", affine_values(x), self._C)
        return w @ self._T

    def _learned_jacobians_t(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Values (p, 3, r) and Jacobians (p, 3, 3, r) of the learned modes at raw points x."""
        from torch.func import jacfwd, vmap

        net = self._net

        def f(xh: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
            out = net.field(xh)  # (3, r)
            return out, out

        xh = net.normalize(x)
        with warnings.catch_warnings():
            # torch builds its forward-mode decompositions with the deprecated torch.jit.script
            # on first use; that warning is about torch's internals, not about this call.
            warnings.filterwarnings("ignore", message=".*torch.jit.script.*", category=FutureWarning)
            jac, val = vmap(jacfwd(f, has_aux=True))(xh)  # jac (p, 3, r, 3): d out_ic / d xh_j
        val = net.u_scale * val
        jac = (net.u_scale / net.x_scale) * jac.permute(0, 1, 3, 2)  # (p, 3, 3, r): [i, j, c]
        if self.affine:
            val = val - torch.einsum("pic,cr->pir", affine_values(x), self._C)
            jac = jac - torch.einsum("ijc,cr->ijr", self._dA, self._C)[None]
        return val @ self._T, jac @ self._T

    def values(self, points: Any) -> np.ndarray:
        """(p, 3, n_modes) float64 basis values ``B(X)`` at points (p, 3); affine modes first (world frame).

        For a body-frame model these are the r learned body-frame displacement fields.
        """
        x = _as_points(points)
        out = np.empty((len(x), 3, self.n_modes))
        if self.n_affine:
            out[:, :, :N_AFFINE] = affine_values(x)
        with torch.no_grad():
            for s in range(0, len(x), _CHUNK):
                xt = torch.tensor(x[s : s + _CHUNK], device=self._device)
                out[s : s + _CHUNK, :, self.n_affine :] = self._learned_values_t(xt).cpu().numpy()
        return out

    def jacobians(self, points: Any) -> np.ndarray:
        """(p, 3, 3, n_modes) float64 ``J[p, i, j, c] = d B_ic / d X_j`` at points (p, 3).

        ``F = I + sum_c J[:, :, :, c] q_c`` is the deformation gradient of ``u = B q``.
        """
        return self.values_and_jacobians(points)[1]

    def values_and_jacobians(self, points: Any) -> tuple[np.ndarray, np.ndarray]:
        """Both :meth:`values` and :meth:`jacobians` in one pass."""
        x = _as_points(points)
        vals = np.empty((len(x), 3, self.n_modes))
        jacs = np.empty((len(x), 3, 3, self.n_modes))
        if self.n_affine:
            vals[:, :, :N_AFFINE] = affine_values(x)
            jacs[:, :, :, :N_AFFINE] = AFFINE_JACOBIAN
        with torch.no_grad():
            for s in range(0, len(x), _CHUNK):
                xt = torch.tensor(x[s : s + _CHUNK], device=self._device)
                v, j = self._learned_jacobians_t(xt)
                vals[s : s + _CHUNK, :, self.n_affine :] = v.cpu().numpy()
                jacs[s : s + _CHUNK, :, :, self.n_affine :] = j.cpu().numpy()
        return vals, jacs

    # --- projection onto the subspace ---------------------------------------------------
    def _vertex_system(self, mesh: Mesh | None) -> tuple[Mesh, np.ndarray, np.ndarray, Any]:
        """Basis at the vertices of ``mesh`` (default: the model mesh), its masses and M_r's factor."""
        import scipy.linalg

        m = self.mesh if mesh is None else mesh
        key = "model" if mesh is None else str(id(mesh))
        hit = self._vertex_cache.get(key)
        if hit is not None and hit[0] is m:
            return hit
        masses = m.vertex_masses(1.0)  # relative weights; a homogeneous density cancels
        basis = self.values(m.vertices)  # (n, 3, k)
        flat = basis.reshape(-1, self.n_modes)
        mr = flat.T @ (np.repeat(masses, 3)[:, None] * flat)
        try:
            factor = scipy.linalg.cho_factor(mr)
        except np.linalg.LinAlgError as exc:
            raise ShapeError(f"the reduced mass matrix of this basis is singular on this mesh ({exc})") from exc
        entry = (m, basis, masses, factor)
        if mesh is None or len(self._vertex_cache) < 4:
            self._vertex_cache[key] = entry
        return entry

    def project(self, displacements: Any, mesh: Mesh | None = None) -> np.ndarray:
        """Exact mass-weighted projection ``q = M_r^-1 B^T M u`` onto the subspace.

        Args:
            displacements: (n, 3) or (f, n, 3) vertex displacements of ``mesh`` in m
                (body-frame displacements for a body-frame model).
            mesh: the mesh they live on; default the model's rest mesh. Any mesh of the
                same object works (the basis is continuous).

        Returns:
            (n_modes,) or (f, n_modes) reduced coordinates.
        """
        import scipy.linalg

        m, basis, masses, factor = self._vertex_system(mesh)
        u = np.asarray(displacements, dtype=np.float64)
        single = u.ndim == 2
        if single:
            u = u[None]
        if u.ndim != 3 or u.shape[1:] != (m.n_vertices, 3):
            raise ShapeError(f"displacements must have shape (n, 3) or (f, n, 3) with n = {m.n_vertices}, got {np.shape(displacements)}")
        rhs = np.einsum("nic,n,fni->cf", basis, masses, u)
        q = scipy.linalg.cho_solve(factor, rhs).T
        return q[0] if single else q

    def reconstruct(self, q: Any, mesh: Mesh | None = None) -> np.ndarray:
        """Vertex displacements ``B q`` (n, 3) or (f, n, 3) of the model mesh (or ``mesh``)."""
        _m, basis, _, _ = self._vertex_system(mesh)
        qa = np.asarray(q, dtype=np.float64)
        if qa.shape[-1] != self.n_modes or qa.ndim not in (1, 2):
            raise ShapeError(f"q must have shape ({self.n_modes},) or (f, {self.n_modes}), got {qa.shape}")
        return np.einsum("nic,...c->...ni", basis, qa)

    # --- encoder ------------------------------------------------------------------------
    def _split_affine(self, x: np.ndarray, u: np.ndarray, weights: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """``(affine coefficients in q, residual)`` of a world-frame field, as in training."""
        if not self.affine and self.frame == "world":
            return np.zeros(0), u
        w = np.ones(len(x)) if weights is None else np.asarray(weights, dtype=np.float64)
        if w.shape != (len(x),) or np.any(w < 0) or not np.isfinite(w).all() or w.sum() <= 0:
            raise ShapeError(f"weights must be ({len(x)},) non-negative and not all zero")
        if self.frame == "body":
            from .rigid import body_frame_displacements

            u = body_frame_displacements(x + u, x, w)
        if not self.affine:
            return np.zeros(0), u
        a = fit_affine(x, u, w)
        return a[: self.n_affine], u - apply_affine(x, a)

    def encode(self, points: Any, displacements: Any, weights: Any = None) -> np.ndarray:
        """Latent z (r,) of the learned modes from a displacement field sampled at points.

        The affine part is first removed by a weighted least-squares fit (``weights``:
        (p,) lumped masses of the points, default uniform; for the model mesh's own
        vertices the masses are used automatically), then the PointNet encoder maps
        the cloud of (X, residual) to z. A body-frame model first removes the best
        rigid fit (the same weights), as in training. Use :meth:`encode_q` for the full ``q``.

        Args:
            points: (p, 3) rest positions X in m (any sampling of the object).
            displacements: (p, 3) world-frame displacements u at those points in m.
            weights: optional (p,) weights of the affine fit.
        """
        return self.encode_q(points, displacements, weights)[self.n_affine :]

    def encode_q(self, points: Any, displacements: Any, weights: Any = None) -> np.ndarray:
        """Reduced coordinates (n_modes,): ``[a; z]`` (world frame: the affine fit, then :meth:`encode`) or ``z`` (body frame)."""
        x = _as_points(points)
        u = _as_points(displacements, "displacements")
        if u.shape != x.shape:
            raise ShapeError(f"points and displacements must have the same shape, got {x.shape} and {u.shape}")
        if weights is None and x.shape == self.mesh.vertices.shape and np.array_equal(x, self.mesh.vertices):
            weights = self.mesh.vertex_masses(1.0)
        a, res = self._split_affine(x, u, weights)
        with torch.no_grad():
            xt = torch.tensor(x, device=self._device)[None]
            ut = torch.tensor(res, device=self._device)[None]
            z_raw = self._net.encode_normalized(xt, ut)[0]
            z = (self._Tinv @ z_raw).cpu().numpy()
        return np.concatenate([a, z])

    # --- file ---------------------------------------------------------------------------
    def save(self, path: str | os.PathLike) -> Path:
        """Write the model to one file atomically (``.npz`` container, JSON header, no pickle).

        Any file name works; ``.lcm`` is the conventional extension.
        """
        p = Path(path)
        state = self._net32.state_dict()
        arrays: dict[str, np.ndarray] = {f"net/{k}": v.detach().cpu().numpy() for k, v in state.items()}
        arrays.update(
            rest_vertices=np.asarray(self.mesh.vertices),
            tets=np.asarray(self.mesh.tets),
            affine_correction=self._fin.affine_correction,
            mode_transform=self._fin.transform,
            mode_transform_inv=self._fin.transform_inv,
            mode_variance=self._fin.mode_variance,
        )
        header = {
            "kind": "model",
            "version": MODEL_FORMAT_VERSION,
            "model_config": self.config.to_dict(),
            "n_learned": self.n_learned,
            "affine": self.affine,
            "frame": self.frame,
            "normalization": self.normalization,
            "scenes": [s.to_dict() for s in self.scenes],
            "default_scene": self._default_index,
            "state_keys": sorted(state.keys()),
            "metadata": self.metadata,
            "saved_at": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            "torch_version": torch.__version__,
        }
        save_npz(p, arrays, header)
        return p

    @classmethod
    def load(cls, path: str | os.PathLike) -> Model:
        """Read a model written by :meth:`save` (no training data needed).

        Version 1 files (before the frame was recorded) load as world-frame models.

        Raises:
            FileFormatError: missing, truncated or foreign file, unknown format version,
                or incomplete/inconsistent contents.
        """
        header, arrays = load_npz(path, "model")
        version = header.get("version")
        if version not in _READABLE_VERSIONS:
            raise FileFormatError(
                f"model '{path}' has format version {version!r}; this licrom reads versions {', '.join(map(str, _READABLE_VERSIONS))}"
            )
        try:
            config_dict = dict(header["model_config"])
            if version == 1:
                config_dict["frame"] = "world"
            config = ModelConfig.from_dict(config_dict)
            if (int(header["n_learned"]) != config.latent_dim or bool(header["affine"]) != config.affine
                    or header.get("frame", "world") != config.frame):
                raise FileFormatError(f"model '{path}' header is inconsistent (n_learned/affine/frame vs model_config)")
            net = LicromNet(config)
            keys = header["state_keys"]
            state = {}
            for k in keys:
                state[k] = torch.from_numpy(np.ascontiguousarray(arrays[f"net/{k}"]))
            net.load_state_dict(state, strict=True)
            mesh = Mesh(arrays["rest_vertices"], arrays["tets"], fix_orientation=False)
            scenes = [Scene.from_dict(s) for s in header["scenes"]]
            fin = _Finalization(
                np.asarray(arrays["affine_correction"], dtype=np.float64),
                np.asarray(arrays["mode_transform"], dtype=np.float64),
                np.asarray(arrays["mode_transform_inv"], dtype=np.float64),
                np.asarray(arrays.get("mode_variance", np.zeros(config.latent_dim)), dtype=np.float64),
            )
            net.eval()
            return cls(net, mesh, scenes, finalization=fin, default_scene_index=int(header.get("default_scene", 0)), metadata=header.get("metadata", {}))
        except FileFormatError:
            raise
        except (KeyError, TypeError, ValueError, RuntimeError, ConfigError) as exc:
            raise FileFormatError(f"model '{path}' is incomplete or inconsistent: {type(exc).__name__}: {exc}") from exc


# ----------------------------------------------------------------------------------------
# finalisation at the end of training
# ----------------------------------------------------------------------------------------
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

