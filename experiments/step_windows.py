"""Where a reduced run's step time goes: the step's median in windows of the run, and builds of licrom compared.

    python experiments/step_windows.py --models out/defaults200/models [--window 150]
    python experiments/step_windows.py --models out/defaults200/models --packages BUILD_A BUILD_B --rounds 3
    python experiments/step_windows.py --small --models DEFAULTS_SMALL_MODELS      # defaults_experiments.py --small's

Each held-out scene of the converged cheese family (``defaults_experiments.py --converged``, the 1638-tet mesh) is run
with ``ReducedSim(model, scene=scene)`` as a user runs it: ``run`` (its ``step_seconds``, the error estimate included),
one thread. Printed per scene: the run's median step, and its median step and mean Newton iterations in each window of
``--window`` steps, so that a landing's cost is told from a slide's; and the median of the one-iteration steps after
step ``SETTLED`` by their distance from the online estimate's evaluations (-2: two steps before one), which shows
what the estimate adds to the steps it rides on.

``--packages``: folders that each hold a built ``licrom`` package (a copy of ``python/licrom`` with its ``_core``);
every round runs each in a process of its own, in turn, and the medians of each scene are printed per package beside
the largest difference of the final positions between the first package and the others (the same physics to
round-off, or not). Interleaved rounds in one session are the comparison this shared machine allows
(docs/results.md section 54).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))


SETTLED = 700
"""Steps after which the held-out scenes have landed and settled (their one-iteration steps are the cheap ones)."""


def around_evaluations(ms: np.ndarray, its: np.ndarray, first: int, stride: int, reach: int = 3) -> dict[int, float]:
    """Median step time (ms) of the one-iteration steps after :data:`SETTLED` by their distance from the estimate's
    nearest evaluation (evaluations at steps ``first``, ``first + stride``, ...; step i of ``ms`` is step i + 1)."""
    by: dict[int, list[float]] = {}
    for i in range(SETTLED, len(ms)):
        if its[i] == 1:
            off = (i + 1 - first) % stride
            off = off - stride if off > stride // 2 else off
            if abs(off) <= reach:
                by.setdefault(off, []).append(float(ms[i]))
    return {o: float(np.median(v)) for o, v in sorted(by.items())}


def scene_runs(models: Path, window: int, small: bool = False) -> dict:
    """Every held-out scene of the converged cheese run with the model's defaults: medians per window, final positions.
    ``small``: the tiny cheese of ``defaults_experiments.py --small`` (not converged), for its 1-epoch model."""
    import body_frame_experiments as bfe
    import defaults_experiments as de
    from licrom import Model, ReducedSim
    from licrom.reduced.error_estimate import ERROR_STRIDE

    de.CONVERGED = not small
    bfe.CHEESE_RESOLUTION = 10
    model = Model.load(models / "cheese.lcm")
    fam = de.family("cheese", small)
    out = {}
    for case in fam.held_out:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the estimate's warnings belong to the accuracy studies
            sim = ReducedSim(model, scene=case.scene)
            traj = sim.run(fam.steps, record_every=fam.record_every)
        ms, its = 1e3 * traj.step_seconds, traj.iterations
        stride = sim._monitor._run_stride
        out[case.kind] = {
            "median_ms": float(np.median(ms)),
            "windows": [(a, float(np.median(ms[a : a + window])), float(its[a : a + window].mean())) for a in range(0, len(ms), window)],
            "final": traj.positions(traj.n_frames - 1).tolist(),
            "around_evaluations": around_evaluations(ms, its, min(stride, ERROR_STRIDE), stride),
        }
    return out


def compare(packages: list[Path], models: Path, window: int, rounds: int, small: bool) -> None:
    """``rounds`` interleaved runs of this script's single-package mode with each package first on the path."""
    results: list[list[dict]] = [[] for _ in packages]
    for _ in range(rounds):
        for p, runs in zip(packages, results):
            env = {**os.environ, "PYTHONPATH": str(p), "RAYON_NUM_THREADS": "1"}
            args = [sys.executable, __file__, "--models", str(models), "--window", str(window), "--json", *(["--small"] if small else [])]
            done = subprocess.run(args, env=env, capture_output=True, text=True)
            if done.returncode != 0:
                raise SystemExit(f"{p}: the run failed:\n{done.stderr[-2000:]}")
            runs.append(json.loads(done.stdout.splitlines()[-1]))
    first = results[0][0]
    for scene in first:
        print(scene)
        for p, runs in zip(packages, results):
            diff = max(float(np.abs(np.array(r[scene]["final"]) - np.array(first[scene]["final"])).max()) for r in runs)
            medians = ", ".join(f"{r[scene]['median_ms']:.3f}" for r in runs)
            print(f"  {p}: run medians {medians} ms; final positions within {diff:.1e} m of the first package's first run")
            offsets = sorted({int(o) for r in runs for o in r[scene]["around_evaluations"]})
            near = ", ".join(f"{o:+d}: {min(r[scene]['around_evaluations'].get(str(o), np.inf) for r in runs):.3f}" for o in offsets)
            print(f"    one-iteration steps after step {SETTLED} by distance from an evaluation (fastest round's median, ms): {near}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--models", type=Path, default=Path("out/defaults200/models"), help="folder with cheese.lcm")
    ap.add_argument("--window", type=int, default=150, help="steps per window")
    ap.add_argument("--packages", type=Path, nargs="*", default=[], help="built licrom packages to compare, each a folder holding licrom/")
    ap.add_argument("--rounds", type=int, default=3, help="interleaved rounds of --packages")
    ap.add_argument("--json", action="store_true", help="print the results as one JSON line (the mode --packages runs)")
    ap.add_argument("--small", action="store_true", help="the tiny cheese of defaults_experiments.py --small and its model (a smoke test)")
    args = ap.parse_args()
    if args.packages:
        compare(args.packages, args.models, args.window, args.rounds, args.small)
        return
    out = scene_runs(args.models, args.window, args.small)
    if args.json:
        print(json.dumps(out))
        return
    for scene, row in out.items():
        print(f"{scene}: median {row['median_ms']:.3f} ms a step")
        for a, ms, its in row["windows"]:
            print(f"  steps {a:5d}-{a + args.window:5d}: {ms:.3f} ms, {its:.2f} iterations")
        near = ", ".join(f"{o:+d}: {ms:.3f}" for o, ms in row["around_evaluations"].items())
        print(f"  one-iteration steps after step {SETTLED} by distance from an evaluation (ms): {near}")


if __name__ == "__main__":
    main()
