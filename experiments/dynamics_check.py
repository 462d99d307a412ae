"""The rank choice of ``licrom train`` with its dynamics check, without the training.

    python experiments/dynamics_check.py RUNS_DIR [RUNS_DIR ...]

For each folder of full runs, the same split as ``licrom train RUNS_DIR`` (``TrainingData`` defaults),
the projection's choice (:func:`licrom.learn.training.choose_rank`) and the replays that check it
(:func:`licrom.learn.training.check_dynamics`), printed as the training report prints them, with
their wall time. docs/results.md section 16 ran it on the converged training runs of the cheese,
box and ball families (``experiments/defaults_experiments.py --converged --runs-only``).

    python experiments/dynamics_check.py RUNS_DIR --levels 60 80 100 120 150 200 250 --replays 8

also replays ``--replays`` runs (spread over their motions as the check spreads them) at every r of ``--levels``,
where the check stops at the first r that meets: how each run's error moves with r (docs/results.md section 51).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from licrom.learn.training import check_dynamics, choose_rank
from licrom.learn.training.dynamics import replay_run, replayed_runs, training_pod
from licrom.learn.training_data import TrainingData


def replay_levels(data: TrainingData, levels: list[int], replays: int) -> list[str]:
    """Each of ``replays`` spread training runs replayed as the dynamics check replays them, at every r of ``levels``:
    one line per run, non-rigid error / final centre of mass."""
    pod = training_pod(data, max(levels))
    lines = []
    for name, run in replayed_runs(data, replays):
        rows = [replay_run(data, pod, run, r) for r in levels]
        lines.append(f"  {name}: " + ", ".join(f"r = {row['r']}: {100 * row['nonrigid_error']:.1f} % / {100 * row['com_error']:.2f} %"
                                             for row in rows))
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", type=Path, nargs="+", help="folders of full runs (.npz), one object each")
    ap.add_argument("--levels", type=int, nargs="+", default=[], help="r values to replay every spread run at")
    ap.add_argument("--replays", type=int, default=8, help="runs replayed at every level of --levels")
    args = ap.parse_args()
    for folder in args.runs:
        start = time.perf_counter()
        data = TrainingData(folder)
        choice = choose_rank(data)
        print(f"== {folder}: {data.mesh.n_tets} tets, {len(data.train_indices)} training runs")
        print(choice.describe())
        print("\n".join(check_dynamics(data, choice.rank).lines()))
        if args.levels:
            print("replays at every level (non-rigid error / final centre of mass over the size):")
            print("\n".join(replay_levels(data, sorted(args.levels), args.replays)))
        print(f"   {time.perf_counter() - start:.0f} s in all")


if __name__ == "__main__":
    main()
