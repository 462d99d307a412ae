"""The Lightning module, data loading and callbacks (built on first use: Lightning is heavy to import)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..model import LicromNet, ModelConfig
from ..training_data import TrainingData
from .config import TrainConfig, write_csv
from .evaluation import _encode_frames, _encoder_frames, _evaluate_tensors
from .objectives import _pod_loss, pod_targets
from .sampling import _Bank, _interpolate, _sample_points
from .step_graph import StepGraphs


def graph_steps(module: Any) -> bool:
    """Whether a fit of ``module`` (a ``LicromModule`` being fitted) replays its passes from CUDA graphs: where
    ``TrainConfig.cuda_graph`` is set, with the ``"pod"`` objective, on one CUDA device at 32-bit precision."""
    cfg, trainer = module.tcfg, module.trainer
    return bool(cfg.cuda_graph and cfg.objective == "pod" and module.device.type == "cuda" and trainer.world_size == 1
                and str(trainer.precision).startswith("32"))


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
            self._gen: torch.Generator | None = None
            # The epoch's loss, summed on the device: Lightning's per-step self.log cost about a third of a small
            # step's time (0.85 of 2.6 ms on the CPU) and it is read once an epoch.
            self._loss_sum: torch.Tensor | None = None
            self._loss_frames = 0
            self._graphs: StepGraphs | None = None

        def attach(self, data: TrainingData) -> None:
            self._data = data
            if self.tcfg.objective == "pod":
                self._pod = pod_targets(data, self.mcfg.latent_dim, self.tcfg.pod_weighting)

        def setup(self, stage: str) -> None:
            self._bank = None  # built on the device at fit start

        def _ensure_bank(self) -> _Bank:
            if self._bank is None or self._bank.device != self.device:
                assert self._data is not None
                self._bank = _Bank(self._data, self.device, self._pod)
                self._val_points = None
                self._gen = torch.Generator(device=self.device)
            return self._bank

        def on_train_epoch_start(self) -> None:
            self._loss_sum, self._loss_frames = None, 0

        def epoch_train_loss(self) -> float:
            """The mean training loss of the epoch so far over its frames (over every process), NaN before a step.

            Every process calls it at the epoch's end: with several, it is a collective.
            """
            if self._loss_sum is None:
                mean = torch.tensor(float("nan"), dtype=torch.float64, device=self.device)
            else:
                mean = self._loss_sum / self._loss_frames
            return float(self.trainer.strategy.reduce(mean, reduce_op="mean"))

        def on_fit_start(self) -> None:
            self._ensure_bank()
            # A fresh set of graphs each fit (an extension's fit loads its checkpoint into the same parameters).
            self._graphs = (StepGraphs(list(self.net.parameters()), self._step_loss, capture=self.device.type == "cuda")
                            if graph_steps(self) else None)

        @property
        def graphs_captured(self) -> int:
            """CUDA graphs the training steps of this fit replay (0: eager steps)."""
            return 0 if self._graphs is None else self._graphs.captured

        @property
        def graph_passes(self) -> int:
            """The fit's passes that went through :class:`StepGraphs` (replayed, or run by it without capture)."""
            return 0 if self._graphs is None else self._graphs.passes

        def _step_loss(self, batch: torch.Tensor, x: torch.Tensor, verts: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
            """The step's loss on the frames ``batch`` at the sampled points ``x`` (made from ``verts`` and ``w``)."""
            bank = self._bank
            assert bank is not None
            if self.tcfg.objective == "pod":
                # The encoder reads the first encoder_points points only: interpolating the frames' displacements
                # at all of them (16 frames x 2048 points) took a tenth of a step's time.
                k = self.tcfg.encoder_points
                u = _interpolate(bank.train, batch, verts[:k], w[:k])
                return _pod_loss(self.net, x, u, _interpolate(bank.pod_modes, None, verts, w), bank.pod_latents[batch],
                                 bank.pod_weights, self.tcfg.encoder_points)
            u = _interpolate(bank.train, batch, verts, w)
            return self.net(x, u, self.tcfg.encoder_points, self.tcfg.projection_weight)

        def optimizer_zero_grad(self, epoch: int, batch_idx: int, optimizer: Any) -> None:
            if self._graphs is None:  # a replayed pass zeroes the gradients it shares with the graph itself
                optimizer.zero_grad()

        def backward(self, loss: torch.Tensor, *args: Any, **kwargs: Any) -> None:
            if self._graphs is None:  # a replayed pass has run its backward already
                super().backward(loss, *args, **kwargs)

        def training_step(self, batch: torch.Tensor, batch_idx: int) -> torch.Tensor:
            bank = self._ensure_bank()
            gen = self._gen
            gen.manual_seed((self.tcfg.seed * 1_000_003 + self.global_step) * 64 + self.global_rank)
            x, verts, w = _sample_points(bank, self.tcfg.points_per_frame, self.tcfg.sample, gen)
            step = self._step_loss if self._graphs is None else self._graphs.loss
            loss = step(batch, x, verts, w)
            frames_loss = loss.detach().double() * len(batch)
            self._loss_sum = frames_loss if self._loss_sum is None else self._loss_sum + frames_loss
            self._loss_frames += len(batch)
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
            train_loss = pl_module.epoch_train_loss()
            pl_module.log("train_loss", train_loss, prog_bar=True, batch_size=1)  # for the progress bar
            m = trainer.callback_metrics
            get = lambda k: float(m[k]) if k in m else float("nan")  # noqa: E731
            row = {
                "epoch": trainer.current_epoch + 1,
                "train_loss": train_loss,
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

    from lightning.pytorch.callbacks import TQDMProgressBar

    class EpochBar(TQDMProgressBar):
        """Lightning's bar, counting epochs from 1 to their number ("Epoch 30/30", not "Epoch 29/29")."""

        def on_train_epoch_start(self, trainer, *args: Any) -> None:
            super().on_train_epoch_start(trainer, *args)
            self.train_progress_bar.set_description(f"Epoch {trainer.current_epoch + 1}/{trainer.max_epochs}")

    return {"Indices": Indices, "EpochShuffle": EpochShuffle, "LicromModule": LicromModule, "History": History, "EpochBar": EpochBar, "pl": pl}
