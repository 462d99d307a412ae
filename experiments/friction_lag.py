"""Does the lagged normal force of friction keep the truth from converging in time? (issue 24, part 1)

    python experiments/friction_lag.py --work out/friction_lag          # ~10 min on 2 cores
    python experiments/friction_lag.py --small --work /tmp/friction_lag  # a smoke test, seconds

Section 12 found the full simulation first order in h on the soft cheese's slide, BDF2 as well as
backward Euler, and named the friction's normal force, lagged from the step's start (``fn`` at
``x_n``), as one suspect. Here the same scene (22 deg az 0, mu 0.3, E = 20 kPa, 6 cm drop) runs on
one mesh at h = 10 ... 0.5 ms against h = 0.125 ms, with the lag (the model of ``licrom.FullSim``) and
with the normal force taken at the step's end instead: each step is solved, then solved again from its
start with the normal forces of that solution's end (``--passes`` times; the fixed point is friction
with the implicit normal force). If the lag were what holds the order down, the second variant would
converge faster, and BDF2 with it at second order. Rows: final centre of mass distance over the size
and the non-rigid difference (``licrom.analysis.compare.nonrigid_error``, frames every 10 ms) against
the same variant at the smallest step; beside them, the two variants against each other at each step.
Writes ``--work/friction_lag.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import licrom
import numpy as np
from licrom.analysis.compare import nonrigid_error
from licrom.full import contact
from licrom.full.device import warp_ready

sys.path.insert(0, str(Path(__file__).resolve().parent))
from truth_convergence import build_mesh, build_scene

FRAME_DT = 0.01  # s


class EndNormalSim(licrom.FullSim):
    """The full simulation with friction's normal force at the step's end: each step solved ``passes`` more
    times from its start, the normal forces taken from the previous solution's end positions."""

    def __init__(self, mesh: licrom.Mesh, scene: licrom.Scene, passes: int) -> None:
        super().__init__(mesh, scene, device="cpu")
        self.passes = passes
        self._normal_at = None

    def _begin_step(self) -> None:
        super()._begin_step()
        if self._normal_at is not None and len(self._contact_idx) and self._n_planes:
            warp_ready().launch(contact.lagged_normal_kernel, dim=(len(self._contact_idx), self._n_planes), device=self.device,
                                inputs=[self._normal_at, self._contacts])

    def step(self) -> tuple[int, float]:
        wp = warp_ready()
        start = [wp.clone(a) for a in (self._x, self._v, self._x_prev, self._v_prev)]
        flags = (self._have_prev, self.time, self._step_index)
        out = super().step()
        for _ in range(self.passes):
            self._normal_at = wp.clone(self._x)
            for now, saved in zip((self._x, self._v, self._x_prev, self._v_prev), start):
                wp.copy(now, saved)
            self._have_prev, self.time, self._step_index = flags
            out = super().step()
        self._normal_at = None
        return out


def run(work: Path, resolution: int, dt: float, duration: float, integrator: str, passes: int) -> tuple[licrom.Trajectory, dict]:
    """The run (cached under ``work``): passes 0 is ``licrom.FullSim`` itself (the lag)."""
    name = f"cheese_r{resolution}_h{dt * 1e3:g}ms_{integrator}_passes{passes}"
    path, meta_path = work / f"{name}.npz", work / f"{name}.json"
    if path.exists() and meta_path.exists():
        return licrom.Trajectory.load(path), json.loads(meta_path.read_text())
    mesh = build_mesh("cheese", resolution)
    scene = build_scene("cheese", mesh, dt, integrator)
    sim = licrom.FullSim(mesh, scene, device="cpu") if passes == 0 else EndNormalSim(mesh, scene, passes)
    steps, every = round(duration / dt), max(1, round(FRAME_DT / dt))
    t0 = time.perf_counter()
    traj = sim.run(steps, record_every=every)
    meta = {"dt": dt, "integrator": integrator, "passes": passes, "steps": steps, "tets": int(mesh.n_tets),
            "wall_s": time.perf_counter() - t0, "unconverged": int(traj.info.get("unconverged_steps", 0)), "size": float(mesh.size)}
    traj.save(path)
    meta_path.write_text(json.dumps(meta))
    print(f"  {name}: {steps} steps in {meta['wall_s']:.1f} s, {meta['unconverged']} unconverged", flush=True)
    return traj, meta


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--work", default="out/friction_lag")
    ap.add_argument("--resolution", type=int, default=8, help="meshes.cheese resolution (8: 864 tets)")
    ap.add_argument("--duration", type=float, default=1.5, help="simulated seconds")
    ap.add_argument("--time-steps", type=float, nargs="+", default=[0.01, 0.005, 0.0025, 0.001, 0.0005, 0.000125])
    ap.add_argument("--integrators", nargs="+", default=["backward_euler", "bdf2"])
    ap.add_argument("--passes", type=int, default=1, help="solves again per step with the end's normal forces")
    ap.add_argument("--small", action="store_true", help="tiny cheese, 0.2 s, three steps")
    args = ap.parse_args()
    if args.small:
        args.resolution, args.duration, args.time_steps = 4, 0.2, [0.01, 0.005, 0.0025]
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    finest = min(args.time_steps)
    rows = []
    for integrator in args.integrators:
        refs = {p: run(work, args.resolution, finest, args.duration, integrator, p) for p in (0, args.passes)}
        for dt in sorted(args.time_steps, reverse=True):
            runs = {p: run(work, args.resolution, dt, args.duration, integrator, p) for p in (0, args.passes)}
            size = runs[0][1]["size"]
            row = {"integrator": integrator, "dt": dt}
            for p, (traj, meta) in runs.items():
                ref = refs[p][0]
                key = "lagged" if p == 0 else "end_normal"
                row[key] = {"com": float(np.linalg.norm(traj.centers_of_mass()[-1] - ref.centers_of_mass()[-1]) / size),
                            "nonrigid": float(nonrigid_error(ref, traj)), "wall_s": meta["wall_s"], "unconverged": meta["unconverged"]}
            a, b = runs[0][0], runs[args.passes][0]
            row["between"] = {"com": float(np.linalg.norm(a.centers_of_mass()[-1] - b.centers_of_mass()[-1]) / size),
                              "nonrigid": float(nonrigid_error(a, b))}
            rows.append(row)
            print(f"{integrator} h = {dt * 1e3:g} ms: lagged COM {row['lagged']['com']:.1%} non-rigid {row['lagged']['nonrigid']:.1%}; "
                  f"end normal COM {row['end_normal']['com']:.1%} non-rigid {row['end_normal']['nonrigid']:.1%}; "
                  f"between {row['between']['com']:.1%} / {row['between']['nonrigid']:.1%}", flush=True)
            (work / "friction_lag.json").write_text(json.dumps({"resolution": args.resolution, "passes": args.passes,
                                                                "duration": args.duration, "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
