"""What a training run does (:class:`TrainConfig`) and where it writes."""

from __future__ import annotations

import csv
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..._io import atomic_path
from ..._limits import blame, check_memory, format_size
from ...errors import ConfigError
from ...subspace.cubature import FIT_TOLERANCE
from ..model.config import _SIZES as _MODEL_SIZES
from ..model.config import ModelConfig, field_floats_per_point, model_sizes, network_weights
from .dynamics import DEFAULT_DYNAMICS_MAX_RANK
from .rank import DEFAULT_MAX_RANK, DEFAULT_TOLERANCE

OBJECTIVES = ("pod", "autoencoder")
POD_WEIGHTINGS = ("run", "frame")


@dataclass(frozen=True)
class TrainConfig:
    """Training options.

    Attributes:
        objective: ``"pod"`` (regress the field onto the POD modes of the training
            residuals, the encoder onto their coordinates; one SVD of the training
            residuals before the first step) or ``"autoencoder"`` (LiCROM's joint
            training); see the module docstring.
        pod_weighting: how the ``"pod"`` objective weights the training frames: ``"run"``
            (a run that deforms a lot counts little more than a gentle one,
            :func:`licrom.subspace.basis.run_balanced_weights`: a few such runs no longer take the
            modes the gentle ones need) or
            ``"frame"`` (every frame counts the same: plain POD, the best subspace for the
            frames' summed squared error).
        epochs: passes over the training frames, or ``"auto"``: 200, and 800 on a mesh above 5000 tets
            (:func:`licrom.learn.training.dynamics.default_epochs`).
        batch_frames: frames per optimisation step (each frame is one point cloud).
        points_per_frame: points sampled per step, shared by the frames of the step
            (the loss points; the field is evaluated once per step). More do not shorten a large
            mesh's training: on the 104k-tet ball at r = 250, 2048, 8192 and 32768 ended at
            1.35x, 1.34x and 1.34x POD after 300 epochs (docs/results.md section 43).
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
        nodes: machines of a multi-node DDP run (Lightning's ``num_nodes``), each with
            ``devices`` GPUs; the launcher (torchrun, SLURM, or ``MASTER_ADDR``,
            ``MASTER_PORT``, ``NODE_RANK`` set on each machine) places the processes.
        join_timeout_s: seconds the processes of a run of several (``nodes`` or ``devices``
            > 1) wait for each other to join before a ConfigError naming the address and
            the processes missing (Lightning would wait 30 minutes). On one machine, where the
            other processes start only when this one reaches the fit and run the command
            again from its start, twice this process's age is added
            (:func:`licrom.learn.training.run.join_timeout_s`).
        precision: Lightning precision string (``"32-true"``; ``"bf16-mixed"`` on GPUs).
        cuda_graph: replay each training step's forward and backward pass from a CUDA graph where training runs
            on one GPU at 32-bit precision with the ``"pod"`` objective (:mod:`licrom.learn.training.step_graph`);
            elsewhere, or with False, every step runs eagerly. The optimiser and its schedule are unchanged.
        checkpoint_dir: Lightning checkpoints; default ``<model>.checkpoints`` beside the model.
        checkpoint_every: epochs between checkpoints (``last.ckpt`` is overwritten).
        resume: continue from the most recently written checkpoint of the same run (data, r,
            network) in the checkpoint directory; another run's is refused by name
            (:mod:`licrom.learn.training.checkpoints`).
        progress: show Lightning's progress bar.
        num_threads: CPU threads for torch (None: leave torch's setting).
        max_time_s: stop (gracefully, after the current step) when training has run this
            many seconds; None: no limit. The schedule still assumes ``epochs``.
        cubature_tolerance: relative force residual at which the cubature fitted at the end
            of training stops adding tets (:meth:`licrom.Cubature.fitted`).
        cubature_points: most tets of that cubature, or ``"auto"``: 1000, and on a mesh above 5000 tets a fit
            of 1000 and one of 3000, keeping the one whose held-out runs land nearer their targets
            (:func:`licrom.learn.training.dynamics.cubature_counts`; the fit of 3000 where no run is held out).
        cubature_candidates: tets that fit chooses from, a random pool of the mesh's (None: as many as
            :data:`licrom.subspace.cubature.FIT_MEMORY` holds, :func:`licrom.subspace.cubature.fit_candidates`, and 8192
            on a mesh above 5000 tets, :func:`licrom.learn.training.dynamics.fit_pool`).
            Where the fit stops above its tolerance with fewer tets than ``cubature_points``, the pool is its limit.
        cubature_samples: most training poses (frames, evenly spaced over the runs) it is
            fitted to; the fit holds ``8 * samples * (modes + 6)`` bytes per candidate tet, at most
            :data:`licrom.subspace.cubature.FIT_MEMORY` (1 GiB) in all (fewer candidates on large meshes).
        rank_tolerance: with ``ModelConfig.latent_dim="auto"``, r is the smallest whose
            held-out relative projection error (leave training runs out) is at most this
            (:func:`licrom.learn.training.rank.choose_rank`).
        max_rank: the largest r chosen automatically.
        dynamics_max_rank: with ``latent_dim="auto"`` (body frame), the largest r to which replays of
            training runs on POD(r) may raise the projection's choice
            (:func:`licrom.learn.training.dynamics.check_dynamics`); 0 (or at most ``max_rank``): no replays.
        extension: when the learned subspace's projection error ends above 1.05x that of
            the POD it is trained towards, training goes on once for ``extension * epochs``
            more epochs (at least 1); 0: never.
    """

    objective: str = "pod"
    pod_weighting: str = "run"
    epochs: int | str = "auto"
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
    nodes: int = 1
    join_timeout_s: float = 120.0
    precision: str = "32-true"
    cuda_graph: bool = True
    checkpoint_dir: str | None = None
    checkpoint_every: int = 1
    resume: bool = False
    progress: bool = True
    num_threads: int | None = None
    max_time_s: float | None = None
    cubature_tolerance: float = FIT_TOLERANCE
    cubature_points: int | str = "auto"
    cubature_candidates: int | None = None
    cubature_samples: int = 256
    rank_tolerance: float = DEFAULT_TOLERANCE
    max_rank: int = DEFAULT_MAX_RANK
    dynamics_max_rank: int = DEFAULT_DYNAMICS_MAX_RANK
    extension: float = 0.5

    def __post_init__(self) -> None:
        for name in ("epochs", "cubature_points"):
            v = getattr(self, name)
            if v != "auto":
                if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                    raise ConfigError(f"TrainConfig.{name} must be an integer >= 1 or 'auto', got {v!r}")
                object.__setattr__(self, name, int(v))
        for name in ("batch_frames", "points_per_frame", "encoder_points", "val_points", "val_encoder_frames", "val_every", "frame_stride", "checkpoint_every", "nodes",
                     "cubature_samples", "max_rank"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise ConfigError(f"TrainConfig.{name} must be an integer >= 1, got {v!r}")
            object.__setattr__(self, name, int(v))
        for name in ("lr", "lr_final_ratio"):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise ConfigError(f"TrainConfig.{name} must be a positive number, got {v!r}")
        for name in ("weight_decay", "projection_weight", "extension"):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not 0 <= v < math.inf:
                raise ConfigError(f"TrainConfig.{name} must be a number >= 0, got {v!r}")
        v = self.dynamics_max_rank
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 0:
            raise ConfigError(f"TrainConfig.dynamics_max_rank must be an integer >= 0 (0: no replays), got {v!r}")
        object.__setattr__(self, "dynamics_max_rank", int(v))
        v = self.cubature_candidates
        if v is not None:
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise ConfigError(f"TrainConfig.cubature_candidates must be an integer >= 1 or None (as many as the fit's memory holds), got {v!r}")
            object.__setattr__(self, "cubature_candidates", int(v))
        if not isinstance(self.cubature_tolerance, (int, float)) or not 0.0 < self.cubature_tolerance < 1.0:
            raise ConfigError(f"TrainConfig.cubature_tolerance must be a number in (0, 1), got {self.cubature_tolerance!r}")
        tol = self.rank_tolerance
        if isinstance(tol, bool) or not isinstance(tol, (int, float)) or not 0 < tol < 1:
            raise ConfigError(f"TrainConfig.rank_tolerance must be a relative error in (0, 1), got {tol!r}")
        if not 0.0 <= self.val_fraction < 1.0:
            raise ConfigError(f"TrainConfig.val_fraction must be in [0, 1), got {self.val_fraction!r}")
        if self.val_indices is not None:
            object.__setattr__(self, "val_indices", tuple(int(i) for i in self.val_indices))
        if self.objective not in OBJECTIVES:
            raise ConfigError(f"TrainConfig.objective must be one of {', '.join(repr(o) for o in OBJECTIVES)}, got {self.objective!r}")
        if self.pod_weighting not in POD_WEIGHTINGS:
            raise ConfigError(f"TrainConfig.pod_weighting must be one of {', '.join(repr(w) for w in POD_WEIGHTINGS)}, got {self.pod_weighting!r}")
        if self.sample not in ("tets", "vertices"):
            raise ConfigError(f"TrainConfig.sample must be 'tets' or 'vertices', got {self.sample!r}")
        if self.device not in ("auto", "cpu", "cuda"):
            raise ConfigError(f"TrainConfig.device must be 'auto', 'cpu' or 'cuda', got {self.device!r}")
        if not (self.devices == "auto" or (isinstance(self.devices, int) and self.devices >= 1)):
            raise ConfigError(f"TrainConfig.devices must be 'auto' or an integer >= 1, got {self.devices!r}")
        if not isinstance(self.seed, (int, np.integer)) or isinstance(self.seed, bool) or self.seed < 0:
            raise ConfigError(f"TrainConfig.seed must be an integer >= 0, got {self.seed!r}")
        jt = self.join_timeout_s
        if isinstance(jt, bool) or not isinstance(jt, (int, float)) or not 0 < jt < math.inf:
            raise ConfigError(f"TrainConfig.join_timeout_s must be a finite number of seconds > 0, got {jt!r}")
        if self.max_time_s is not None and (not isinstance(self.max_time_s, (int, float)) or not self.max_time_s > 0):
            raise ConfigError(f"TrainConfig.max_time_s must be None or a positive number of seconds, got {self.max_time_s!r}")
        if not isinstance(self.cuda_graph, bool):
            raise ConfigError(f"TrainConfig.cuda_graph must be True or False, got {self.cuda_graph!r}")
        if self.num_threads is not None and (not isinstance(self.num_threads, int) or self.num_threads < 1):
            raise ConfigError(f"TrainConfig.num_threads must be None or an integer >= 1, got {self.num_threads!r}")

        # The training step's buffers with the smallest network: a lower bound for every ModelConfig
        # (check_training_memory adds the network's share once it is known).
        sizes = {**_SMALLEST_NETWORK, **{name: getattr(self, name) for name in _TRAIN_SIZES}, "objective": self.objective}
        _check_step(sizes, {"TrainConfig": self}, _TRAIN_SIZES, "with the smallest network")

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        if d["val_indices"] is not None:
            d["val_indices"] = list(d["val_indices"])
        return d


# The TrainConfig sizes that multiply a step's buffers, with their defaults (an estimate falls back to them
# when it names the culprit).
_TRAIN_SIZES = {"points_per_frame": 2048, "batch_frames": 16, "encoder_points": 512, "val_points": 512, "val_encoder_frames": 256}
# r = 1, one hidden layer of width 1, no Fourier features, one encoder layer of width 1: TrainConfig alone is
# checked with it.
_SMALLEST_NETWORK = {"latent_dim": 1, "field_layers": 2, "field_width": 1, "fourier_features": 0,
                     "encoder_point_widths": (1,), "encoder_fc_widths": ()}
# Bytes per point of a step: the point, its tet's 4 vertices (int64), barycentric weights and their temporaries.
_BYTES_PER_POINT = 256
# Bytes per (frame, point) of a step: 4 vertex displacements (float32) interpolated, the target, the
# reconstruction and the loss terms, with their gradients.
_BYTES_PER_FRAME_POINT = 128
# Frames encoded at once in validation (licrom.learn.training.evaluation._encode_frames).
_VAL_CHUNK = 64
# Bytes per network weight while training: float32 weight, gradient and Adam's two moments, a checkpoint's
# copy, the float64 copy of finalisation (an upper estimate).
_BYTES_PER_WEIGHT = 40


def _step_bytes(s: Mapping[str, Any]) -> int:
    """Bytes a training run of sizes ``s`` holds at once: a step's sampled points, the field with its
    gradients at them, the encoder's activations, the validation batch and the weights (Python ints: no overflow)."""
    points, frames = s["points_per_frame"], s["batch_frames"]
    enc = min(s["encoder_points"], points)
    field = 8 * field_floats_per_point(s)  # float32, forward and backward
    encoder = 6 + 2 * sum(s["encoder_point_widths"])
    total = points * (_BYTES_PER_POINT + field) + frames * points * _BYTES_PER_FRAME_POINT + frames * enc * 8 * encoder
    if s["objective"] == "pod":  # the POD modes interpolated at the points, their loss terms
        total += 96 * s["latent_dim"] * points
    val, val_frames = s["val_points"], s["val_encoder_frames"]
    total += val_frames * val * 64 + min(val_frames, _VAL_CHUNK) * val * 4 * encoder + val * field
    return total + _BYTES_PER_WEIGHT * network_weights(s)


def _check_step(sizes: dict[str, Any], configs: Mapping[str, Any], baseline: Mapping[str, Any], network: str) -> None:
    culprit = blame(_step_bytes, sizes, baseline)
    owner = next(name for name, cfg in configs.items() if hasattr(cfg, culprit))
    others = ", ".join(f"{k}={format_size(sizes[k])}" for k in _TRAIN_SIZES if k != culprit)
    check_memory(f"{owner}.{culprit}", getattr(configs[owner], culprit), _step_bytes(sizes),
                 f"the training step's points, frames and validation batch with {others}, {network}")


def check_training_memory(config: TrainConfig, model_config: ModelConfig) -> None:
    """Raise ConfigError when a training run of these configs would need more than the memory limit.

    TrainConfig and ModelConfig each check their own sizes; this checks them together (many points
    through a wide field), before any data is read or any network built. ``latent_dim="auto"`` counts
    as r = 1 (a lower bound: r is chosen from the data).

    Raises:
        ConfigError: naming the size that weighs most, the estimate and the limit
            (:mod:`licrom._limits`: a fraction of the physical memory, or ``LICROM_MEMORY_LIMIT``).
    """
    sizes = {**model_sizes(model_config), **{name: getattr(config, name) for name in _TRAIN_SIZES}, "objective": config.objective}
    _check_step(sizes, {"TrainConfig": config, "ModelConfig": model_config}, {**_TRAIN_SIZES, **_MODEL_SIZES}, "the network as given")


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
