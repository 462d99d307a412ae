"""The entry point :func:`train` and its outputs (loss CSV and plot)."""

from __future__ import annotations

import copy
import dataclasses
import os
import tempfile
import time
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ...errors import AccuracyWarning, ConfigError
from ...rigid import check_frame
from ...viz._plot import pyplot, save_png
from ..model import LicromNet, Model, ModelConfig
from ..model.finalize import finalize_basis
from ..training_data import TrainingData, TrajectorySource
from .checkpoints import checkpoint_io, resume_checkpoint, run_fingerprint
from .config import CSV_COLUMNS, TrainConfig, check_training_memory, output_paths, write_csv
from .dynamics import check_dynamics, cubature_counts, default_epochs, fit_pool, large_mesh_remedy, too_large
from .evaluation import _evaluate_tensors, _orthogonalized_vertex_field, _projection_error2
from .held_out import REMEDY, replay_held_out, target_ratio, warn_misses
from .lightning import _lightning_classes
from .objectives import _refit_output_layer, pod_targets
from .rank import RankChoice, choose_rank


def plot_losses(rows: Sequence[dict[str, Any]], path: str | os.PathLike, title: str = "", rank: RankChoice | None = None) -> Path:
    """PNG of the loss curves (train/val MSE and held-out relative errors) per epoch, and with
    ``rank`` a third panel: the leave-runs-out error curve against r, the tolerance and the chosen r."""
    plt = pyplot()
    ep = [r["epoch"] for r in rows]
    fig, axes = plt.subplots(1, 3 if rank is not None else 2, figsize=(16.5 if rank is not None else 11, 4))
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
    if rank is not None:
        ax = axes[2]
        ax.semilogy(rank.candidates, rank.errors, "o-", label="RMS over held-out runs")
        ax.semilogy(rank.candidates, rank.worst_errors, ".--", label="worst held-out run")
        ax.axhline(rank.tolerance, color="k", lw=0.8, ls="--", label=f"tolerance {100 * rank.tolerance:g} %")
        ax.axvline(rank.rank, color="C3", lw=1.0, label=f"chosen r = {rank.rank}" + (" (cap)" if rank.capped else ""))
        ax.set_xlabel("r (learned modes)")
        ax.set_ylabel("POD projection error, leave runs out")
        ax.legend()
        ax.grid(True, which="both", alpha=0.3)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return save_png(fig, path)


def warn_without_impact_frames(data: TrainingData) -> None:
    """An ``AccuracyWarning`` naming the runs recorded every few steps that touch a plane and hold no impact frames
    (:func:`~licrom.learn.training_data.runs_without_impact_frames`): their landings' transients are not in the data."""
    names = data.without_impact_frames
    if not names:
        return
    shown = ", ".join(names[:5]) + (", ..." if len(names) > 5 else "")
    warnings.warn(f"{len(names)} of {len(data.names)} runs ({shown}) keep a frame only every few steps and no impact frames: "
                  "a landing's transient falls between their frames, and modes without it land the body off (on the converged "
                  "cheese 7.7 % of its size against 0.04 %, docs/results.md section 67). Record them with `licrom generate`, "
                  "which keeps every step for a while after each impact (--impact-window), or `FullSim.run(..., impact_window=...)`",
                  AccuracyWarning, stacklevel=3)


def fit_cubature(model: Model, data: TrainingData, cfg: TrainConfig, held_out: Sequence[tuple[str, Any]] | None = None) -> dict[str, Any] | None:
    """Fit the model's default cubature to the forces of its training poses and store it in the model.

    The poses are at most ``cfg.cubature_samples`` frames, evenly spaced over every run of
    ``data`` (training and held-out: the fit needs no held-out check, the more poses the
    better), in the model's frame; the fit is :meth:`licrom.Cubature.fitted` with
    ``cfg.cubature_tolerance`` and at most ``cfg.cubature_points`` tets. Where that is ``"auto"`` on a large mesh
    (:func:`~licrom.learn.training.dynamics.cubature_counts`), each count is fitted and the model keeps the fit whose
    ``held_out`` runs (default: ``data.held_out``) land nearest their targets
    (:func:`~licrom.learn.training.held_out.target_ratio`; the largest fit where there are none). Its size,
    residual, time and the choice go to ``model.metadata["cubature"]``.

    Returns:
        The kept fit's replay of the held-out runs (:func:`~licrom.learn.training.held_out.replay_held_out`) where
        the runs chose it, for training's check not to replay them again; else None.
    """
    from ...subspace.cubature import Cubature, fit_candidates, model_samples

    t0 = time.perf_counter()
    frames = [f for f in (data.train, data.val) if len(f)]
    total = sum(len(f) for f in frames)
    keep = max(1, min(cfg.cubature_samples, total))
    picks = np.unique(np.linspace(0, total - 1, keep).round().astype(np.int64))
    offsets = np.cumsum([0] + [len(f) for f in frames])
    u = np.concatenate([f.full_displacements(data.rest, picks[(picks >= lo) & (picks < hi)] - lo)
                        for f, lo, hi in zip(frames, offsets[:-1], offsets[1:])])
    samples = model_samples(model, u)
    candidates = fit_pool(model.mesh.n_tets, cfg.cubature_candidates)
    counts = cubature_counts(model.mesh.n_tets) if cfg.cubature_points == "auto" else (cfg.cubature_points,)
    held_out = data.held_out if held_out is None else held_out
    fits, choice, replays = [], [], []
    for count in counts:
        t_fit = time.perf_counter()
        fits.append((count, Cubature.fitted(model, samples, count=count, tolerance=cfg.cubature_tolerance, candidates=candidates)))
        choice.append({"max_count": count, "count": fits[-1][1].count, "fit_error": fits[-1][1].fit_error,
                       "fit_seconds": time.perf_counter() - t_fit})
    if len(fits) > 1 and held_out:
        for row, (_, cubature) in zip(choice, fits):
            model.set_cubature(cubature, samples)
            replays.append(replay_held_out(model, held_out))
            row["target_ratio"] = target_ratio(replays[-1])
            row["held_out"] = replays[-1]["runs"]  # each fit's runs, with the online estimate beside the true error
        ratios = [row["target_ratio"] for row in choice]
        # the smaller fit where they tie (the cheaper step); the larger where no run could be replayed
        best = len(fits) - 1 if np.all(np.isnan(ratios)) else int(np.nanargmin(ratios))
    else:
        best = len(fits) - 1
    count, cubature = fits[best]
    model.set_cubature(cubature, samples)
    pool = min(model.mesh.n_tets, candidates or fit_candidates(*samples.shape))
    if cubature.fit_error > cfg.cubature_tolerance:
        # Both limits are named: the fit ends at its count, or earlier when no candidate left lowers the residual
        # (then the pool is the limit: the 104k-tet ball at r = 250), and its weights may drop some chosen tets.
        warnings.warn(f"the fitted cubature's force residual is {cubature.fit_error:.1e}, above its tolerance {cfg.cubature_tolerance:.0e}, "
                      f"with {cubature.count} of {model.mesh.n_tets} tets ({count} allowed, chosen from {pool} candidates): the reduced "
                      "elastic forces are that far off at the training poses (raise TrainConfig.cubature_points, licrom train --cubature-points, "
                      + ("or the candidates, TrainConfig.cubature_candidates, licrom train --cubature-candidates, " if pool < model.mesh.n_tets else "")
                      + "or run with cubature='full' to see what the fit costs)",
                      AccuracyWarning, stacklevel=3)
    model.metadata["cubature"] = {"scheme": cubature.scheme, "count": cubature.count, "fit_error": cubature.fit_error,
                                  "tolerance": cfg.cubature_tolerance, "max_count": count, "candidates": candidates,
                                  "samples": len(samples), "choice": choice if len(fits) > 1 else None,
                                  "fit_seconds": time.perf_counter() - t0}
    return replays[best] if replays else None


# ----------------------------------------------------------------------------------------
# the entry point
# ----------------------------------------------------------------------------------------
SUBSPACE_RATIO = 1.05
"""Largest ratio of the learned subspace's projection error to that of the POD it is trained towards, before training goes on."""


def _trained_net(module: Any, data: TrainingData, cfg: TrainConfig) -> LicromNet:
    """The trained network on the CPU in float32, its output layer solved exactly for the ``"pod"`` objective."""
    net = copy.deepcopy(module.net).to("cpu").float().eval()
    if cfg.objective == "pod":
        _refit_output_layer(net, data, module._pod[0])
    return net


def _subspace_ratio(net: LicromNet, data: TrainingData, cfg: TrainConfig, mcfg: ModelConfig, targets: np.ndarray | None) -> dict[str, Any]:
    """Projection errors of the held-out frames (the training frames when none are held out) onto the learned
    subspace, onto the POD of its size that the objective trains towards (``cfg.pod_weighting``; plain POD for
    the autoencoder; ``targets``, its modes (r, n, 3) when known) and onto plain POD (:func:`subspace_report`'s
    bound), each the relative mass-weighted error of the full displacement in the model's frame, and ``ratio`` =
    learned over trained-towards POD (errors below 1e-4 count as 1e-4)."""
    split, frames = ("validation", data.val) if len(data.val) else ("training", data.train)
    r = mcfg.latent_dim
    with torch.no_grad():
        learned = _orthogonalized_vertex_field(net, torch.tensor(data.rest), torch.tensor(data.masses), mcfg.affine).numpy()
    total = max(float(frames.norm2_full.sum()), 1e-300)
    err = lambda basis: float(np.sqrt(_projection_error2(frames.residuals, basis, data.masses) / total))  # noqa: E731
    weighting = cfg.pod_weighting if cfg.objective == "pod" else "frame"
    out = {"split": split, "r": r, "pod_weighting": weighting, "model": err(learned.reshape(-1, 3, r))}
    out["pod"] = err(np.moveaxis(pod_targets(data, r, weighting)[0] if targets is None else targets, 0, 2))
    out["plain_pod"] = out["pod"] if weighting == "frame" else err(np.moveaxis(pod_targets(data, r, "frame")[0], 0, 2))
    # Below 1e-4 (relative) both span the frames: no ratio of round-off (r as large as the frames' count).
    out["ratio"] = max(out["model"], 1e-4) / max(out["pod"], 1e-4)
    return out


def _accelerator(cfg: TrainConfig) -> tuple[str, Any]:
    """Lightning's ``(accelerator, devices)`` for ``cfg``.

    Raises:
        ConfigError: CUDA asked for (``device="cuda"``, or ``devices`` > 1: GPUs) where there is none, or more
            GPUs than there are.
    """
    gpus = torch.cuda.device_count() if torch.cuda.is_available() else 0
    if isinstance(cfg.devices, int) and cfg.devices > 1:
        # Several devices are GPUs: training on the CPU instead would ignore the request silently.
        if cfg.device == "cpu":
            raise ConfigError(f"TrainConfig.devices (--gpus) is {cfg.devices} but TrainConfig.device is 'cpu'; the CPU trains in "
                              "one process: accepted with device 'cpu': devices 'auto' or 1")
        if gpus == 0:
            raise ConfigError(f"TrainConfig.devices (--gpus) is {cfg.devices} but no CUDA device is available here "
                              "(torch.cuda.is_available() is False); accepted here: devices 'auto' or 1 (training on the CPU)")
        if cfg.devices > gpus:
            raise ConfigError(f"TrainConfig.devices (--gpus) is {cfg.devices} but this machine has {gpus} CUDA device(s); "
                              f"accepted here: 'auto' or 1..{gpus}")
    if cfg.device == "cpu":
        return "cpu", 1
    if cfg.device == "cuda" and gpus == 0:
        raise ConfigError("TrainConfig.device is 'cuda' but no CUDA device is available (torch.cuda.is_available() is False)")
    if gpus:
        return "gpu", cfg.devices
    return "cpu", 1


JOIN_CATCH_UP = 2.0
"""On one machine Lightning starts the other processes of a multi-GPU run when this one reaches the fit, and
each runs the command or script again from its start (loading the runs and choosing r included, all of them
at once). So a one-machine run waits ``TrainConfig.join_timeout_s`` plus this many times this process's age
for them: with the 120 s alone, the processes of a training on 40 runs of a 120k-tet mesh on 4 GPUs had not
joined in time (docs/scaling.md)."""


def process_age_s() -> float:
    """Seconds since this process started (Linux's ``/proc``; 0 where it cannot be read)."""
    try:
        # Field 22 of /proc/self/stat, the start in clock ticks after boot; the name (field 2) may hold spaces.
        start_ticks = float(Path("/proc/self/stat").read_text().rsplit(")", 1)[1].split()[19])
        uptime = float(Path("/proc/uptime").read_text().split()[0])
        return max(0.0, uptime - start_ticks / os.sysconf("SC_CLK_TCK"))
    except (OSError, ValueError, IndexError):
        return 0.0


def join_timeout_s(cfg: TrainConfig, age_s: float) -> float:
    """Seconds the processes of a run wait for each other to join: ``cfg.join_timeout_s``, plus
    :data:`JOIN_CATCH_UP` times this process's age ``age_s`` on one machine, where the others start only now
    (on several machines a launcher starts them all at once)."""
    return cfg.join_timeout_s + (JOIN_CATCH_UP * age_s if cfg.nodes == 1 else 0.0)


def _strategy(cfg: TrainConfig, accelerator: str, devices: Any) -> Any:
    """Lightning's strategy: ``"auto"`` for one process; for several, DDP whose processes wait at most
    :func:`join_timeout_s` for each other to join (then a ConfigError saying what is missing)."""
    per_node = (torch.cuda.device_count() if devices == "auto" else int(devices)) if accelerator == "gpu" else 1
    if per_node * cfg.nodes == 1:
        return "auto"
    age = process_age_s()
    timeout = join_timeout_s(cfg, age)
    waited = (f"{timeout:g} s (TrainConfig.join_timeout_s, --join-timeout)" if timeout == cfg.join_timeout_s else
              f"{timeout:.0f} s (TrainConfig.join_timeout_s, --join-timeout, {cfg.join_timeout_s:g} s, plus {JOIN_CATCH_UP:g}x "
              f"this process's age, {age:.0f} s, for the others to start from the beginning)")
    from datetime import timedelta

    from lightning.pytorch.strategies import DDPStrategy
    from torch.distributed.constants import default_pg_timeout

    class JoiningDDP(DDPStrategy):
        """DDP whose rendezvous gives up after ``join_timeout_s``; collectives keep torch's default timeout."""

        def setup_distributed(self) -> None:
            try:
                super().setup_distributed()
            except torch.distributed.DistError as exc:
                where = f"{os.environ.get('MASTER_ADDR', '?')}:{os.environ.get('MASTER_PORT', '?')}"
                hint = ("start the same command on every node with MASTER_ADDR, MASTER_PORT and NODE_RANK set (or under torchrun "
                        "or SLURM), or train with --nodes 1" if cfg.nodes > 1 else "the other processes of this machine did not start")
                raise ConfigError(
                    f"the {self.world_size} processes of this run ({cfg.nodes} node(s) x {self.num_processes} process(es); this one: "
                    f"node rank {self.node_rank}, global rank {self.global_rank}) did not all join at MASTER_ADDR:MASTER_PORT = {where} "
                    f"within {waited}: {str(exc).rstrip('.')}; {hint}") from exc
            # The join timeout is the collectives' too: give them back torch's default (a slow checkpoint is no lost peer).
            set_timeout = getattr(torch.distributed, "set_timeout", None)  # absent from older torch: there the collectives keep join_timeout_s
            if set_timeout is not None:
                set_timeout(default_pg_timeout)

    return JoiningDDP(timeout=timedelta(seconds=timeout))


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
            :class:`~licrom.learn.training_data.TrainingData` (its split is used as is).
        out_path: model file to write (``.lcm`` by convention), with the loss CSV, the
            loss plot and the checkpoint directory beside it (see :func:`output_paths`).
            ``None`` writes nothing (checkpoints off, no resume).
        config: training options.
        model_config: network sizes and the frame; r is ``model_config.latent_dim``, by default
            ``"auto"``: the smallest r whose leave-runs-out projection error meets
            ``config.rank_tolerance`` (:func:`~licrom.learn.training.rank.choose_rank`, recorded in
            ``metadata["rank"]``). After training, the learned subspace's held-out projection
            error is compared with the POD it was trained towards; above :data:`SUBSPACE_RATIO`
            times it, training goes on once (``config.extension``; ``metadata["subspace"]``).
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
    accelerator, devices = _accelerator(cfg)  # before the data is read: a machine without the GPUs asked for is refused at once
    check_training_memory(cfg, mcfg)  # the two configs together (each checked its own sizes), before any data
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
    tdata.check_deformation()
    warn_without_impact_frames(tdata)
    if cfg.epochs == "auto":
        cfg = dataclasses.replace(cfg, epochs=default_epochs(tdata.mesh.n_tets))
    t_data = time.perf_counter() - t_start
    rank = dynamics = None
    if mcfg.latent_dim == "auto":
        rank = choose_rank(tdata, cfg.rank_tolerance, cfg.max_rank)
        dynamics = check_dynamics(tdata, rank.rank, cfg.dynamics_max_rank)
        mcfg = dataclasses.replace(mcfg, latent_dim=dynamics.rank)
        check_training_memory(cfg, mcfg)

    L = _lightning_classes()
    pl = L["pl"]
    paths = output_paths(out_path) if out_path is not None else None
    ckpt_dir = Path(cfg.checkpoint_dir) if cfg.checkpoint_dir else (paths["checkpoints"] if paths else None)
    fingerprint = run_fingerprint(tdata, mcfg) if ckpt_dir is not None else None
    ckpt_path = None
    if cfg.resume:
        found = resume_checkpoint(ckpt_dir, fingerprint) if ckpt_dir is not None and fingerprint is not None else None
        if found is None:
            warnings.warn(f"resume requested but no checkpoint found in '{ckpt_dir}'; training from scratch", stacklevel=2)
        ckpt_path = None if found is None else str(found)

    pl.seed_everything(cfg.seed, workers=True, verbose=False)
    module = L["LicromModule"](mcfg.to_dict(), cfg.to_dict())
    module.net.set_normalization(tdata.x_center, tdata.x_scale, tdata.u_scale)
    module.attach(tdata)

    history = L["History"](paths["csv"] if paths else None)
    callbacks: list[Any] = [history, L["EpochBar"]()] if cfg.progress else [history]
    plugins: list[Any] = []
    if ckpt_dir is not None and fingerprint is not None:
        from lightning.pytorch.callbacks import ModelCheckpoint

        # No version counter: every run writes last.ckpt itself (never last-v1.ckpt beside an older run's).
        callbacks.append(ModelCheckpoint(dirpath=ckpt_dir, filename="epoch{epoch:04d}", auto_insert_metric_name=False,
                                         save_last=True, save_top_k=0, every_n_epochs=cfg.checkpoint_every,
                                         enable_version_counter=False))
        plugins.append(checkpoint_io(fingerprint))
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
        def make_trainer(max_epochs: int) -> Any:
            return pl.Trainer(
                accelerator=accelerator,
                devices=devices,
                num_nodes=cfg.nodes,
                strategy=_strategy(cfg, accelerator, devices),
                precision=cfg.precision,
                max_epochs=max_epochs,
                callbacks=callbacks,
                plugins=plugins,
                logger=False,
                enable_checkpointing=ckpt_dir is not None,
                enable_progress_bar=cfg.progress,
                enable_model_summary=False,
                num_sanity_val_steps=0,
                default_root_dir=str(ckpt_dir) if ckpt_dir else None,
                log_every_n_steps=1,
                max_time=None if cfg.max_time_s is None else {"seconds": float(cfg.max_time_s)},
            )

        trainer = make_trainer(cfg.epochs)
        n_train = len(tdata.train)
        from torch.utils.data import DataLoader

        batch = min(cfg.batch_frames, n_train)
        if trainer.world_size > 1:
            train_loader = DataLoader(L["Indices"](n_train), batch_size=batch, shuffle=True)
        else:
            train_loader = DataLoader(L["Indices"](n_train), batch_size=batch, sampler=L["EpochShuffle"](n_train, cfg.seed))
        val_loader = DataLoader(L["Indices"](1), batch_size=1) if len(tdata.val) else None
        t_fit = time.perf_counter()
        try:
            trainer.fit(module, train_dataloaders=train_loader, val_dataloaders=val_loader, ckpt_path=ckpt_path, weights_only=True)
            net = _trained_net(module, tdata, cfg)
            targets = module._pod[0] if module._pod is not None else None
            subspace = _subspace_ratio(net, tdata, cfg, mcfg, targets)
            # One extension, from a checkpoint of this fit (epochs, optimiser, schedule and loss rows go on). A time
            # limit is the user's and stops it; several processes need the checkpoint where all of them read.
            if (subspace["ratio"] > SUBSPACE_RATIO and cfg.extension > 0 and cfg.max_time_s is None
                    and (ckpt_dir is not None or trainer.world_size == 1)):
                extra = max(1, round(cfg.extension * cfg.epochs))
                with tempfile.TemporaryDirectory() as tmp:
                    before = (Path(tmp) if trainer.world_size == 1 else ckpt_dir) / "before_extension.ckpt"
                    trainer.save_checkpoint(before)
                    trainer = make_trainer(cfg.epochs + extra)
                    trainer.fit(module, train_dataloaders=train_loader, val_dataloaders=val_loader, ckpt_path=str(before), weights_only=True)
                    if trainer.is_global_zero:
                        before.unlink(missing_ok=True)  # last.ckpt holds the extended run
                net = _trained_net(module, tdata, cfg)
                subspace = {**_subspace_ratio(net, tdata, cfg, mcfg, targets), "ratio_before_extension": subspace["ratio"], "extended_epochs": extra}
        finally:
            torch.set_float32_matmul_precision(old_matmul)
            for lg, level in zip(quiet_loggers, old_levels):
                lg.setLevel(level)
        t_fit = time.perf_counter() - t_fit

    if subspace["ratio"] > SUBSPACE_RATIO:
        warnings.warn(f"the learned subspace's projection error is {subspace['ratio']:.2f}x that of the POD it was trained towards "
                      f"(r = {mcfg.latent_dim}, {subspace['split']} frames; target <= {SUBSPACE_RATIO}x): train longer "
                      "(TrainConfig.epochs) or widen the field (ModelConfig.field_width)", stacklevel=2)
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
        "rank": ({**rank.to_dict(), "rank": mcfg.latent_dim, "dynamics": dynamics.to_dict()}
                 if rank is not None and dynamics is not None else {"rank": mcfg.latent_dim, "method": "given (ModelConfig.latent_dim)"}),
        "subspace": subspace,
        "accelerator": accelerator,
        "world_size": trainer.world_size,
        "cuda_graphs": {"graphs": module.graphs_captured, "passes": module.graph_passes},
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
    replayed = fit_cubature(model, tdata, cfg, held_out=None if trainer.is_global_zero else ())  # the choice's replays on one process
    if tdata.held_out and trainer.is_global_zero:
        remedy = REMEDY
        if tdata.frame == "body" and too_large(tdata.mesh.n_tets):
            cap = dynamics.max_rank if dynamics is not None else cfg.dynamics_max_rank
            remedy = large_mesh_remedy(cap, int(mcfg.latent_dim), int(cfg.epochs))
        report = replayed if replayed is not None else replay_held_out(model, tdata.held_out)
        warn_misses(report, remedy, stacklevel=3)
        model.metadata["held_out"] = report
    if paths is not None and trainer.is_global_zero:
        model.save(paths["model"])
        if rows:
            write_csv(paths["csv"], rows)
            try:
                plot_losses(rows, paths["png"], title=f"LiCROM r={mcfg.latent_dim} ({mcfg.frame} frame), {len(tdata.train_indices)} train / {len(tdata.val_indices)} held-out trajectories",
                            rank=rank)
            except Exception as exc:  # a plot must never lose a trained model
                warnings.warn(f"could not write the loss plot: {exc}", stacklevel=2)
    return model
