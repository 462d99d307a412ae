"""Full-space step cost: per-step time, Newton and CG iterations for the cheese at ~5k, 20k, 100k tets.

The cheese lands on a 20 degree incline (mu 0.5): it starts resting on the plane, lying
on its largest face, and moving down the slope and into the plane at 0.5 m/s, so every
measured step has contact, friction (stick and slip) and elastic deformation. One warm-up
step (kernel compilation, first allocations) is excluded; then ``--steps`` steps are timed.

    python benches/full_sim_bench.py                      # cpu, resolutions 15 24 40
    python benches/full_sim_bench.py --device cuda
    python benches/full_sim_bench.py --resolutions 15 24 --steps 5

This is a measurement, not a test: nothing is asserted.
"""

from __future__ import annotations

import argparse
import math
import platform
import time

import licrom
import numpy as np
from licrom import ContactParams, InitialState, Material, Plane, Scene, meshes
from licrom.full import FullSim


def bench_scene(mesh: licrom.Mesh, slope_deg: float = 20.0, friction: float = 0.5) -> Scene:
    t = math.radians(slope_deg)
    normal = np.array([math.sin(t), 0.0, math.cos(t)])
    downhill = np.array([math.cos(t), 0.0, -math.sin(t)])
    lo, hi = mesh.bounds
    half_height = 0.5 * (hi[2] - lo[2])
    return Scene(
        material=Material(youngs_modulus=1.0e5, poisson_ratio=0.3, density=1000.0),
        planes=(Plane.incline(slope_deg, friction),),
        contact=ContactParams(),
        initial=InitialState(
            translation=tuple(normal * half_height),
            rotation=(0.0, t, 0.0),
            velocity=tuple(0.5 * downhill - 0.5 * normal),
        ),
    )


def run(resolution: int, device: str, steps: int) -> dict:
    mesh = meshes.cheese(resolution=resolution)
    scene = bench_scene(mesh)
    start = time.perf_counter()
    sim = FullSim(mesh, scene, device=device)
    sim.step()  # warm-up: kernel compilation and first launches
    setup = time.perf_counter() - start
    seconds, newton, cg = [], [], []
    for _ in range(steps):
        sim.step()
        st = sim.last_stats
        seconds.append(st.seconds)
        newton.append(st.iterations)
        cg.append(st.linear_iterations)
    return {
        "resolution": resolution,
        "tets": mesh.n_tets,
        "vertices": mesh.n_vertices,
        "contacts": len(sim.contact_indices),
        "setup_s": setup,
        "step_ms": 1e3 * float(np.mean(seconds)),
        "step_ms_max": 1e3 * float(np.max(seconds)),
        "newton": float(np.mean(newton)),
        "newton_max": int(np.max(newton)),
        "cg": float(np.mean(cg)),
        "cg_per_newton": float(np.sum(cg) / max(np.sum(newton), 1)),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cpu", help="cpu, cuda or cuda:N")
    parser.add_argument("--resolutions", type=int, nargs="+", default=[15, 24, 40],
                        help="cheese resolutions (15 ~ 6k, 24 ~ 22k, 40 ~ 105k tets)")
    parser.add_argument("--steps", type=int, default=5, help="timed steps per mesh after the warm-up step")
    args = parser.parse_args()

    print(f"licrom {licrom.__version__} full-space step benchmark, device {args.device}, {platform.processor() or platform.machine()}")
    print("cheese on a 20 deg incline (mu 0.5), E = 1e5 Pa, h = 0.01 s, tolerance 1e-6 m/s")
    header = f"{'res':>4} {'tets':>8} {'verts':>7} {'contacts':>8} {'step ms':>9} {'max ms':>9} {'newton':>7} {'max':>4} {'cg/step':>8} {'cg/newton':>9} {'setup s':>8}"
    print(header)
    print("-" * len(header))
    for res in args.resolutions:
        r = run(res, args.device, args.steps)
        print(
            f"{r['resolution']:>4} {r['tets']:>8} {r['vertices']:>7} {r['contacts']:>8} {r['step_ms']:>9.1f} "
            f"{r['step_ms_max']:>9.1f} {r['newton']:>7.1f} {r['newton_max']:>4} {r['cg']:>8.0f} {r['cg_per_newton']:>9.1f} {r['setup_s']:>8.1f}",
            flush=True,
        )


if __name__ == "__main__":
    main()
