"""What the error estimate's cubature term costs a reduced run: the same run with and without it, as a ratio.

    python benches/estimate_cost.py --model out/defaults/models/cheese.lcm --rounds 9

``ReducedSim(model)`` on the model's default scene (its first training run's), ``--steps`` steps recording every 10th,
run in interleaved rounds with the term (:mod:`licrom.reduced.cubature_error`) and without it (the residual term
alone); prints each round's ratio and the median of each, from one process on this machine.
"""

from __future__ import annotations

import argparse
import time
import warnings

import licrom
import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", required=True, help="a trained model (.lcm)")
    ap.add_argument("--steps", type=int, default=1500)
    ap.add_argument("--rounds", type=int, default=5)
    args = ap.parse_args()
    sim = licrom.ReducedSim(licrom.Model.load(args.model))
    monitor = sim._monitor
    term = monitor._cubature_error
    start = (sim.positions, sim.velocities)
    walls: dict[bool, list[float]] = {True: [], False: []}
    for _ in range(args.rounds):
        for with_term in (True, False):
            sim.set_state(*start)
            sim.time = 0.0
            monitor._cubature_error = term if with_term else None
            t = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                sim.run(args.steps, record_every=10)
            walls[with_term].append(time.perf_counter() - t)
    ratios = np.array(walls[True]) / np.array(walls[False])
    w, wo = float(np.median(walls[True])), float(np.median(walls[False]))
    print(f"{sim.mesh.n_tets} tets, k = {sim._values.shape[2]}, {sim.cubature.count} cubature tets; the term about every {term.stride} "
          "steps and at the run's end")
    print(f"run of {args.steps} steps: {w:.3f} s with the term, {wo:.3f} s without (medians of {args.rounds}): "
          f"{100 * (w / wo - 1):+.1f} %; rounds {np.round(ratios, 3).tolist()}")


if __name__ == "__main__":
    main()
