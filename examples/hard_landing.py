"""A hard landing learned from its own run: learned subspaces against POD of the same run.

The README's scene (the cheese dropped from 8 cm onto a 20 degree incline, mu 0.3) is
simulated in full space; the reduced model then runs the same scene in

* the affine modes alone,
* affine + POD modes of this very run (numpy SVD of the residual the affine modes leave),
* every trained model given with ``--models`` (e.g. ``licrom train DATA -o m.lcm`` on the
  trajectory this script writes to ``--work``), with every tet as a cubature point and with
  the naive 1000,

and one table gives, for each, how well the subspace holds the run (projection error of the
residual) and how well a reduced run in it follows the full one.

    python examples/hard_landing.py --work licrom-out/readme --models licrom-out/readme/*.lcm
"""

from __future__ import annotations

import argparse
from pathlib import Path

import licrom
import numpy as np
from licrom import AffineBasis, MeshBasis, Model, ReducedSim, StackedBasis, Trajectory
from licrom.analysis.compare import compare
from licrom.rigid import relative_error
from licrom.subspace.affine import apply_affine, fit_affine
from licrom.subspace.basis import SubspaceProjector
from licrom.subspace.cubature import Cubature


def readme_scene() -> tuple[licrom.Mesh, licrom.Scene]:
    mesh = licrom.meshes.cheese(resolution=12)
    scene = licrom.Scene(planes=(licrom.Plane.incline(20.0, friction=0.3),),
                         initial=licrom.InitialState(translation=(0, 0, 0.08)))
    return mesh, scene


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--work", type=Path, default=Path("licrom-out/readme"), help="folder of the full run (truth.npz)")
    ap.add_argument("--models", type=Path, nargs="*", default=[], help="trained models (.lcm) to evaluate")
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--pod", type=int, nargs="+", default=[10, 20, 40])
    args = ap.parse_args()

    mesh, scene = readme_scene()
    path = args.work / "truth.npz"
    if path.exists():
        truth = Trajectory.load(path)
    else:
        args.work.mkdir(parents=True, exist_ok=True)
        truth = licrom.FullSim(mesh, scene).run(args.steps)
        truth.save(path)
    masses = mesh.vertex_masses(scene.material.density)
    u = truth.displacements
    residual = u - apply_affine(mesh.vertices, fit_affine(mesh.vertices, u, masses))

    bases = [("affine", AffineBasis(), Cubature.full(mesh))]
    bases += [(f"affine + POD {k}", StackedBasis(AffineBasis(), MeshBasis.pod(mesh, residual, k)[0]), Cubature.full(mesh))
              for k in args.pod]
    naive = Cubature.naive(mesh, 1000)
    for p in args.models:
        model = Model.load(p)
        bases += [(p.stem, model, Cubature.full(mesh)), (p.stem, model, naive)]

    print(f"cheese {mesh.n_tets} tets, 8 cm drop onto 20 deg, mu 0.3, {args.steps} steps; "
          f"the residual is {100 * relative_error(u, u - residual, masses):.3f} % of the displacement")
    print("| subspace | modes | cubature | residual projection error | mean rel. error | final COM error / size |")
    print("|---|---|---|---|---|---|")
    for name, basis, cubature in bases:
        values = basis.values(mesh.vertices)
        q = SubspaceProjector(values, masses).project(u)
        projected = np.einsum("nik,fk->fni", values, q)
        proj_err = relative_error(residual, residual - (u - projected), masses)
        c = compare(truth, ReducedSim(basis, mesh, scene, cubature=cubature).run(truth.n_frames - 1))
        print(f"| {name} | {basis.n_modes} | {cubature.scheme} {cubature.count} | {100 * proj_err:.2f} % | "
              f"{100 * c.mean_error:.2f} % | {100 * c.final_com_error:.2f} % |", flush=True)


if __name__ == "__main__":
    main()
