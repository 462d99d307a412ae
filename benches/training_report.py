"""Quality and speed of the learned subspace, measured.

Trains LiCROM models on a directory of full-simulation trajectories (for example
``licrom generate DATA --preset cheese``, the report's 15-trajectory set) and prints:

* the reconstruction error by r (default 8, 20, 40): relative mass-weighted L2
  error of the displacement, full (affine part included) and of the residual
  alone (what the affine modes cannot express), through the exact projection
  onto [affine | W] and through the encoder, on the training, validation and
  (optional) test trajectories; next to it the POD bound: the error of the best
  r-dimensional linear subspace of the training residuals on the mesh (no
  continuous basis can beat it on held-out data by much);
* time per epoch (training only) and the epochs to reach 1% held-out projection
  error (full displacement and residual), and to come within 20% of the POD bound;
* with ``--sweep``: a small grid over r, field width and learning rate, picked by
  validation error (the test trajectories, when held out with --test-fraction,
  are never used to pick).

Whole trajectories are held out. Example (GPU)::

    python benches/training_report.py DATA --device cuda --epochs 300 --jobs 3 --out out/training_report
    python benches/training_report.py DATA --device cuda --sweep --sweep-epochs 100 --jobs 3

``DATA`` may be ``synthetic`` (smooth analytic deformations with rigid motions of a
cheese mesh) when no simulated set is at hand. Several ``--jobs`` train at once in
separate processes (on one GPU, or splitting the CPU cores).
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import multiprocessing as mp
import os
import time
from pathlib import Path
from typing import Any

import numpy as np


# ----------------------------------------------------------------------------------------
# data
# ----------------------------------------------------------------------------------------
def load_named(source: str, seed: int) -> list:
    from licrom import meshes
    from licrom.learn.training_data import load_trajectories, make_synthetic_trajectories

    if source == "synthetic":
        mesh = meshes.cheese(resolution=10)
        trajs = make_synthetic_trajectories(mesh, count=10, frames=100, seed=seed, modes=8, rotation=True)
        return [(t.info["name"], t) for t in trajs]
    return load_trajectories(source)


def split(count: int, val_fraction: float, test_fraction: float, seed: int) -> tuple[list[int], list[int], list[int]]:
    rng = np.random.default_rng(seed)
    perm = [int(i) for i in rng.permutation(count)]
    n_test = round(test_fraction * count) if test_fraction > 0 else 0
    n_val = max(1, round(val_fraction * count)) if val_fraction > 0 and count - n_test >= 2 else 0
    if n_test + n_val >= count:
        raise SystemExit(f"not enough trajectories ({count}) for {n_val} validation + {n_test} test")
    # validation first, so adding a test split leaves the validation set unchanged
    val, test = sorted(perm[:n_val]), sorted(perm[n_val : n_val + n_test])
    train = sorted(perm[n_test + n_val :])
    return train, val, test


def build_data(args: argparse.Namespace) -> dict[str, Any]:
    """Training data with the validation split, and (optionally) with the test split."""
    from licrom.learn.training_data import TrainingData

    named = load_named(args.data, args.seed)
    tr, va, te = split(len(named), args.val_fraction, args.test_fraction, args.seed)
    sel = [named[i] for i in tr + va]
    data_val = TrainingData([t for _, t in sel], val_indices=list(range(len(tr), len(tr) + len(va))), frame_stride=args.frame_stride)
    data_val.names = [n for n, _ in sel]
    data_test = None
    if te:
        sel_t = [named[i] for i in tr + te]
        data_test = TrainingData([t for _, t in sel_t], val_indices=list(range(len(tr), len(tr) + len(te))), frame_stride=args.frame_stride)
        data_test.names = [n for n, _ in sel_t]
    return {"val": data_val, "test": data_test, "names": [n for n, _ in named], "train_idx": tr, "val_idx": va, "test_idx": te}


def pod_bounds(data, ranks: list[int], test=None) -> dict[int, dict[str, float]]:
    """Residual error of the best r-dimensional subspace of the training residuals (mass norm)."""
    sq = np.sqrt(np.repeat(data.masses, 3))
    r_train = data.train.residuals.reshape(len(data.train), -1).astype(np.float64) * sq
    gram = r_train @ r_train.T
    lam, vec = np.linalg.eigh(gram)
    order = np.argsort(lam)[::-1]
    lam, vec = np.maximum(lam[order], 0.0), vec[:, order]
    keep = lam > lam[0] * 1e-14
    modes = (vec[:, keep].T @ r_train) / np.sqrt(lam[keep])[:, None]  # orthonormal rows
    out: dict[int, dict[str, float]] = {}

    def err(frames, k):
        if frames is None or len(frames) == 0:
            return float("nan")
        x = frames.residuals.reshape(len(frames), -1).astype(np.float64) * sq
        p = x - (x @ modes[:k].T) @ modes[:k]
        return float(np.linalg.norm(p) / max(np.linalg.norm(x), 1e-300))

    for k in ranks:
        out[k] = {"train": err(data.train, k), "val": err(data.val, k), "test": err(test.val if test is not None else None, k)}
    return out


# ----------------------------------------------------------------------------------------
# one training run (in a worker process)
# ----------------------------------------------------------------------------------------
_DATA: dict[str, Any] | None = None


def _worker_init(args: argparse.Namespace, threads: int | None, gpus: int = 0) -> None:
    global _DATA
    if gpus > 1:  # spread the workers over the GPUs (before torch touches CUDA)
        ident = mp.current_process()._identity
        os.environ["CUDA_VISIBLE_DEVICES"] = str(((ident[0] - 1) if ident else 0) % gpus)
    import torch

    if threads:
        torch.set_num_threads(threads)
    _DATA = build_data(args)


def run_one(job: dict[str, Any]) -> dict[str, Any]:
    from licrom.learn.model import ModelConfig
    from licrom.learn.training import TrainConfig, evaluate, train

    assert _DATA is not None
    args = job["args"]
    mcfg = ModelConfig(latent_dim=job["r"], field_width=job["width"], fourier_features=job["fourier"], fourier_scale=args.fourier_scale)
    tcfg = TrainConfig(
        epochs=job["epochs"], lr=job["lr"], seed=args.seed, device=args.device, devices=1, progress=args.progress,
        batch_frames=args.batch_frames, points_per_frame=args.points, projection_weight=job["projection_weight"],
        checkpoint_every=max(1, job["epochs"] // 10),
        max_time_s=args.max_minutes * 60 if args.max_minutes else None,
    )
    out = job.get("out")
    t0 = time.perf_counter()
    model = train(_DATA["val"], out, tcfg, mcfg)
    wall = time.perf_counter() - t0
    hist = model.metadata["history"]
    dev = "cuda" if model.metadata["accelerator"] == "gpu" else "cpu"
    res: dict[str, Any] = {k: job[k] for k in ("r", "width", "lr", "projection_weight", "fourier", "epochs")}
    res["train"] = evaluate(model, _DATA["val"], "train", device=dev)
    res["val"] = evaluate(model, _DATA["val"], "val", device=dev)
    res["test"] = evaluate(model, _DATA["test"], "val", device=dev) if _DATA["test"] is not None else None
    secs = [h["train_seconds"] for h in hist]
    res["seconds_per_epoch_mean"] = float(np.mean(secs[1:] if len(secs) > 1 else secs))
    res["seconds_per_epoch_median"] = float(np.median(secs))
    res["seconds_per_epoch_first"] = float(secs[0])
    res["wall_seconds"] = wall
    res["history"] = hist
    res["accelerator"] = model.metadata["accelerator"]
    res["model_file"] = str(out) if out else None
    return res


def first_epoch(hist: list[dict], key: str, threshold: float) -> int | None:
    for h in hist:
        v = h.get(key)
        if v is not None and math.isfinite(v) and v <= threshold:
            return int(h["epoch"])
    return None


def run_jobs(jobs: list[dict], args: argparse.Namespace) -> list[dict]:
    n = max(1, min(args.jobs, len(jobs)))
    threads = args.threads or (max(1, (os.cpu_count() or 1) // n) if args.device == "cpu" or n > 1 else None)
    if n == 1:
        global _DATA
        if _DATA is None:
            _worker_init(args, threads)
        elif threads:
            import torch

            torch.set_num_threads(threads)
        return [run_one(j) for j in jobs]
    gpus = 0
    if args.device != "cpu":
        import torch

        gpus = torch.cuda.device_count()
    ctx = mp.get_context("spawn")
    with ctx.Pool(n, initializer=_worker_init, initargs=(args, threads, gpus)) as pool:
        return pool.map(run_one, jobs, chunksize=1)


# ----------------------------------------------------------------------------------------
# report
# ----------------------------------------------------------------------------------------
def pct(v: Any) -> str:
    return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else f"{100 * v:.3f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data", help="directory of trajectory .npz files, or 'synthetic'")
    ap.add_argument("--device", default="auto", choices=["auto", "cpu", "cuda"])
    ap.add_argument("--epochs", type=int, default=300)
    ap.add_argument("--modes", type=int, nargs="+", default=[8, 20, 40])
    ap.add_argument("--width", type=int, default=60)
    ap.add_argument("--lr", type=float, default=3e-3)
    ap.add_argument("--projection-weight", type=float, default=1.0)
    ap.add_argument("--fourier-features", type=int, default=32)
    ap.add_argument("--fourier-scale", type=float, default=1.0)
    ap.add_argument("--batch-frames", type=int, default=16)
    ap.add_argument("--points", type=int, default=2048)
    ap.add_argument("--frame-stride", type=int, default=1)
    ap.add_argument("--val-fraction", type=float, default=0.2)
    ap.add_argument("--test-fraction", type=float, default=0.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--jobs", type=int, default=1, help="training runs at once (processes)")
    ap.add_argument("--threads", type=int, default=None, help="torch CPU threads per run")
    ap.add_argument("--out", default="out/training_report")
    ap.add_argument("--max-minutes", type=float, default=None, help="stop each training run after this long")
    ap.add_argument("--no-table", action="store_true", help="skip the table by r (sweep only)")
    ap.add_argument("--sweep", action="store_true")
    ap.add_argument("--sweep-epochs", type=int, default=100)
    ap.add_argument("--sweep-modes", type=int, nargs="+", default=[20])
    ap.add_argument("--sweep-widths", type=int, nargs="+", default=[32, 60, 128])
    ap.add_argument("--sweep-lrs", type=float, nargs="+", default=[1e-3, 3e-3, 1e-2])
    ap.add_argument("--sweep-projection-weights", type=float, nargs="+", default=[1.0])
    ap.add_argument("--sweep-fourier", type=int, nargs="+", default=[32], help="Fourier feature counts")
    ap.add_argument("--progress", action="store_true", help="Lightning progress bars")
    args = ap.parse_args()

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    global _DATA
    info = build_data(args)
    _DATA = info
    data = info["val"]
    ranks = sorted(set(args.modes + (args.sweep_modes if args.sweep else [])))
    pod = pod_bounds(data, ranks, info["test"])
    import torch

    report: dict[str, Any] = {
        "data": args.data,
        "trajectories": info["names"],
        "split": {k: [info["names"][i] for i in info[f"{k}_idx"]] for k in ("train", "val", "test")},
        "frames": {"train": len(data.train), "val": len(data.val), "test": len(info["test"].val) if info["test"] else 0},
        "mesh": {"vertices": data.mesh.n_vertices, "tets": data.mesh.n_tets},
        "residual_to_full_norm": float(np.sqrt(data.train.norm2_residual.sum() / max(data.train.norm2_full.sum(), 1e-300))),
        "pod_bound": {str(k): v for k, v in pod.items()},
        "args": vars(args),
        "torch": torch.__version__,
        "cuda_device": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
        "cpu_count": os.cpu_count(),
    }
    print(f"data {args.data}: {len(info['names'])} trajectories, mesh {data.mesh.n_vertices} vertices / {data.mesh.n_tets} tets")
    print(f"split: train {len(info['train_idx'])} ({len(data.train)} frames), validation {len(info['val_idx'])} ({len(data.val)} frames), "
          f"test {len(info['test_idx'])}")
    print(f"residual (non-affine) part of the training displacement: {100 * report['residual_to_full_norm']:.4f} % of its norm")
    print(f"device {args.device} ({report['cuda_device'] or 'CPU'}), {args.jobs} job(s) at once")

    if not args.no_table:
        jobs = [dict(args=args, r=r, width=args.width, lr=args.lr, projection_weight=args.projection_weight, fourier=args.fourier_features, epochs=args.epochs,
                     out=str(out / f"model_r{r}.lcm")) for r in args.modes]
        results = run_jobs(jobs, args)
        report["table"] = results
        print(f"\n## Reconstruction error by r (%, relative mass-weighted L2; {args.epochs} epochs, width {args.width}, lr {args.lr:g}, "
              f"projection weight {args.projection_weight:g}, Fourier features {args.fourier_features})\n")
        print("| r | split | projection residual | encoder residual | projection full | encoder full | POD bound residual |")
        print("|---|---|---|---|---|---|---|")
        for res in results:
            r = res["r"]
            for sp in ("train", "val", "test"):
                e = res.get(sp)
                if not e or not e.get("frames"):
                    continue
                print(f"| {r} | {sp} | {pct(e['proj_residual'])} | {pct(e['enc_residual'])} | {pct(e['proj_full'])} | "
                      f"{pct(e['enc_full'])} | {pct(pod[r][sp])} |")
        print("\n## Speed and convergence\n")
        print("| r | s/epoch (train, mean) | first epoch s | wall s | epochs to 1% held-out proj (full) | "
              "epochs to 1% held-out proj (residual) | epochs to 1.2x POD (residual) | best held-out proj residual (epoch) |")
        print("|---|---|---|---|---|---|---|---|")
        for res in results:
            r, hist = res["r"], res["history"]
            vals = [(h["val_proj_residual"], h["epoch"]) for h in hist if math.isfinite(h["val_proj_residual"])]
            best = min(vals) if vals else (float("nan"), None)
            res["epochs_to_1pct_full"] = first_epoch(hist, "val_proj_full", 0.01)
            res["epochs_to_1pct_residual"] = first_epoch(hist, "val_proj_residual", 0.01)
            res["epochs_to_1p2_pod"] = first_epoch(hist, "val_proj_residual", 1.2 * pod[r]["val"])
            print(f"| {r} | {res['seconds_per_epoch_mean']:.3f} | {res['seconds_per_epoch_first']:.3f} | {res['wall_seconds']:.0f} | "
                  f"{res['epochs_to_1pct_full']} | {res['epochs_to_1pct_residual']} | {res['epochs_to_1p2_pod']} | "
                  f"{pct(best[0])} ({best[1]}) |")

    if args.sweep:
        grid = list(itertools.product(args.sweep_modes, args.sweep_widths, args.sweep_lrs, args.sweep_projection_weights, args.sweep_fourier))
        jobs = [dict(args=args, r=r, width=w, lr=lr, projection_weight=pw, fourier=ff, epochs=args.sweep_epochs, out=None) for r, w, lr, pw, ff in grid]
        results = run_jobs(jobs, args)
        report["sweep"] = results
        print(f"\n## Sweep ({args.sweep_epochs} epochs each; picked by validation projection error of the residual)\n")
        print("| r | width | lr | proj. weight | Fourier | val proj residual | val enc residual | test proj residual | s/epoch |")
        print("|---|---|---|---|---|---|---|---|---|")
        for res in sorted(results, key=lambda x: (x["r"], x["val"].get("proj_residual", np.inf))):
            t = res["test"]["proj_residual"] if res.get("test") else None
            print(f"| {res['r']} | {res['width']} | {res['lr']:g} | {res['projection_weight']:g} | {res['fourier']} | {pct(res['val']['proj_residual'])} | "
                  f"{pct(res['val']['enc_residual'])} | {pct(t)} | {res['seconds_per_epoch_mean']:.3f} |")
        best = {}
        for res in results:
            b = best.get(res["r"])
            if b is None or res["val"]["proj_residual"] < b["val"]["proj_residual"]:
                best[res["r"]] = res
        report["sweep_best"] = {str(r): {k: b[k] for k in ("width", "lr", "projection_weight", "fourier")} for r, b in best.items()}
        for r, b in sorted(best.items()):
            print(f"best for r = {r}: width {b['width']}, lr {b['lr']:g}, projection weight {b['projection_weight']:g}, Fourier {b['fourier']} "
                  f"(validation {pct(b['val']['proj_residual'])} %, POD bound {pct(pod[r]['val'])} %)")

    report["total_seconds"] = time.perf_counter() - t0
    (out / "report.json").write_text(json.dumps(report, indent=1, default=float))
    print(f"\nwrote {out / 'report.json'} ({report['total_seconds']:.0f} s)")


if __name__ == "__main__":
    main()
