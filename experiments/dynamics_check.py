"""The rank choice of ``licrom train`` with its dynamics check, without the training.

    python experiments/dynamics_check.py RUNS_DIR [RUNS_DIR ...]

For each folder of full runs, the same split as ``licrom train RUNS_DIR`` (``TrainingData`` defaults),
the projection's choice (:func:`licrom.learn.training.choose_rank`) and the replays that check it
(:func:`licrom.learn.training.check_dynamics`), printed as the training report prints them, with
their wall time. docs/results.md section 16 ran it on the converged training runs of the cheese,
box and ball families (``experiments/defaults_experiments.py --converged --runs-only``).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from licrom.learn.training import check_dynamics, choose_rank
from licrom.learn.training_data import TrainingData


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", type=Path, nargs="+", help="folders of full runs (.npz), one object each")
    for folder in ap.parse_args().runs:
        start = time.perf_counter()
        data = TrainingData(folder)
        choice = choose_rank(data)
        print(f"== {folder}: {data.mesh.n_tets} tets, {len(data.train_indices)} training runs")
        print(choice.describe())
        print("\n".join(check_dynamics(data, choice.rank).lines()))
        print(f"   {time.perf_counter() - start:.0f} s in all")


if __name__ == "__main__":
    main()
