"""Time a training epoch: its steps and what follows them (validation, checkpoint), on synthetic runs of any size.

The runs are smooth synthetic deformations and rigid motions of the procedural cheese
(:func:`licrom.learn.training_data.make_synthetic_trajectories`, no simulation), so the figures are the
training's own cost at a given mesh size, frame count and r, independent of the physics. The printed hash of the
trained network's weights lets two versions of the code be checked for the same training, bit for bit.

    python benches/training_epoch_bench.py --resolution 12 --epochs 4               # the 1.6k-tet cheese, CPU
    python benches/training_epoch_bench.py --resolution 42 --rank 250 --device cuda  # 120k tets, on a GPU
    python benches/training_epoch_bench.py --resolution 42 --rank 250 --device cuda --cuda-graph both

``--cuda-graph both`` trains twice from the same seed, the steps replayed from CUDA graphs
(``TrainConfig.cuda_graph``) and eagerly, and prints both timings and how far the two trainings' weights are apart.
"""

from __future__ import annotations

import argparse
import hashlib
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
import torch
from licrom import meshes
from licrom.learn.model import ModelConfig
from licrom.learn.training import TrainConfig, train
from licrom.learn.training_data import TrainingData, make_synthetic_trajectories


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--resolution", type=int, default=12, help="meshes.cheese resolution (12: 1.6k tets, 42: 120k)")
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--frames", type=int, default=200, help="frames of each run")
    ap.add_argument("--rank", type=int, default=120, help="r (ModelConfig.latent_dim)")
    ap.add_argument("--epochs", type=int, default=4)
    ap.add_argument("--points", type=int, default=2048, help="TrainConfig.points_per_frame")
    ap.add_argument("--val-every", default=None, help="TrainConfig.val_every (default: the config's)")
    ap.add_argument("--device", default="auto")
    ap.add_argument("--bare", type=int, default=0, metavar="N",
                    help="also time N training steps without Lightning (the module's step, backward, Adam) and count "
                         "their kernel launches")
    ap.add_argument("--cuda-graph", choices=("on", "off", "both"), default="on", help="TrainConfig.cuda_graph (both: each, compared)")
    ap.add_argument("--save", action="store_true", help="write the model, its loss curves and a checkpoint every epoch "
                    "(as `licrom train` does) to a temporary folder")
    args = ap.parse_args()

    t0 = time.perf_counter()
    runs = make_synthetic_trajectories(meshes.cheese(resolution=args.resolution), args.runs, args.frames, modes=6)
    data = TrainingData(runs, val_fraction=0.2, seed=0, frame="body")
    print(f"{data.mesh.n_tets} tets, {data.mesh.n_vertices} vertices; {len(data.train)} training frames, "
          f"{len(data.val)} validation frames; data {time.perf_counter() - t0:.1f} s")
    extra = {} if args.val_every is None else {"val_every": args.val_every if args.val_every == "auto" else int(args.val_every)}
    trained = {}
    for graph in {"on": (True,), "off": (False,), "both": (True, False)}[args.cuda_graph]:
        cfg = TrainConfig(epochs=args.epochs, points_per_frame=args.points, device=args.device, progress=False, extension=0,
                          cubature_points=50, cubature_candidates=256, cuda_graph=graph, **extra)
        trained[graph] = timed_training(data, cfg, args)
    if len(trained) == 2:
        a, b = trained[True], trained[False]
        print(f"CUDA graphs against eager steps: weights apart by {np.max(np.abs(a - b)) / np.max(np.abs(b)):.1e} of the largest "
              f"(max norm), {np.linalg.norm(a - b) / np.linalg.norm(b):.1e} (2-norm)")
    if args.bare:
        bare_steps(data, cfg, ModelConfig(latent_dim=args.rank), args.bare)


def timed_training(data: TrainingData, cfg: TrainConfig, args) -> np.ndarray:
    """Train with ``cfg``, print what its epochs cost, and return the trained weights (flat, float64)."""
    t0 = time.perf_counter()
    with warnings.catch_warnings(), tempfile.TemporaryDirectory() as tmp:
        warnings.simplefilter("ignore")
        model = train(data, Path(tmp) / "bench.lcm" if args.save else None, cfg, ModelConfig(latent_dim=args.rank))
    total = time.perf_counter() - t0
    rows = model.metadata["history"][1:] or model.metadata["history"]  # the first epoch warms up (and captures)
    steps = np.mean([r["train_seconds"] for r in rows])
    after = np.mean([r["epoch_seconds"] - r["train_seconds"] for r in rows])
    batches = -(-len(data.train) // cfg.batch_frames)
    weights = torch.cat([p.detach().double().flatten().cpu() for p in model.net.parameters()]).numpy()
    print(f"device {model.metadata['accelerator']}, r = {args.rank}, {args.points} points a frame, "
          f"{model.metadata['cuda_graphs']['graphs']} CUDA graphs: steps {steps:.3f} s an epoch ({1e3 * steps / batches:.2f} ms a step, "
          f"{batches} steps), after them {after:.3f} s an epoch; fit {model.metadata['fit_seconds']:.1f} s for {args.epochs} "
          f"epochs, train() {total:.1f} s in all; validation projection error {model.metadata['final'].get('val_proj_residual', float('nan')):.4g}")
    print(f"weights sha256 {hashlib.sha256(weights.tobytes()).hexdigest()[:16]}")
    return weights


def bare_steps(data: TrainingData, cfg: TrainConfig, mcfg: ModelConfig, steps: int) -> None:
    """The training step without Lightning's loop: what the step's own operations cost, and how many kernels it launches."""
    from licrom.learn.training.lightning import _lightning_classes

    device = torch.device("cuda" if cfg.device in ("auto", "cuda") and torch.cuda.is_available() else "cpu")
    module = _lightning_classes()["LicromModule"](mcfg.to_dict(), cfg.to_dict())
    module.net.set_normalization(data.x_center, data.x_scale, data.u_scale)
    module.attach(data)
    module.to(device)
    opt = torch.optim.Adam(module.net.parameters(), lr=cfg.lr)
    g = torch.Generator().manual_seed(0)
    batches = [torch.randperm(len(data.train), generator=g)[: cfg.batch_frames].to(device) for _ in range(steps)]

    def run() -> float:
        if device.type == "cuda":
            torch.cuda.synchronize()
        t = time.perf_counter()
        for i, b in enumerate(batches):
            loss = module.training_step(b, i)
            opt.zero_grad()
            loss.backward()
            opt.step()
        if device.type == "cuda":
            torch.cuda.synchronize()
        return (time.perf_counter() - t) / steps

    run()  # warm-up
    seconds = min(run() for _ in range(3))
    with torch.profiler.profile() as prof:
        run()
    launches = sum(e.count for e in prof.key_averages() if e.key in ("cudaLaunchKernel", "cudaLaunchKernelExC"))
    ops = sum(e.count for e in prof.key_averages() if e.key.startswith("aten::"))
    print(f"bare steps: {1e3 * seconds:.2f} ms a step (best of 3 rounds of {steps}); {launches / steps:.0f} kernel launches "
          f"and {ops / steps:.0f} aten calls a step")


if __name__ == "__main__":
    main()
