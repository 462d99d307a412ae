"""The POD objective: targets, loss, and the exact fit of the output layer."""

from __future__ import annotations

import numpy as np
import torch

from ...errors import ConfigError, ShapeError
from ...subspace.basis import MeshBasis, run_balanced_weights
from ..model import LicromNet
from ..training_data import TrainingData
from .config import POD_WEIGHTINGS


def pod_targets(data: TrainingData, count: int, weighting: str = "run") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Regression targets of the ``"pod"`` objective from the training residuals of ``data``.

    Args:
        data: the training data.
        count: number of modes.
        weighting: ``"run"`` (the training runs balanced in the POD,
            :func:`licrom.subspace.basis.run_balanced_weights`) or ``"frame"`` (plain POD).

    Returns:
        ``(modes, latents, weights)``: the ``count`` POD modes (count, n, 3), scaled to a
        mass-weighted mean ``|phi|^2`` of 1 (the normalised field's target); each training
        frame's coordinates (F, count) divided by ``u_scale`` (the encoder's target, so
        that ``u ~ u_scale * sum_k z_k phi_k``); and the weight of each mode in the field
        loss (count,), proportional to the RMS of its coordinate, mean 1.

    Raises:
        ConfigError: ``count`` exceeds the number of training frames (or 3 n), or an
            unknown ``weighting``.
    """
    if weighting not in POD_WEIGHTINGS:
        raise ConfigError(f"pod weighting must be one of {', '.join(repr(w) for w in POD_WEIGHTINGS)}, got {weighting!r}")
    res = data.train.residuals
    weights = run_balanced_weights(data.train.trajectory, data.train.norm2_residual) if weighting == "run" else None
    try:
        basis, _ = MeshBasis.pod(data.mesh, res, count, weights=weights)
    except ShapeError as exc:
        raise ConfigError(f"the 'pod' objective needs latent_dim <= the number of training frames ({len(res)}): {exc}") from exc
    m = data.mesh.vertex_masses(1.0)
    modes = basis.modes * np.sqrt(m.sum())  # (n, 3, r): sum_v m_v |phi_v|^2 = m_total
    # One matrix product (BLAS): numpy's einsum of the three operands looped over them, 76 s at 120k tets.
    weighted_modes = (modes * m[:, None, None]).reshape(-1, count)  # (3n, count)
    latents = (res.reshape(len(res), -1).astype(np.float64) @ weighted_modes) / (m.sum() * data.u_scale)
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
