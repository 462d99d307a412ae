"""What keeps the truth from converging in time, and what makes it converge (issue 24, part 1).

    python experiments/truth_in_time.py --work out/friction_lag              # the lag against the end normal, ~10 min
    python experiments/truth_in_time.py --passes 0 --drop 0.005 --work out/gentle_drop  # a gentler landing
    python experiments/truth_in_time.py --passes 0 --eta 400 --work out/damped400       # with material damping
    python experiments/truth_in_time.py --small --work /tmp/truth_in_time    # a smoke test, seconds

Section 12 found the full simulation first order in h on the soft cheese's slide, BDF2 as well as
backward Euler, and far from converged at any practical step. Here the same scene (22 deg az 0,
mu 0.3, E = 20 kPa, 6 cm drop) runs on one mesh at h = 10 ... 0.5 ms against h = 0.125 ms, to
separate the suspects:

* friction's normal force, lagged from the step's start (``fn`` at ``x_n``), against the normal force
  at the step's end (:class:`EndNormalSim`: each step solved again from its start with the normal
  forces of that solution's end, ``--passes`` times; the fixed point is friction with the implicit
  normal force);
* the landing (``--drop``), the contact's damping (``--normal-damping``), the friction (``--friction``;
  0.6 sticks at h = 10 ms) and the stiffness (``--youngs-modulus``);
* sensitivity to the start (``--noise-floor``: at each step the same run dropped ``NUDGE`` (0.1 mm)
  higher, against it);
* material damping (``--eta``: ``licrom.Material.viscosity``, a Kelvin-Voigt dissipation on the Green
  strain's rate, :mod:`licrom.full.damping`; with ``--passes 0``), and with it the mesh (``--mesh-resolutions``: only a mesh study at
  ``--mesh-step``, each mesh against the finest as section 12 measures it).

Rows: final centre of mass distance over the size and the non-rigid difference
(``licrom.analysis.compare.nonrigid_error``, frames every 10 ms) against the same variant at the
smallest step; with ``--passes`` >= 1, the two friction variants against each other. Writes
``--work/friction_lag.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import licrom
import numpy as np
from licrom.analysis.compare import first_contact_frame, nonrigid_error
from licrom.full import contact
from licrom.full.device import warp_ready
from licrom.scene.scene import ContactParams, SolverParams

sys.path.insert(0, str(Path(__file__).resolve().parent))
from body_frame_experiments import NUDGE, _on_plane, incline
from truth_convergence import build_mesh, sampled_nonrigid, sampled_positions

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


def build_scene(args: argparse.Namespace, mesh: licrom.Mesh, dt: float, integrator: str, nudge: float = 0.0) -> licrom.Scene:
    """Section 12's cheese scene (22 deg az 0) with ``args``' friction, drop (plus ``nudge``, m), E and contact damping."""
    base = licrom.Scene(material=licrom.Material(youngs_modulus=args.youngs_modulus, poisson_ratio=0.3, density=1000.0, viscosity=args.eta), dt=dt,
                        integrator=integrator, solver=SolverParams(on_failure="record"), contact=ContactParams(normal_damping=args.normal_damping))
    return _on_plane(mesh, base, incline(22.0, 0.0, args.friction), args.drop + nudge, (0.15, 0.1, 0.0))


def run(work: Path, args: argparse.Namespace, dt: float, integrator: str, passes: int, nudge: float = 0.0) -> tuple[licrom.Trajectory, dict]:
    """The run (cached under ``work``): passes 0 is ``licrom.FullSim`` itself (the lag); dropped ``nudge`` m higher."""
    name = (f"cheese_r{args.resolution}_h{dt * 1e3:g}ms_{integrator}_passes{passes}" + (f"_nudge{nudge:g}" if nudge else "")
            + (f"_eta{args.eta:g}" if args.eta else ""))
    path, meta_path = work / f"{name}.npz", work / f"{name}.json"
    if path.exists() and meta_path.exists():
        return licrom.Trajectory.load(path), json.loads(meta_path.read_text())
    mesh = build_mesh("cheese", args.resolution)
    scene = build_scene(args, mesh, dt, integrator, nudge)
    sim = licrom.FullSim(mesh, scene, device="cpu") if passes == 0 else EndNormalSim(mesh, scene, passes)
    steps, every = round(args.duration / dt), max(1, round(FRAME_DT / dt))
    t0 = time.perf_counter()
    traj = sim.run(steps, record_every=every)
    meta = {"dt": dt, "integrator": integrator, "passes": passes, "steps": steps, "tets": int(mesh.n_tets),
            "wall_s": time.perf_counter() - t0, "unconverged": int(traj.info.get("unconverged_steps", 0)), "size": float(mesh.size)}
    traj.save(path)
    meta_path.write_text(json.dumps(meta))
    print(f"  {name}: {steps} steps in {meta['wall_s']:.1f} s, {meta['unconverged']} unconverged", flush=True)
    return traj, meta


def mesh_study(work: Path, args: argparse.Namespace, dt: float, integrator: str) -> list[dict]:
    """Each of ``args.mesh_resolutions`` at step ``dt`` against the finest, as section 12's mesh tables measure it:
    at the coarsest mesh's vertices (its lumped masses), each run interpolated in its own mesh's tets."""
    runs = []
    for r in args.mesh_resolutions:
        runs.append(run(work, argparse.Namespace(**{**vars(args), "resolution": r}), dt, integrator, 0))
    coarse = build_mesh("cheese", min(args.mesh_resolutions))
    points, weights = coarse.vertices, coarse.vertex_masses(1000.0)
    ref = runs[-1][0]
    ref_s, ref_com, start = sampled_positions(ref, points), ref.centers_of_mass()[-1], first_contact_frame(ref) or 0
    rows = []
    for traj, meta in runs:
        row = {**meta, "com": float(np.linalg.norm(traj.centers_of_mass()[-1] - ref_com) / ref.mesh.size),
               "nonrigid": sampled_nonrigid(ref_s, sampled_positions(traj, points), weights, start)}
        rows.append(row)
        print(f"{integrator} h = {dt * 1e3:g} ms, {meta['tets']} tets: COM {row['com']:.1%} non-rigid {row['nonrigid']:.1%} "
              f"against {ref.mesh.n_tets} tets ({meta['wall_s']:.0f} s)", flush=True)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--work", default="out/friction_lag")
    ap.add_argument("--resolution", type=int, default=8, help="meshes.cheese resolution (8: 864 tets)")
    ap.add_argument("--duration", type=float, default=1.5, help="simulated seconds")
    ap.add_argument("--time-steps", type=float, nargs="+", default=[0.01, 0.005, 0.0025, 0.001, 0.0005, 0.000125])
    ap.add_argument("--integrators", nargs="+", default=["backward_euler", "bdf2"])
    ap.add_argument("--passes", type=int, default=1, help="solves again per step with the end's normal forces")
    ap.add_argument("--friction", type=float, default=0.3, help="mu (0.6: the cheese sticks)")
    ap.add_argument("--drop", type=float, default=0.06, help="height above the plane, m")
    ap.add_argument("--youngs-modulus", type=float, default=2.0e4, help="E, Pa")
    ap.add_argument("--normal-damping", type=float, default=0.0, help="the contact's k_d, N s/m^3")
    ap.add_argument("--eta", type=float, default=0.0, help="Kelvin-Voigt viscosity (Material.viscosity), Pa s, with --passes 0")
    ap.add_argument("--noise-floor", action="store_true", help="also each step's run dropped NUDGE higher, against the run itself")
    ap.add_argument("--mesh-resolutions", type=int, nargs="+", metavar="R",
                    help="only a mesh study: these meshes.cheese resolutions at the step --mesh-step, against the finest")
    ap.add_argument("--mesh-step", type=float, default=0.0005, help="h of the mesh study, s")
    ap.add_argument("--small", action="store_true", help="tiny cheese, 0.2 s, three steps")
    args = ap.parse_args()
    if args.small:
        args.resolution, args.duration, args.time_steps = 4, 0.2, [0.01, 0.005, 0.0025]
        args.mesh_step = 0.005 if args.mesh_resolutions else args.mesh_step
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    if args.mesh_resolutions:
        rows = mesh_study(work, args, args.mesh_step, args.integrators[0])
        (work / "mesh.json").write_text(json.dumps({"eta": args.eta, "dt": args.mesh_step, "integrator": args.integrators[0],
                                                    "duration": args.duration, "rows": rows}, indent=1))
        return
    finest = min(args.time_steps)
    variants = sorted({0, args.passes})
    rows = []
    for integrator in args.integrators:
        refs = {p: run(work, args, finest, integrator, p) for p in variants}
        for dt in sorted(args.time_steps, reverse=True):
            runs = {p: run(work, args, dt, integrator, p) for p in variants}
            size = runs[0][1]["size"]
            row = {"integrator": integrator, "dt": dt}
            for p, (traj, meta) in runs.items():
                ref = refs[p][0]
                row["lagged" if p == 0 else "end_normal"] = {
                    "com": float(np.linalg.norm(traj.centers_of_mass()[-1] - ref.centers_of_mass()[-1]) / size),
                    "nonrigid": float(nonrigid_error(ref, traj)), "wall_s": meta["wall_s"], "unconverged": meta["unconverged"],
                    "min_det_f": float(np.min(traj.min_det_f)) if traj.min_det_f is not None else None}
            line = f"{integrator} h = {dt * 1e3:g} ms: lagged COM {row['lagged']['com']:.1%} non-rigid {row['lagged']['nonrigid']:.1%}"
            if args.noise_floor:
                nudged, _ = run(work, args, dt, integrator, 0, NUDGE)
                lagged = runs[0][0]
                row["noise_floor"] = {"com": float(np.linalg.norm(nudged.centers_of_mass()[-1] - lagged.centers_of_mass()[-1]) / size),
                                      "nonrigid": float(nonrigid_error(lagged, nudged))}
                line += f" (noise floor {row['noise_floor']['com']:.1%} / {row['noise_floor']['nonrigid']:.1%})"
            if args.passes:
                a, b = runs[0][0], runs[args.passes][0]
                row["between"] = {"com": float(np.linalg.norm(a.centers_of_mass()[-1] - b.centers_of_mass()[-1]) / size),
                                  "nonrigid": float(nonrigid_error(a, b))}
                line += (f"; end normal COM {row['end_normal']['com']:.1%} non-rigid {row['end_normal']['nonrigid']:.1%}; "
                         f"between {row['between']['com']:.1%} / {row['between']['nonrigid']:.1%}")
            rows.append(row)
            print(line, flush=True)
            (work / "friction_lag.json").write_text(json.dumps({"resolution": args.resolution, "passes": args.passes, "drop": args.drop,
                                                                "youngs_modulus": args.youngs_modulus, "normal_damping": args.normal_damping,
                                                                "duration": args.duration, "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
