"""Time the training's data stage on a large mesh: loading the runs, ``TrainingData`` and ``choose_rank``.

    python benches/training_data_stage.py [--runs 8] [--resolution 42] [--frames 150]

Synthetic runs (``make_synthetic_trajectories``: smooth deformations and rigid motions, no physics) of
``meshes.cheese(resolution)`` (42: 120378 tets, 23398 vertices) are saved as ``licrom generate`` saves
them (float32), then read back the way ``licrom.train`` reads them; each stage's wall time is printed,
with the five largest cumulative entries of a profile of the stage that dominates. At 120k tets and 40
runs this stage ran twice (once in each process of a 2-GPU training) before any epoch.
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import tempfile
import time
from pathlib import Path

from licrom import meshes
from licrom.learn.training.rank import choose_rank
from licrom.learn.training_data import TrainingData, make_synthetic_trajectories


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=8)
    ap.add_argument("--resolution", type=int, default=42)
    ap.add_argument("--frames", type=int, default=150)
    args = ap.parse_args()
    mesh = meshes.cheese(resolution=args.resolution)
    runs = make_synthetic_trajectories(mesh, count=args.runs, frames=args.frames, seed=1, modes=8)
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        for k, run in enumerate(runs):
            run.save(Path(tmp) / f"run{k:03d}.npz")
        del runs
        saved = time.perf_counter() - t0
        profile = cProfile.Profile()
        profile.enable()
        t1 = time.perf_counter()
        data = TrainingData(tmp)
        t2 = time.perf_counter()
        choice = choose_rank(data)
        t3 = time.perf_counter()
        profile.disable()
    print(f"{args.runs} runs of {args.frames + 1} frames on {mesh.n_tets} tets ({mesh.n_vertices} vertices): save {saved:.1f} s, "
          f"TrainingData {t2 - t1:.1f} s, choose_rank {t3 - t2:.1f} s (r = {choice.rank})")
    pstats.Stats(profile).sort_stats("cumulative").print_stats(8)


if __name__ == "__main__":
    main()
