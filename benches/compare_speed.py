"""Full-space vs reduced per-step time on the same cheese meshes, printed as a ratio from one run.

Both simulations run the same scene (the cheese landing on a 20 degree incline with
mu 0.5) on the same mesh. The reduced model is a trained LiCROM model (``--model``),
evaluated on each mesh (the subspace is continuous, so one model serves every
resolution); without a model, a smooth polynomial basis of the same size stands in.

    python benches/compare_speed.py --model licrom-out/cheese/model.lcm --resolutions 15 24 42
"""

from __future__ import annotations

import argparse
import math
import time

import licrom
import numpy as np
from licrom import AffineBasis, FullSim, MeshBasis, Plane, ReducedSim, StackedBasis, meshes
from licrom.analysis.compare import time_steps
from licrom.data.presets import report_dataset_spec
from licrom.scene.placement import drop_state, initial_state_on_plane
from licrom.subspace.cubature import ContactPoints, Cubature


def polynomial_basis(mesh: licrom.Mesh, r: int) -> StackedBasis:
    """Affine modes + ``r`` smooth polynomial modes (degree 2 and 3 monomials times e_i)."""
    x = (mesh.vertices - mesh.vertices.mean(0)) / mesh.size
    monomials = [x[:, i] * x[:, j] for i in range(3) for j in range(i, 3)]
    monomials += [x[:, i] * x[:, j] * x[:, k] for i in range(3) for j in range(i, 3) for k in range(j, 3)]
    modes = np.zeros((mesh.n_vertices, 3, r))
    for c in range(r):
        modes[:, c % 3, c] = monomials[(c // 3) % len(monomials)] * (1 + c // (3 * len(monomials)))
    return StackedBasis(AffineBasis(), MeshBasis(mesh, modes))


def scene_for(mesh: licrom.Mesh):
    base = report_dataset_spec("cheese", resolution=4).base_scene
    plane = Plane.incline(20.0, 0.5)
    state = initial_state_on_plane(drop_state(mesh, base.material.density, 0.01), plane, mesh, base.material.density)
    return base.replace(planes=(plane,), initial=state)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default=None, help="trained model (.lcm); default: polynomial stand-in basis")
    ap.add_argument("--modes", type=int, default=20, help="learned modes of the stand-in basis")
    ap.add_argument("--resolutions", type=int, nargs="+", default=[15, 24, 42], help="cheese resolutions")
    ap.add_argument("--warmup", type=int, default=6, help="steps run before timing (the 1 cm drop lands in 5)")
    ap.add_argument("--full-steps", type=int, default=6, help="full-space steps timed")
    ap.add_argument("--reduced-steps", type=int, default=200, help="reduced steps timed")
    ap.add_argument("--cubature", type=int, default=1000, help="cubature tets")
    ap.add_argument("--contacts", type=int, default=1000, help="contact points (farthest-point subset)")
    ap.add_argument("--device", default="cpu", help="full simulation device")
    args = ap.parse_args()

    model = licrom.Model.load(args.model) if args.model else None
    rows = []
    for res in args.resolutions:
        mesh = meshes.cheese(resolution=res)
        scene = scene_for(mesh)
        basis = model if model is not None else polynomial_basis(mesh, args.modes)

        # Both are timed over the same steps, once the cheese has landed and rests in contact.
        full_ms, full_its = time_steps(FullSim(mesh, scene, device=args.device), args.full_steps, warmup=args.warmup)
        t = time.perf_counter()
        reduced = ReducedSim(basis, mesh, scene, cubature=Cubature.naive(mesh, args.cubature),
                             contact_points=ContactPoints.subset(mesh, args.contacts))
        setup = time.perf_counter() - t
        red_ms, red_its = time_steps(reduced, args.reduced_steps, warmup=args.warmup)
        rows.append((res, mesh.n_tets, full_ms, full_its, red_ms, red_its, setup, full_ms / red_ms))
        print(f"resolution {res}: {mesh.n_tets} tets done", flush=True)

    k = (model.n_modes if model is not None else 12 + args.modes)
    print(f"\nreduced: {k} dofs ({'trained model' if model else 'polynomial stand-in'}), "
          f"{args.cubature} cubature tets, {args.contacts} contact points; full on {args.device}")
    print(f"{'res':>4} {'tets':>8} {'full ms/step':>13} {'full its':>9} {'reduced ms/step':>16} {'red its':>8} {'setup s':>8} {'ratio':>9}")
    for res, tets, fm, fi, rm, ri, setup, ratio in rows:
        print(f"{res:>4} {tets:>8} {fm:>13.1f} {fi:>9.1f} {rm:>16.4f} {ri:>8.1f} {setup:>8.2f} {ratio:>8.0f}x")
    if rows and not math.isfinite(rows[-1][-1]):
        raise SystemExit("non-finite timing")


if __name__ == "__main__":
    main()
