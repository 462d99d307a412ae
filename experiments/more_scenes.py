"""The defaults on held-out scenes no earlier section ran: drawn slopes, azimuths, friction and throws.

    python experiments/more_scenes.py [--family cheese] [--model out/converged/models/cheese.lcm] [--scenes 8] [--work out/more_scenes] [--small]
    python experiments/more_scenes.py --family box --scenes 16 --nudged-tumbles 4  # and the first 4 tumbles' nudged full runs

Section 16 judges the defaults on a few held-out scenes of each family, one of each kind. This draws ``--scenes``
more of the same kinds (seeded, placed as the family places its runs), :data:`DRAWS`:

* ``cheese`` (1638 tets): slope 18-32 deg, downhill azimuth anywhere, friction 0.25-0.6;
* ``sphere`` (1074 tets): thrown down slopes of 20-30 deg at friction 0.2-0.5 (downhill along x, as it was trained);
* ``box`` (432 tets): every other scene tips over (slope 20-30 deg, friction 0.8-1.0), the others are thrown to
  tumble (slope 30-35 deg, spin 10-15 rad/s, 0.3-0.5 m/s, friction 0.6), whose targets are 3x the noise floor
  where it is above 2 % (chaotic).

Each runs at the converged truth of section 12 (BDF2, h = 1 ms,
viscosity 400 Pa s) in full and with ``ReducedSim(model, scene=scene)`` (the model's defaults), and prints a
row per scene: the noise floor (the full run against itself dropped 0.1 mm higher), the learned projection
(the full run's body-frame displacements projected onto the model's modes), the reduced run's non-rigid error,
final centre of mass over the size and stick/slip against the full run, its error estimate and median step,
and whether it meets the targets (non-rigid < 10 %, centre of mass < 2 %, stick/slip right). Full runs are
cached under ``--work``; ``--small`` runs two scenes of 20 steps on the tiny cheese with a 1-epoch model.
``--nudged-tumbles N`` also runs in full the first N drawn tumbles moved 0.1 mm along x and dropped 0.1 mm lower
(:data:`NUDGED_TUMBLES`; the moves along y repeat their scenes, the slope being level along y): the further held-out
tumbles of results section 29, which ``experiments/estimate_at_defaults.py`` reads from ``--work/full``.
"""

from __future__ import annotations

import argparse
import json
import warnings
from pathlib import Path

import body_frame_experiments as bfe
import licrom
import numpy as np
from licrom.subspace.body_basis import BodyFrameBasis

SEED = 2026
"""Seed of the drawn scenes."""


DRAWS = ("cheese", "sphere", "box")
"""Families whose scenes can be drawn."""


def drawn_case(family: str, fam: bfe.Family, rng: np.random.Generator, k: int) -> bfe.Case:
    """The ``k``-th drawn held-out scene of ``family`` (``fam`` its family at the original physics)."""
    base = fam.held_out[0].scene
    if family == "cheese":
        slope, az, mu = round(rng.uniform(18.0, 32.0), 1), round(rng.uniform(0.0, 360.0)), round(rng.uniform(0.25, 0.6), 2)
        plane = bfe.incline(slope, az, mu)
        return bfe.Case(f"cheese_drawn_{plane.slope_deg:.1f}_{plane.friction:g}_az{az}", "drawn: " + bfe._label(plane, az), True,
                        bfe._on_plane(fam.mesh, base, plane, 0.06, (0.15, 0.1, 0.0)))
    if family == "sphere":
        slope, mu = round(rng.uniform(20.0, 30.0), 1), round(rng.uniform(0.2, 0.5), 2)
        plane = bfe.incline(slope, 0.0, mu)
        return bfe.Case(f"sphere_drawn_{slope:g}_{mu:g}", "drawn, rolls: " + bfe._label(plane, 0.0), True,
                        bfe._on_plane(fam.mesh, base, plane, 0.1, velocity=(0.5, 0.0, -1.0)))
    if k % 2 == 0:
        slope, mu = round(rng.uniform(20.0, 30.0), 1), round(rng.uniform(0.8, 1.0), 2)
        plane = bfe.incline(slope, 0.0, mu)
        return bfe.Case(f"box_drawn_tip_{slope:g}_{mu:g}", "drawn, tips over: " + bfe._label(plane, 0.0), True,
                        bfe._on_plane(fam.mesh, base, plane, 0.005))
    slope, spin, speed = round(rng.uniform(30.0, 35.0), 1), round(rng.uniform(10.0, 15.0), 1), round(rng.uniform(0.3, 0.5), 2)
    plane = bfe.incline(slope, 0.0, 0.6)
    return bfe.Case(f"box_drawn_tumble_{slope:g}_{spin:g}_{speed:g}", f"drawn, tumbles: spin {spin:g} rad/s, {speed:g} m/s, "
                    + bfe._label(plane, 0.0), True, bfe._on_plane(fam.mesh, base, plane, 0.03, rotation=(np.pi / 2, 0.0, 0.0),
                                                                velocity=(speed, 0.0, 0.0), angular_velocity=(0.0, spin, 0.0)))


NUDGED_TUMBLES = {"_nudged_x": (bfe.NUDGE, 0.0, 0.0), "_nudged_down": (0.0, 0.0, -bfe.NUDGE)}
"""Name suffix and start offset (m) of each nudged companion of a drawn tumble (``--nudged-tumbles``)."""


def drawn_family(family: str, count: int, small: bool) -> bfe.Family:
    """``family``'s mesh and stepping with ``count`` drawn held-out scenes (seeded by :data:`SEED`), at the converged truth
    (``small``: the tiny mesh at the family's own step, where 20 steps see it land)."""
    fam = bfe.FAMILIES[family](small)
    rng = np.random.default_rng(SEED)
    drawn = bfe.Family(family, fam.mesh, fam.steps, tuple(drawn_case(family, fam, rng, k) for k in range(count)))
    return drawn if small else bfe.at_converged_truth(family, drawn)


def scene_row(model: licrom.Model, fam: bfe.Family, case: bfe.Case, work: Path, values: np.ndarray) -> dict:
    full = bfe.full_run(work, case.name, fam.mesh, case.scene, fam.steps, fam.record_every)
    floor = bfe.run_metrics(full, bfe.full_run(work, case.name + bfe.NUDGED, fam.mesh, bfe.nudged(case.scene), fam.steps, fam.record_every))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the estimate's warning is a column of the table
        reduced = licrom.ReducedSim(model, scene=case.scene).run(fam.steps, record_every=fam.record_every)
    m = bfe.run_metrics(full, reduced)
    chaotic = max(floor["nonrigid_error"], floor["com_error"]) > bfe.CHAOTIC_FLOOR
    row = {"name": case.name, "kind": case.kind, "floor_nonrigid": floor["nonrigid_error"], "floor_com": floor["com_error"], "chaotic": chaotic,
           "learned_projection": bfe.body_projection_error(full, values), "nonrigid_error": m["nonrigid_error"], "com_error": m["com_error"],
           "stick_slip_right": m["stick_slip_right"], "estimate": float(reduced.error_estimate[-1]) if len(reduced.error_estimate) else float("nan"),
           "reduced_ms": 1e3 * float(np.median(reduced.step_seconds)), "full_ms": 1e3 * float(np.median(full.step_seconds))}
    row["meets"] = bool(bfe.meets_defaults_targets(row, floor))
    return row


def table(rows: list[dict]) -> str:
    pct = bfe._pct
    out = ["| scene | noise floor (non-rigid / COM) | learned projection | non-rigid error | estimate | final COM / size | stick/slip | "
           "reduced ms/step | full ms/step | meets |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        out.append(f"| {r['kind']} | {pct(r['floor_nonrigid'])} / {pct(r['floor_com'])}{' chaotic' if r.get('chaotic') else ''} | {pct(r['learned_projection'])} | {pct(r['nonrigid_error'])} | "
                   f"{pct(r['estimate'])} | {pct(r['com_error'])} | {'right' if r['stick_slip_right'] else 'wrong'} | {r['reduced_ms']:.3f} | "
                   f"{r['full_ms']:.1f} | {'yes' if r['meets'] else 'no'} |")
    return "\n".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--family", choices=DRAWS, default="cheese", help="the object whose scenes are drawn")
    ap.add_argument("--model", type=Path, default=None, help="the family's model (licrom train defaults; default out/converged/models/FAMILY.lcm)")
    ap.add_argument("--scenes", type=int, default=8, help="scenes drawn")
    ap.add_argument("--work", type=Path, default=Path("out/more_scenes"))
    ap.add_argument("--small", action="store_true", help="tiny cheese, 2 scenes of 20 steps, a 1-epoch model trained here")
    ap.add_argument("--nudged-tumbles", type=int, default=0, help="full runs of the first N drawn tumbles, each start moved 0.1 mm (NUDGED_TUMBLES)")
    args = ap.parse_args()
    bfe.CHEESE_RESOLUTION = 10
    fam = drawn_family(args.family, 2 if args.small else args.scenes, args.small)
    if args.small:
        runs = [bfe.full_run(args.work, c.name + "_train", fam.mesh, c.scene, fam.steps, fam.record_every) for c in fam.cases]
        model_path = args.work / "model.lcm"
        from licrom.learn.training import TrainConfig
        licrom.train(runs, model_path, TrainConfig(epochs=1, progress=False))
        args.model = model_path
    model = licrom.Model.load(args.model or Path(f"out/converged/models/{args.family}.lcm"))
    values = BodyFrameBasis(fam.mesh, model, density=fam.cases[0].scene.material.density).values(fam.mesh.vertices)
    rows = []
    for case in fam.cases:
        rows.append(scene_row(model, fam, case, args.work, values))
        print(table(rows[-1:]).splitlines()[-1], flush=True)
    for case in [c for c in fam.cases if "tumble" in c.name][: args.nudged_tumbles]:
        for suffix, offset in NUDGED_TUMBLES.items():
            bfe.full_run(args.work, case.name + suffix, fam.mesh, bfe.nudged(case.scene, offset), fam.steps, fam.record_every)
    (args.work / f"more_scenes_{args.family}.json").write_text(json.dumps({"model": str(args.model), "rows": rows}, indent=1))
    met = sum(r["meets"] for r in rows)
    print(f"\n{table(rows)}\n\n{met} of {len(rows)} scenes meet every target; non-rigid {bfe._pct(min(r['nonrigid_error'] for r in rows))}-"
          f"{bfe._pct(max(r['nonrigid_error'] for r in rows))}, centre of mass {bfe._pct(min(r['com_error'] for r in rows))}-"
          f"{bfe._pct(max(r['com_error'] for r in rows))} of the size")


if __name__ == "__main__":
    main()
