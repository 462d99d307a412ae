"""Training checkpoints: written atomically, read without running code, resumed only into their own run.

A checkpoint is Lightning's (weights, optimiser, schedule, loop counters, loss history) plus,
under ``"licrom_run"``, the fingerprint of the run that wrote it: a hash of the training data
(rest mesh, frames and train/validation split), r and the network sizes. Checkpoints are read
with ``torch.load(weights_only=True)``, which restores tensors and plain containers only, so a
planted file cannot run code. A resume takes the most recently written checkpoint of the same
run in the checkpoint folder, and refuses, naming what differs, when every checkpoint there
belongs to another run.
"""

from __future__ import annotations

import hashlib
import os
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..._io import atomic_path
from ...errors import ConfigError, FileFormatError
from ..model import ModelConfig
from ..training_data import TrainingData

__all__ = ["RUN_KEY", "checkpoint_io", "read_checkpoint", "resume_checkpoint", "run_fingerprint"]

RUN_KEY = "licrom_run"
# How a user sets each network size (the ModelConfig field is named for the rest).
_FLAGS = {"field_width": "--width", "field_layers": "--layers", "fourier_features": "--fourier", "frame": "--frame"}
_AFRESH = "start afresh: run again without --resume (TrainConfig.resume=False), which overwrites the checkpoints"


def run_fingerprint(data: TrainingData, config: ModelConfig) -> dict[str, Any]:
    """What a resumed run must share with the checkpoint: ``{"data": hash, "r": r, "network": sizes}``."""
    digest = hashlib.blake2b(digest_size=16)
    for a in (data.rest, data.mesh.tets, data.train.residuals, data.val.residuals, data.train_indices, data.val_indices):
        arr = np.ascontiguousarray(a)
        digest.update(f"{arr.dtype.str}{arr.shape}".encode())
        digest.update(arr.reshape(-1).view(np.uint8))
    network = config.to_dict()
    r = network.pop("latent_dim")
    return {"data": digest.hexdigest(), "r": r, "network": network}


def _differences(found: Any, wanted: dict[str, Any]) -> list[str]:
    if not isinstance(found, dict):
        return ["it records no run (written by an older licrom or another program)"]
    out = []
    if found.get("data") != wanted["data"]:
        out.append("the training data differ (other trajectories or frames, or another train/validation split)")
    if found.get("r") != wanted["r"]:
        out.append(f"r differs: {found.get('r')!r} in the checkpoint, {wanted['r']} now (-r/--modes)")
    net = found.get("network") if isinstance(found.get("network"), dict) else {}
    for key, value in wanted["network"].items():
        if net.get(key) != value:
            flag = _FLAGS.get(key, f"ModelConfig.{key}")
            out.append(f"the network differs: {key} {net.get(key)!r} in the checkpoint, {value!r} now ({flag})")
    return out


def read_checkpoint(path: str | os.PathLike) -> dict[str, Any]:
    """Load a checkpoint on the CPU with ``weights_only=True`` (tensors and plain containers only).

    Raises:
        FileFormatError: truncated, corrupt, foreign, or holding anything but weights
            (e.g. code); the message says to start afresh.
    """
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # any failure of torch's reader means: not a readable checkpoint
        raise FileFormatError(f"checkpoint '{path}' is truncated, corrupt or not a licrom training checkpoint "
                              f"({type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}); {_AFRESH}") from exc
    if not isinstance(ckpt, dict) or "state_dict" not in ckpt:
        raise FileFormatError(f"checkpoint '{path}' is not a licrom training checkpoint; {_AFRESH}")
    return ckpt


def resume_checkpoint(folder: Path, fingerprint: dict[str, Any]) -> Path | None:
    """The most recently written checkpoint of this run in ``folder``; None when the folder holds none.

    Raises:
        ConfigError: every checkpoint there belongs to another run (the message says how it differs).
        FileFormatError: no checkpoint of this run is readable and some are truncated or corrupt.
    """
    paths = sorted(Path(folder).glob("*.ckpt")) if Path(folder).is_dir() else []
    if not paths:
        return None
    same, other, corrupt = [], [], []
    for path in paths:
        try:
            ckpt = read_checkpoint(path)
        except FileFormatError as exc:
            corrupt.append(exc)
            continue
        run = ckpt.get(RUN_KEY)
        saved = run.get("saved_at") if isinstance(run, dict) else None
        order = (saved if isinstance(saved, float) else path.stat().st_mtime, path.name)
        (same if not _differences(run, fingerprint) else other).append((order, path, run))
    if same:
        for exc in corrupt:
            warnings.warn(f"skipped: {exc}", stacklevel=3)
        return max(same, key=lambda e: e[0])[1]
    if corrupt:
        raise corrupt[0]
    _, path, run = max(other, key=lambda e: e[0])
    raise ConfigError(f"cannot resume from '{path}': it belongs to another training run: "
                      f"{'; '.join(_differences(run, fingerprint))}. Resume with the same data, -r and network, or {_AFRESH}")


def checkpoint_io(fingerprint: dict[str, Any]) -> Any:
    """Lightning's checkpoint I/O made atomic and weights-only, stamping ``fingerprint`` into every checkpoint."""
    from lightning.pytorch.plugins.io import TorchCheckpointIO

    class LicromCheckpointIO(TorchCheckpointIO):
        def save_checkpoint(self, checkpoint: dict[str, Any], path: Any, storage_options: Any = None) -> None:
            with atomic_path(path) as tmp:
                torch.save({**checkpoint, RUN_KEY: {**fingerprint, "saved_at": time.time()}}, tmp)

        def load_checkpoint(self, path: Any, map_location: Any = None, weights_only: bool | None = None) -> dict[str, Any]:
            return read_checkpoint(path)

    return LicromCheckpointIO()
