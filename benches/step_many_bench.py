"""Many reduced scenes at once: ``ReducedSim.step_many`` against stepping the same scenes in a Python loop.

``--scenes`` copies of one reduced model of the cheese, each on its own incline with its own
friction and drop (so that the scenes differ in cost, as a batch of real scenes would), take
``--steps`` steps:

- ``loop``: ``sim.step()`` for every scene in turn, for every step (one Python call per scene step);
- ``batched, threads t``: one ``ReducedSim.step_many(sims, steps, threads=t)`` call;
- ``per-step calls, threads t``: ``steps`` calls ``ReducedSim.step_many(sims, threads=t)`` (the
  pattern of a controller or a game that looks at every scene between steps).

Prints scene steps per second for each (the best of ``--repeat`` timings, the variants taking
turns), from one run, and checks that every variant ends in the loop's states, bit for bit. The model is a trained one (``--model``) or a smooth
polynomial stand-in basis of ``--modes`` learned modes, in the world frame or, with ``--frame body``,
in the body frame (a trained model runs in its own frame).

    python benches/step_many_bench.py --scenes 16 --steps 20 --threads 1 2
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from compare_speed import polynomial_basis
from licrom import Plane, ReducedSim, meshes
from licrom.data.presets import report_dataset_spec
from licrom.learn.model import Model
from licrom.reduced.body import BodyFrameSim
from licrom.scene.placement import drop_state, initial_state_on_plane
from licrom.subspace.body_basis import BodyFrameBasis
from licrom.subspace.cubature import ContactPoints, Cubature


def build(args: argparse.Namespace) -> list:
    """The scenes' simulations, at their drops."""
    if args.model:
        model = Model.load(args.model)
        mesh, base = model.mesh, model.default_scene
        basis = model
    else:
        mesh = meshes.cheese(resolution=args.resolution)
        base = report_dataset_spec("cheese", resolution=4).base_scene
        basis = polynomial_basis(mesh, args.modes)
    density = base.material.density
    cubature = Cubature.naive(mesh, min(args.cubature, mesh.n_tets))
    contacts = ContactPoints.subset(mesh, min(args.contacts, len(mesh.boundary_vertices)))
    sims = []
    for k in range(args.scenes):
        plane = Plane.incline(5.0 + 25.0 * k / max(args.scenes - 1, 1), 0.2 + 0.6 * ((3 * k) % args.scenes) / args.scenes)
        state = initial_state_on_plane(drop_state(mesh, density, 0.002 + 0.003 * (k % 4), rotation=(0.1 * (k % 3), 0.05, 0.0)),
                                       plane, mesh, density)
        scene = base.replace(planes=(plane,), initial=state)
        if args.frame == "body" and not args.model:
            # The stand-in's polynomial modes in the body frame (its affine modes are the frame's).
            sims.append(BodyFrameSim(BodyFrameBasis(mesh, learned=basis.bases[1], density=density), mesh, scene, cubature=cubature,
                                     contact_points=contacts))
        else:  # a trained model runs in its own frame
            sims.append(ReducedSim(basis, mesh, scene, cubature=cubature, contact_points=contacts))
    return sims


def state(sim) -> list[bytes]:
    names = ("q", "qdot", "center", "rotation", "velocity", "angular_velocity")
    return [getattr(sim, n).tobytes() for n in names if hasattr(sim, n)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default=None, help="trained model (.lcm); default: polynomial stand-in basis on a cheese")
    ap.add_argument("--frame", choices=["world", "body"], default="world", help="frame of the stand-in basis: world (ReducedSim) or body (BodyFrameSim)")
    ap.add_argument("--resolution", type=int, default=12, help="cheese resolution of the stand-in")
    ap.add_argument("--modes", type=int, default=20, help="learned modes of the stand-in basis")
    ap.add_argument("--cubature", type=int, default=1000, help="cubature tets (naive scheme)")
    ap.add_argument("--contacts", type=int, default=1000, help="contact points (a subset of the boundary vertices)")
    ap.add_argument("--scenes", type=int, default=16, help="scenes stepped together")
    ap.add_argument("--steps", type=int, default=20, help="steps of each scene (the drops land within the first ten)")
    ap.add_argument("--threads", type=int, nargs="+", default=[1, 2], help="thread counts of the batched calls")
    ap.add_argument("--repeat", type=int, default=3, help="timings of each variant, the best reported (the variants take turns)")
    args = ap.parse_args()

    sims = build(args)
    # The drops as construction sets them (set_state then starts afresh, as construction does).
    start_states = [s.scene.initial.apply(s.mesh.vertices, s.mesh.vertex_masses(s.scene.material.density)) for s in sims]

    def reset() -> None:
        for s, (p, v) in zip(sims, start_states):
            s.set_state(p, v)
            s.time = 0.0

    def loop() -> None:
        for _ in range(args.steps):
            for s in sims:
                s.step()

    variants = {"loop": loop}
    for t in args.threads:
        variants[f"batched, threads {t}"] = lambda t=t: ReducedSim.step_many(sims, args.steps, threads=t)
    for t in args.threads:
        variants[f"per-step calls, threads {t}"] = lambda t=t: [ReducedSim.step_many(sims, threads=t) for _ in range(args.steps)]

    print(f"{args.scenes} scenes x {args.steps} steps; {type(sims[0]).__name__}, {sims[0].n_modes} dofs, "
          f"{sims[0].cubature.count} cubature tets, {sims[0].contact_points.count} contact points; "
          f"{len(os.sched_getaffinity(0))} cores available; best of {args.repeat}")
    reset()
    loop()
    expected = [state(s) for s in sims]
    best = dict.fromkeys(variants, float("inf"))
    for _ in range(args.repeat):
        for label, run in variants.items():
            reset()
            start = time.perf_counter()
            run()
            best[label] = min(best[label], time.perf_counter() - start)
            if [state(s) for s in sims] != expected:
                raise SystemExit(f"{label}: the states differ from the loop's")
    work = args.scenes * args.steps
    for label, seconds in best.items():
        print(f"{label:<28} {seconds:8.3f} s  {work / seconds:10.1f} scene steps/s  x{best['loop'] / seconds:5.2f}")
    print("every variant ends in the loop's states, bit for bit")


if __name__ == "__main__":
    main()
