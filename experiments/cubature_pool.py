"""The cubature fit on meshes larger than its candidate pool: its error against every tet's forces.

    python experiments/cubature_pool.py RUNS_DIR HELD_OUT.npz [HELD_OUT.npz ...] [--pools 300 600] [--rank 120]
    python experiments/cubature_pool.py --model MODEL.lcm     # a trained model's stored cubature and a refit

On a large mesh ``Cubature.optimized`` chooses its tets from a random pool of candidates (as many as
``licrom.subspace.cubature.FIT_MEMORY`` holds: about 4000 of the 120k-tet cheese's tets at r = 120). The
first form stands in for that on a small mesh: the body-frame subspace of the training runs of RUNS_DIR (6
affine modes + POD(``--rank``), run-balanced as training balances it), the cubature fitted as training fits
it (256 evenly spaced training poses) from random pools of ``--pools`` tets, and with every tet a candidate;
per fit, its tets, its own residual, its residual against every tet's reduced forces (recomputed here), and
each held-out run's non-rigid error and final centre of mass (``licrom.analysis.compare``). The second
form measures a trained model's stored cubature and a refit of it against every tet's forces at the poses
stored with it. Prints the rows.
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np
from licrom import Material, Trajectory
from licrom.analysis.compare import compare
from licrom.learn.model.trained import Model
from licrom.learn.training.held_out import run_cadence
from licrom.learn.training_data import TrainingData
from licrom.reduced.body import BodyFrameSim
from licrom.rigid import body_frame_displacements
from licrom.subspace.basis import Basis, MeshBasis, SubspaceProjector, run_balanced_weights
from licrom.subspace.body_basis import BodyFrameBasis
from licrom.subspace.cubature import Cubature, model_basis, reduced_forces

SAMPLES = 256  # TrainConfig.cubature_samples


def true_error(fit: Cubature, every: np.ndarray, mesh, basis: Basis, material: Material, samples: np.ndarray) -> float:
    """RMS over the poses of the fit's force error relative to every tet's force (the fit's own measure)."""
    mine = reduced_forces(mesh, basis, material, samples, fit.tets, fit.weights)
    norms = np.linalg.norm(every, axis=1)
    keep = norms > 1e-12 * norms.max()
    return float(np.sqrt(np.mean(np.sum((mine - every)[keep] ** 2, axis=1) / norms[keep] ** 2)))


def pools(args: argparse.Namespace) -> None:
    data = TrainingData(args.runs)
    mesh, material = data.mesh, data.scenes[0].material
    frames = data.train
    pod, _ = MeshBasis.pod(mesh, frames.residuals, args.rank, weights=run_balanced_weights(frames.trajectory, frames.norm2_residual))
    basis = BodyFrameBasis(mesh, pod, density=material.density)
    runs = [t for _, t in data.training_runs + data.held_out]
    u = np.concatenate([t.displacements for t in runs])
    u = u[np.unique(np.linspace(0, len(u) - 1, SAMPLES).round().astype(int))]
    samples = SubspaceProjector(basis.values(mesh.vertices), data.masses).project(body_frame_displacements(mesh.vertices + u, mesh.vertices, data.masses))
    every = reduced_forces(mesh, basis, material, samples)
    held = [Trajectory.load(p) for p in args.held_out]
    print(f"{mesh.n_tets} tets, r = {args.rank}, {len(samples)} poses; per held-out run: non-rigid / final COM")
    for pool in [*args.pools, mesh.n_tets]:
        t0 = time.perf_counter()
        fit = Cubature.optimized(mesh, basis, material, samples, count=1000, candidates=pool, tolerance=1e-2)
        seconds = time.perf_counter() - t0
        cells = []
        for run in held:
            steps, every_k = run_cadence(run)
            c = compare(run, BodyFrameSim(basis, mesh, run.scene, cubature=fit).run(steps, record_every=every_k))
            cells.append(f"{100 * c.nonrigid_error:.1f} % / {100 * c.final_com_error:.2f} %")
        print(f"pool {pool}: {fit.count} tets, fit residual {fit.fit_error:.2e}, against every tet "
              f"{true_error(fit, every, mesh, basis, material, samples):.2e}, {seconds:.1f} s | " + " | ".join(cells), flush=True)


def stored(args: argparse.Namespace) -> None:
    model = Model.load(args.model)
    mesh, material, samples = model.mesh, model.default_scene.material, model.cubature_samples
    basis = model_basis(model)
    t0 = time.perf_counter()
    every = reduced_forces(mesh, basis, material, samples)
    print(f"{mesh.n_tets} tets, r = {model.n_learned}, {len(samples)} stored poses; every tet's forces in {time.perf_counter() - t0:.1f} s")
    fit = model.cubature
    print(f"stored: {fit.count} tets, its residual {fit.fit_error:.2e}, against every tet {true_error(fit, every, mesh, basis, material, samples):.2e}")
    t0 = time.perf_counter()
    refit = Cubature.fitted(model, samples)
    print(f"refit: {refit.count} tets, its residual {refit.fit_error:.2e}, against every tet "
          f"{true_error(refit, every, mesh, basis, material, samples):.2e}, {time.perf_counter() - t0:.1f} s")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="?", help="folder of full runs of one object (its training split is fitted)")
    ap.add_argument("held_out", nargs="*", help="held-out full runs of the same object")
    ap.add_argument("--pools", type=int, nargs="*", default=[300, 600], help="candidate pool sizes (every tet is added)")
    ap.add_argument("--rank", type=int, default=120, help="POD modes of the subspace")
    ap.add_argument("--model", help="a trained model: its stored cubature and a refit against every tet's forces")
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    if args.model:
        stored(args)
    elif args.runs:
        pools(args)
    else:
        ap.error("give RUNS_DIR and held-out runs, or --model")


if __name__ == "__main__":
    main()
