"""Does the online error estimate rank reduced runs by their true non-rigid error, and flag the bad ones?

    python experiments/error_estimate_validation.py [--work out/body_frame] [--r 2 4 8 20 60] [--small] [--converged]

For every held-out run of the families of ``experiments/body_frame_experiments.py`` (cheese:
new slopes, friction and azimuth; box: tipping and tumbling; sphere: rolling), plus the
first held-out cheese scene with a softer material (E = 10 kPa) and on a finer mesh of the
cheese (resolution 10, the res-8 POD modes interpolated onto it), the script runs the
body-frame model with POD(r) modes of the family's training runs for each r, and compares

* the true error, :func:`licrom.analysis.compare.nonrigid_error` against the full run, with
* the run-level estimate, the last frame of ``Trajectory.error_estimate``.

It prints the table, Spearman's rho over all runs and within each family, the flagging
confusion at :data:`licrom.reduced.error_estimate.ERROR_THRESHOLD` against true errors above 15 %,
and the estimate's cost against the step's (median over the steps of one run of the cheese),
and writes ``--work/error_estimate.json``. Full runs are cached under ``--work/full`` (shared
with ``body_frame_experiments.py``). ``--small`` runs tiny meshes for a few steps (a smoke
test, under a minute). ``--converged`` runs every family at a converged truth
(``body_frame_experiments.at_converged_truth``: BDF2 at 1 ms, the ball 0.5 ms, viscosity 400 Pa s,
frames every 10 ms), where the step is ten to twenty times shorter than the 10 ms the estimate was first set at.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
import warnings
from pathlib import Path

import licrom
import numpy as np
from body_frame_experiments import FAMILIES, Case, Setting, _on_plane, at_converged_truth, full_run, incline
from licrom import MeshBasis, meshes
from licrom._io import atomic_path
from licrom.analysis.compare import nonrigid_error
from licrom.reduced.body import BodyFrameSim
from licrom.reduced.error_estimate import ERROR_THRESHOLD
from scipy.stats import spearmanr

BAD = 0.15  # a run whose true non-rigid error exceeds this must be flagged


def interpolated_basis(basis: MeshBasis, mesh: licrom.Mesh) -> MeshBasis:
    """``basis`` (bound to its mesh) carried onto another mesh of the object by linear interpolation."""
    tets, bary = basis.mesh.locate(mesh.vertices)
    values = basis.values(basis.mesh.vertices)
    return MeshBasis(mesh, np.einsum("pa,paik->pik", bary, values[basis.mesh.tets[tets]]))


def reduced_row(family: str, kind: str, r: int, full: licrom.Trajectory, sim: BodyFrameSim, steps: int, record_every: int = 1) -> dict:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", licrom.LicromWarning)
        red = sim.run(steps, record_every=record_every)
    return {"family": family, "kind": kind, "r": r, "true": nonrigid_error(full, red), "estimate": float(red.error_estimate[-1]),
            "step_ms": 1e3 * float(np.median(red.step_seconds))}


def cost_ratio(sim: BodyFrameSim, steps: int) -> tuple[float, float]:
    """Wall time of the steps and of the estimate's work (``ErrorMonitor.after_step`` and ``finish``) over one run, s.

    The estimate evaluates the residual every ``stride``-th step and keeps the sample positions
    of the steps before that its integrator reads, so its cost per step is its total over the run divided by the steps.
    """
    mon = sim._monitor
    history = [sim._previous_positions(k) for k in range(mon.history_length - 1, 0, -1)] + [sim.positions]
    mon.start([x[mon.vertices] for x in history])
    step_s, est_s = 0.0, 0.0

    def deformation(q: np.ndarray) -> float:
        return float(q @ sim._modal_mass @ q)

    for _ in range(steps):
        t0 = time.perf_counter()
        sim.step()
        t1 = time.perf_counter()
        mon.after_step(lambda: (sim.q, sim.center, sim.rotation), deformation)
        t2 = time.perf_counter()
        step_s += t1 - t0
        est_s += t2 - t1
    t0 = time.perf_counter()
    mon.finish(sim.q, deformation)  # the cubature term's evaluation at the run's end
    return step_s, est_s + time.perf_counter() - t0


def cost(setting: Setting, case: Case, r: int, passes: int) -> dict:
    """The estimate's cost against the step's on ``case`` with POD(r) over ``passes`` runs: the run of
    median ratio, and the ratio of the least-disturbed totals (the machine may be shared, so single
    runs are noisy)."""
    runs = [cost_ratio(BodyFrameSim(setting.body_basis(setting.body_pod(r)), setting.mesh, case.scene), setting.family.steps)
            for _ in range(passes)]
    ratios = [e / s for s, e in runs]
    k = int(np.argsort(ratios)[len(ratios) // 2])
    steps = setting.family.steps
    return {"r": r, "tets": setting.mesh.n_tets, "passes": passes, "steps": steps, "step_ms": 1e3 * runs[k][0] / steps,
            "estimate_ms": 1e3 * runs[k][1] / steps, "ratio": ratios[k], "ratio_min": min(ratios), "ratio_max": max(ratios),
            "ratio_of_fastest": min(e for _, e in runs) / min(s for s, _ in runs)}


def confusion(rows: list[dict]) -> dict:
    flagged = [row["estimate"] > ERROR_THRESHOLD for row in rows]
    bad = [row["true"] > BAD for row in rows]
    return {"bad": sum(bad), "flagged": sum(flagged), "bad_flagged": sum(f and b for f, b in zip(flagged, bad)),
            "missed": sum(b and not f for f, b in zip(flagged, bad)), "false_alarms": sum(f and not b for f, b in zip(flagged, bad))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--work", type=Path, default=Path("out/body_frame"))
    ap.add_argument("--r", type=int, nargs="+", default=[2, 4, 8, 20, 60], help="POD modes of the reduced runs")
    ap.add_argument("--small", action="store_true", help="tiny meshes, few steps: a smoke test")
    ap.add_argument("--converged", action="store_true", help="every family at a converged truth (BDF2, viscosity; --work/converged)")
    args = ap.parse_args()
    work = args.work / "small" if args.small else args.work
    work = work / "converged" if args.converged else work
    sizes = [1, 4] if args.small else args.r
    rows, t_start = [], time.perf_counter()
    for name, make in FAMILIES.items():
        fam = at_converged_truth(name, make(args.small)) if args.converged else make(args.small)
        every = fam.record_every
        train = [full_run(work, c.name, fam.mesh, c.scene, fam.steps, every) for c in fam.training]
        setting = Setting(fam, train, work / "models", 1)
        cases = [(c, fam.mesh) for c in fam.held_out]
        if name == "cheese":
            first = fam.held_out[0]
            soft = first.scene.replace(material=dataclasses.replace(first.scene.material, youngs_modulus=1.0e4))
            cases.append((Case(f"{first.name}_E10k", f"softer (E = 10 kPa): {first.kind}", True, soft), fam.mesh))
            fine = meshes.cheese(resolution=6 if args.small else 10)
            plane = first.scene.planes[0]
            scene = _on_plane(fine, first.scene, incline(plane.slope_deg, 0.0, plane.friction), 0.06, (0.15, 0.1, 0.0))
            cases.append((Case(f"{first.name}_res{6 if args.small else 10}", f"finer mesh: {first.kind}", True, scene), fine))
        for case, mesh in cases:
            full = full_run(work, case.name, mesh, case.scene, fam.steps, every)
            for r in sizes:
                pod = setting.body_pod(r)
                basis = setting.body_basis(pod if mesh is fam.mesh else interpolated_basis(pod, mesh))
                basis = basis if mesh is fam.mesh else basis.on(mesh)
                rows.append(reduced_row(name, case.kind, r, full, BodyFrameSim(basis, mesh, case.scene), fam.steps, every))
                print(f"{name:7s} {case.kind[:46]:46s} r={r:3d}  true {100 * rows[-1]['true']:7.2f} %  "
                      f"estimate {100 * rows[-1]['estimate']:7.2f} %", flush=True)
        if name == "cheese":
            timing = cost(setting, fam.held_out[0], sizes[-1], 3 if args.small else 7)
    true = np.array([row["true"] for row in rows])
    est = np.array([row["estimate"] for row in rows])
    rho = {"all": float(spearmanr(true, est)[0])}
    for name in FAMILIES:
        sel = [i for i, row in enumerate(rows) if row["family"] == name]
        rho[name] = float(spearmanr(true[sel], est[sel])[0]) if len(sel) > 2 else float("nan")
    conf = confusion(rows)
    print("Spearman rho: " + ", ".join(f"{k} {v:.3f}" for k, v in rho.items()))
    print(f"threshold {100 * ERROR_THRESHOLD:.0f} %: {conf}")
    print(f"cost on the {timing['tets']}-tet cheese, r = {timing['r']} (median of {timing['passes']} runs of {timing['steps']} steps): "
          f"step {timing['step_ms']:.3f} ms, estimate {timing['estimate_ms']:.4f} ms per step, ratio {100 * timing['ratio']:.1f} % "
          f"(runs: {100 * timing['ratio_min']:.1f}-{100 * timing['ratio_max']:.1f} %; fastest totals: {100 * timing['ratio_of_fastest']:.1f} %)")
    with atomic_path(work / "error_estimate.json") as tmp:
        tmp.write_text(json.dumps({"rows": rows, "spearman": rho, "confusion": conf, "threshold": ERROR_THRESHOLD, "bad": BAD,
                                   "cost": timing, "wall_s": time.perf_counter() - t_start}, indent=1))
    print(f"wrote {work / 'error_estimate.json'}")


if __name__ == "__main__":
    main()
