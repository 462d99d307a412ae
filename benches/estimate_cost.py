"""What the online error estimate costs a reduced run: the same run with none of it, with its residual term alone and
with the whole estimate, as ratios.

    python benches/estimate_cost.py --model out/defaults/models/cheese.lcm --rounds 9

``ReducedSim(model)`` on the model's default scene (its first training run's), ``--steps`` steps recording every 10th,
run in interleaved rounds (``--stride``: the residual's stride set by hand, to compare with the model's): without the estimate's work after each step, with the residual term alone
(:mod:`licrom.reduced.error_estimate`), and with its cubature term too (:mod:`licrom.reduced.cubature_error`). The
measure is the run's summed step times (``Trajectory.step_seconds``, which hold the estimate's work after each step);
prints the medians and each round's ratios to the run without it, from one process on this machine.
"""

from __future__ import annotations

import argparse
import warnings

import licrom
import numpy as np

VARIANTS = ("none", "residual", "estimate")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", required=True, help="a trained model (.lcm)")
    ap.add_argument("--steps", type=int, default=1500)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--stride", type=int, help="the residual's stride in place of the model's (residual_stride)")
    args = ap.parse_args()
    sim = licrom.ReducedSim(licrom.Model.load(args.model))
    monitor = sim._monitor
    if args.stride is not None:
        monitor.stride = args.stride
    term, after_step = monitor._cubature_error, monitor.after_step
    start = (sim.positions, sim.velocities)
    sums: dict[str, list[float]] = {v: [] for v in VARIANTS}
    for _ in range(args.rounds):
        for variant in VARIANTS:
            sim.set_state(*start)
            sim.time = 0.0
            monitor._cubature_error = term if variant == "estimate" else None
            monitor.after_step = after_step if variant != "none" else lambda state, deformation: None
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                traj = sim.run(args.steps, record_every=10)
            sums[variant].append(float(traj.step_seconds.sum()))
    del monitor.after_step
    base = np.array(sums["none"])
    stride = "none" if term is None else f"about every {term.stride} steps and at the run's end"
    print(f"{sim.mesh.n_tets} tets, k = {sim._values.shape[2]}, {sim.cubature.count} cubature tets; the residual every "
          f"{monitor.stride} steps, the cubature term {stride}")
    print(f"run of {args.steps} steps, summed step times (medians of {args.rounds}): none {1e3 * np.median(base):.1f} ms, "
          f"{1e3 * np.median(base) / args.steps:.4f} ms a step")
    for variant in VARIANTS[1:]:
        ratios = np.array(sums[variant]) / base
        print(f"  {variant}: {1e3 * np.median(sums[variant]):.1f} ms, {100 * (np.median(ratios) - 1):+.1f} % "
              f"(rounds {np.round(ratios, 3).tolist()})")


if __name__ == "__main__":
    main()
