"""How tight the cubature that training fits must be: held-out non-rigid error, size, fit and step time per tolerance.

    python experiments/cubature_tolerance.py [--work out/body_frame] [--r 20 60] [--small]

For each family of ``experiments/body_frame_experiments.py`` (its cached full runs) and each r, the
body-frame subspace is the 6 symmetric affine modes + POD(r) of the training runs (balanced as
training balances them: the learned modes come within 1.01x of it), standing in for a trained
model so that no training is needed. Its cubature is fitted as :func:`licrom.train` fits it
(:func:`licrom.learn.training.run.fit_cubature`: at most 256 training poses, evenly spaced) to each
tolerance, and every held-out run is simulated with it, with every tet, and with the report's
1000 naive tets. Printed per family and r: tets kept, fit seconds, the held-out runs' non-rigid
error (``licrom.analysis.compare.nonrigid_error``) and the median reduced step in ms. Writes
``--work/cubature_tolerance.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from body_frame_experiments import FAMILIES, Setting, full_run
from licrom import BodyFrameSim, Cubature
from licrom._io import atomic_path
from licrom.analysis.compare import nonrigid_error
from licrom.rigid import body_frame_displacements
from licrom.subspace.basis import SubspaceProjector

TOLERANCES = (3e-2, 1e-2, 3e-3, 1e-3)
SAMPLES = 256  # TrainConfig.cubature_samples


def training_samples(setting: Setting, basis) -> np.ndarray:
    """Reduced coordinates of at most SAMPLES training poses, evenly spaced over the runs (as training picks them)."""
    mesh = setting.mesh
    frames = np.concatenate([t.displacements for t in setting.train])
    picks = np.unique(np.linspace(0, len(frames) - 1, min(SAMPLES, len(frames))).round().astype(np.int64))
    u = body_frame_displacements(mesh.vertices + frames[picks], mesh.vertices, setting.masses)
    return SubspaceProjector(basis.values(mesh.vertices), setting.masses).project(u)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--work", type=Path, default=Path("out/body_frame"))
    ap.add_argument("--families", nargs="+", default=list(FAMILIES), choices=list(FAMILIES))
    ap.add_argument("--r", type=int, nargs="+", default=[20, 60])
    ap.add_argument("--small", action="store_true", help="tiny meshes, few steps (a smoke test)")
    args = ap.parse_args()
    work = args.work / "small" if args.small else args.work
    sizes = [min(r, 4) for r in args.r] if args.small else args.r
    rows = []
    for name in args.families:
        fam = FAMILIES[name](args.small)
        train = [full_run(work, c.name, fam.mesh, c.scene, fam.steps) for c in fam.training]
        held = [(c, full_run(work, c.name, fam.mesh, c.scene, fam.steps)) for c in fam.held_out]
        setting = Setting(fam, train, work / "models", 1)
        material = fam.cases[0].scene.material
        for r in sizes:
            basis = setting.body_basis(setting.body_pod(r))
            samples = training_samples(setting, basis)
            cubatures = {"full": (Cubature.full(fam.mesh), 0.0), "naive 1000": (Cubature.naive(fam.mesh, 1000), 0.0)}
            for tol in TOLERANCES:
                t0 = time.perf_counter()
                cubatures[f"fitted {tol:g}"] = (Cubature.optimized(fam.mesh, basis, material, samples, tolerance=tol), time.perf_counter() - t0)
            for label, (cub, fit_s) in cubatures.items():
                errors, steps = [], []
                for case, full in held:
                    sim = BodyFrameSim(basis, fam.mesh, case.scene, cubature=cub)
                    reduced = sim.run(fam.steps)
                    errors.append(nonrigid_error(full, reduced))
                    steps.append(float(np.median(reduced.step_seconds)) * 1e3)
                row = {"family": name, "tets": fam.mesh.n_tets, "r": r, "cubature": label, "count": cub.count, "fit_error": cub.fit_error,
                       "fit_s": fit_s, "nonrigid": errors, "step_ms": float(np.median(steps)), "cases": [c.name for c, _ in held]}
                rows.append(row)
                print(f"{name} r={r:3d} {label:>14}: {cub.count:5d} tets, fit {fit_s:5.1f} s, non-rigid "
                      + " / ".join(f"{100 * e:.1f}" for e in errors) + f" %, step {row['step_ms']:.3f} ms", flush=True)
    with atomic_path(work / "cubature_tolerance.json") as tmp:
        tmp.write_text(json.dumps(rows, indent=1))
    print(f"wrote {work / 'cubature_tolerance.json'}")


if __name__ == "__main__":
    main()
