"""A trained model on a larger mesh of its object: setup, the reduced step per window of a run, and the full step on
the same scene over its first steps, as a ratio from one process (docs/results.md section 57).

    python experiments/transfer_step.py --model out/defaults200/models/cheese.lcm --resolution 42 --full-steps 150
    python experiments/transfer_step.py --model MODEL --resolution 6 --steps 40 --full-steps 10 --window 10  # seconds

``ReducedSim(model, mesh=meshes.cheese(resolution=R))`` on the model's default scene (its first training run's): the
fitted cubature refitted on the new mesh to the stored training poses, the default contact points, the learned field
evaluated at the new mesh's vertices; its construction is timed. Then ``run(--steps)`` (one thread where
``RAYON_NUM_THREADS=1``), printed as the median step and mean Newton iterations per ``--window`` steps, and
``FullSim(mesh, scene).run(--full-steps)`` (warp, on the CPU unless a GPU is there), whose median step over its
steps is set against the reduced run's median over the same steps. The full run's accuracy is not compared: at 100k
tets its 1500 steps take most of an hour on two cores.
"""

from __future__ import annotations

import argparse
import time
import warnings
from pathlib import Path

import licrom
import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", type=Path, required=True, help="a trained cheese model (.lcm)")
    ap.add_argument("--resolution", type=int, default=42, help="meshes.cheese resolution of the larger mesh (42: 120k tets)")
    ap.add_argument("--steps", type=int, default=1500, help="reduced steps")
    ap.add_argument("--full-steps", type=int, default=150, help="full steps on the same scene (0: none)")
    ap.add_argument("--window", type=int, default=100, help="steps per window of the reduced run")
    args = ap.parse_args()
    model = licrom.Model.load(args.model)
    mesh = licrom.meshes.cheese(resolution=args.resolution)
    t = time.perf_counter()
    sim = licrom.ReducedSim(model, mesh=mesh)
    setup = time.perf_counter() - t
    print(f"{mesh.n_tets} tets, {mesh.n_vertices} vertices: setup {setup:.1f} s, {sim.cubature.count} cubature tets "
          f"(refitted), r = {model.n_modes}; scene dt {sim.scene.dt} s, {sim.scene.integrator}")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the estimate's warning belongs to the accuracy studies
        t = time.perf_counter()
        reduced = sim.run(args.steps, record_every=args.steps)
    ms, its = 1e3 * reduced.step_seconds, reduced.iterations
    print(f"reduced: {args.steps} steps in {time.perf_counter() - t:.1f} s, median {np.median(ms):.3f} ms a step, "
          f"estimate {100 * reduced.error_estimate[-1]:.1f} %")
    for a in range(0, args.steps, args.window):
        print(f"  steps {a:5d}-{a + args.window:5d}: {np.median(ms[a:a + args.window]):.3f} ms, {its[a:a + args.window].mean():.2f} iterations")
    if args.full_steps:
        t = time.perf_counter()
        full = licrom.FullSim(mesh, sim.scene).run(args.full_steps, record_every=args.full_steps)
        fs = 1e3 * full.step_seconds
        n = min(args.full_steps, args.steps)
        print(f"full: {args.full_steps} steps in {time.perf_counter() - t:.1f} s, median {np.median(fs):.1f} ms a step; "
              f"over steps 0-{n}: full {np.median(fs[:n]):.1f} ms, reduced {np.median(ms[:n]):.3f} ms, "
              f"{np.median(fs[:n]) / np.median(ms[:n]):.0f}x")


if __name__ == "__main__":
    main()
