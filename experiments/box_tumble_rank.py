"""The box's held-out runs at body-frame POD(r) of its training runs, every tet as cubature (docs/results.md section 33).

    python experiments/box_tumble_rank.py [--runs out/impact/runs/box] [--ranks 60 120 250]
        [--held-out out/more_scenes/full/box_drawn_*.npz out/converged/full/box_tip_26.npz ...]

The subspace is the one training builds before it learns: the 6 affine modes and POD(r) of the training split's
body-frame displacements, balanced by run (``run_balanced_weights``). Every tet is a cubature point, so r alone
changes between rows. Each held-out full run is replayed with ``BodyFrameSim`` at its own scene, steps and frame
cadence and compared with it (``licrom.analysis.compare``). Prints non-rigid error / final centre of mass (% of the
size) per run and r.
"""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

from licrom import Trajectory
from licrom.analysis.compare import compare
from licrom.learn.training.held_out import run_cadence
from licrom.learn.training_data import TrainingData
from licrom.reduced.body import BodyFrameSim
from licrom.subspace.basis import MeshBasis, run_balanced_weights
from licrom.subspace.body_basis import BodyFrameBasis
from licrom.subspace.cubature import Cubature

HELD_OUT = ["out/more_scenes/full/box_drawn_tumble_30.9_13.3_0.36.npz", "out/more_scenes/full/box_drawn_tumble_31.7_11.4_0.35.npz",
            "out/more_scenes/full/box_drawn_tumble_32.3_11.9_0.37.npz", "out/more_scenes/full/box_drawn_tumble_33.2_13.8_0.4.npz",
            "out/converged/full/box_tumble_32_12.npz", "out/converged/full/box_tip_26.npz"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=Path, default=Path("out/impact/runs/box"), help="the box's training runs (its training split is used)")
    ap.add_argument("--ranks", type=int, nargs="+", default=[60, 120, 250], help="POD sizes r")
    ap.add_argument("--held-out", type=Path, nargs="+", default=[Path(p) for p in HELD_OUT], help="full runs to replay")
    args = ap.parse_args()
    warnings.simplefilter("ignore")  # the reduced runs' AccuracyWarning: the errors are printed
    data = TrainingData(args.runs)
    mesh, material, frames = data.mesh, data.scenes[0].material, data.train
    print(f"{mesh.n_tets} tets; training split {[name for name, _ in data.training_runs]}, {len(frames.residuals)} frames")
    print("r | " + " | ".join(p.stem for p in args.held_out))
    for r in args.ranks:
        pod, _ = MeshBasis.pod(mesh, frames.residuals, r, weights=run_balanced_weights(frames.trajectory, frames.norm2_residual))
        basis = BodyFrameBasis(mesh, pod, density=material.density)
        cells = []
        for path in args.held_out:
            run = Trajectory.load(path)
            steps, every = run_cadence(run)
            c = compare(run, BodyFrameSim(basis, mesh, run.scene, cubature=Cubature.full(mesh)).run(steps, record_every=every))
            cells.append(f"{100 * c.nonrigid_error:.1f} / {100 * c.final_com_error:.1f}")
        print(f"POD({r}) | " + " | ".join(cells), flush=True)


if __name__ == "__main__":
    main()
