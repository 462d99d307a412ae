"""The networks: the neural field W(X) (5-layer ELU MLP, C^1 in X) and the PointNet encoder P(X, u) -> z."""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence

import numpy as np
import torch
from torch import nn

from ...errors import ConfigError
from ...subspace.affine import N_AFFINE, affine_values
from .config import ModelConfig

__all__ = ["LicromNet", "NeuralField", "PointNetEncoder", "state_size"]


def _xavier(module: nn.Module) -> None:
    for m in module.modules():
        if isinstance(m, nn.Linear):
            nn.init.xavier_uniform_(m.weight)
            nn.init.zeros_(m.bias)


def _mlp_size(dims: Sequence[int]) -> int:
    return sum(a * b + b for a, b in itertools.pairwise(dims))


def state_size(config: ModelConfig) -> int:
    """Numbers in ``LicromNet(config).state_dict()``, computed without building (allocating) the networks."""
    f, r = config.fourier_features, config.latent_dim
    field = _mlp_size([3 + 2 * f] + [config.field_width] * (config.field_layers - 1) + [3 * r]) + 3 * f
    encoder = _mlp_size([6, *config.encoder_point_widths, *config.encoder_fc_widths, r])
    return field + encoder + 5  # + x_center (3), x_scale, u_scale


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
        if config.latent_dim == "auto":
            raise ConfigError("ModelConfig.latent_dim is 'auto': the network needs r, chosen from the data by licrom.train "
                              "(licrom.learn.training.rank.choose_rank); give an integer to build it directly")
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
