"""Impact frames: what a subspace learned from frames 10 ms apart misses of a landing, and what keeping every step
just after each impact gives back.

    python experiments/impact_frames.py [--work out/converged] [--windows 0 0.05 0.1] [--rank 120] [--write-runs DIR] [--small]
    python experiments/impact_frames.py --resolution 12 --mechanism-only --rank 100     # the mechanism on the 2748-tet mesh

The soft cheese family at the converged truth (section 12: BDF2 at h = 1 ms, viscosity 400 Pa s, frames every 10 ms,
the 1638-tet mesh). For each impact window W (s), its 20 training runs are simulated again keeping every step's
displacement for W after each impact (``FullSim.run(..., impact_window=W)``; W = 0 is the runs of sections 16 and 25),
and the body-frame model with POD(r) of their frames as training weighs them (run-balanced, regular and impact frames
alike; every tet as cubature, so that only the modes differ) runs each held-out scene against its converged truth:
non-rigid error, final centre of mass over the size, and the projection bound of those modes. The mechanism's row:
the new-azimuth scene on POD(r) of its own frames, the 10 ms frames against every step's; ``--resolution`` puts it on
another mesh of the cheese (12: 2748 tets), ``--mechanism-only`` skips the windows' training runs. ``--write-runs DIR`` copies
the training runs of the cheese, the box and the ball at the default window (:data:`licrom.data.dataset.IMPACT_WINDOW`)
into DIR/FAMILY, for ``licrom train`` (section 16's models trained on them).
``--small``: the tiny cheese at h = 5 ms, 40 steps, r = 8.
"""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

import body_frame_experiments as bfe
import numpy as np
from licrom.data.dataset import IMPACT_WINDOW
from licrom.reduced.body import BodyFrameSim
from licrom.subspace.body_basis import BodyFrameBasis
from licrom.subspace.cubature import Cubature

SECTION_TITLE = "## 26. Impact frames: the landing's transient in the training data"


def family(small: bool) -> bfe.Family:
    fam = bfe.cheese_family(small)
    return bfe.with_physics(fam, 0.005, "bdf2", bfe.CONVERGED_VISCOSITY) if small else bfe.at_converged_truth("cheese", fam)


def training_runs(fam: bfe.Family, work: Path, window: float) -> list:
    """The family's training runs with impact frames for ``window`` s after each impact (cached under ``work``,
    ``work/impact_W`` for W > 0)."""
    where = work if window == 0 else work / f"impact_{window:g}"
    return [bfe.full_run(where, c.name, fam.mesh, c.scene, fam.steps, fam.record_every, impact_window=window)
            for c in fam.cases if not c.held_out]


def body_frames(run) -> np.ndarray:
    """A run's regular and impact frames as body-frame displacements."""
    u = np.concatenate([run.displacements, run.impact_displacements])
    return bfe.body_frame_displacements(run.rest_positions + u, run.rest_positions, bfe.masses_of(run))


def held_out_rows(fam: bfe.Family, cases, basis: BodyFrameBasis, truths: dict) -> list[dict]:
    """Each held-out case on the body-frame model of ``basis`` with every tet as cubature, against its truth."""
    rows = []
    for case in cases:
        full = truths[case.name]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the estimate's warning: not what this measures
            reduced = BodyFrameSim(basis, fam.mesh, case.scene, cubature=Cubature.full(fam.mesh)).run(fam.steps, record_every=fam.record_every)
        m = bfe.run_metrics(full, reduced)
        rows.append({"scene": case.kind, "nonrigid": m["nonrigid_error"], "com": m["com_error"], "right": m["stick_slip_right"],
                     "projection": bfe.body_projection_error(full, basis.values(fam.mesh.vertices))})
    return rows


def write_runs(out: Path, work: Path, small: bool) -> None:
    """The training runs of every family of section 16 (cheese, box, ball) at its converged truth, with impact frames
    for :data:`~licrom.data.dataset.IMPACT_WINDOW`, copied into ``out/FAMILY`` for ``licrom train``."""
    for name in ("cheese", "box", "sphere"):
        fam = family(small) if name == "cheese" else bfe.FAMILIES[name](small)
        if name != "cheese":
            fam = bfe.with_physics(fam, 0.005, "bdf2", bfe.CONVERGED_VISCOSITY) if small else bfe.at_converged_truth(name, fam)
        runs = training_runs(fam, work, IMPACT_WINDOW)
        (out / name).mkdir(parents=True, exist_ok=True)
        for case, run in zip((c for c in fam.cases if not c.held_out), runs):
            run.save(out / name / f"{case.name}.npz")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--work", type=Path, default=Path("out/converged"), help="cache of the full runs (the converged truths)")
    ap.add_argument("--windows", type=float, nargs="+", default=[0.0, 0.05, 0.1], help="impact windows to compare, s")
    ap.add_argument("--rank", type=int, default=None, help="POD modes (default 120; 8 with --small)")
    ap.add_argument("--write-runs", type=Path, default=None, help="copy the training runs at the default impact window here")
    ap.add_argument("--docs", type=Path, default=None, help="write the section into DOCS/results.md")
    ap.add_argument("--resolution", type=int, default=10, help="the cheese's mesh (10: 1638 tets, 12: 2748)")
    ap.add_argument("--mechanism-only", action="store_true", help="only the mechanism's row (no training runs)")
    ap.add_argument("--small", action="store_true")
    args = ap.parse_args()
    bfe.CHEESE_RESOLUTION = args.resolution
    fam = family(args.small)
    r = args.rank or (8 if args.small else 120)
    rho = fam.cases[0].scene.material.density
    truths = {c.name: bfe.full_run(args.work, c.name, fam.mesh, c.scene, fam.steps, fam.record_every) for c in fam.held_out}
    lines = ["| impact window | training frames | held-out scene | projection | non-rigid error | final COM / size | stick/slip |",
             "|---|---|---|---|---|---|---|"]
    for window in [] if args.mechanism_only else args.windows:
        runs = training_runs(fam, args.work, window)
        frames = [body_frames(t) for t in runs]
        basis = BodyFrameBasis(fam.mesh, bfe.residual_pod(fam.mesh, frames, bfe.masses_of(runs[0]), r), density=rho)
        for row in held_out_rows(fam, fam.held_out, basis, truths):
            lines.append(f"| {1e3 * window:g} ms | {sum(len(f) for f in frames)} | {row['scene']} | {100 * row['projection']:.2f} % | "
                         f"{100 * row['nonrigid']:.2f} % | {100 * row['com']:.2f} % | {'right' if row['right'] else 'wrong'} |")
            print(lines[-1], flush=True)
    # the mechanism: one held-out run on POD(r) of its own frames, 10 ms apart or every step
    case = next((c for c in fam.held_out if c.figure), fam.held_out[0])
    every = bfe.full_run(args.work, case.name + "_every_step", fam.mesh, case.scene, fam.steps, 1)
    own = [("its frames every 10 ms", truths[case.name]), ("every step", every)]
    lines += ["", f"Own POD({r}) of {case.kind}, every tet as cubature:", "",
              "| frames | count | non-rigid error | final COM / size |", "|---|---|---|---|"]
    for label, run in own:
        frames = body_frames(run)[bfe.contact_start(run):]
        basis = BodyFrameBasis(fam.mesh, bfe.residual_pod(fam.mesh, [frames], bfe.masses_of(run), r), density=rho)
        row = held_out_rows(fam, [case], basis, truths)[0]
        lines.append(f"| {label} | {len(frames)} | {100 * row['nonrigid']:.2f} % | {100 * row['com']:.2f} % |")
        print(lines[-1], flush=True)
    if args.write_runs:
        write_runs(args.write_runs, args.work, args.small)
    if args.docs:
        args.docs.mkdir(parents=True, exist_ok=True)
        bfe.write_section(args.docs, f"{SECTION_TITLE}\n\nMeasured by `python experiments/impact_frames.py` "
                          f"(windows {', '.join(f'{w:g}' for w in args.windows)} s, r = {r}).\n\n" + "\n".join(lines), SECTION_TITLE)


if __name__ == "__main__":
    main()
