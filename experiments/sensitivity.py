"""How far a scene's own full run moves under small changes of its inputs, beside the reduced model's miss.

    python experiments/sensitivity.py --work out/body_frame_c10i [--model M.lcm] [--cases NAME ...]
        [--tumbles SLOPE:MU:AZIMUTH ...] [--out F.json]
    python experiments/sensitivity.py --work W --table F.json [F.json ...]      # section 68's table from saved runs

The noise floor (a drop 0.1 mm higher) says whether a run repeats; it does not say whether the run is stable against
the errors a reduced model makes, which change the body's path by more than 0.1 mm. Each case of the converged cheese
(``body_frame_experiments``, 1638 tets, BDF2 at 1 ms) is run in full space again with one input moved by a small
amount (:func:`licrom.analysis.sensitivity.sensitivity`: the drop 1 mm higher, gravity turned by 0.5 deg about two
horizontal axes, the friction coefficient 0.01 higher, Young's modulus 2 % higher, and the time step halved, the
truth's own convergence), beside the noise floor and the downhill azimuth turned by 1 deg. Each is compared with the
case's run as a reduced run is (non-rigid error, final centre of mass over the size, stick/slip). With ``--model``
the model's ``ReducedSim(model, scene=scene)`` (its fitted cubature) and the same with every tet stand beside them.

A run whose outcome moves by tens of percent when its slope turns by a degree is chaotic at the scale of a model's
error: its reduced run is held to that spread, not to the 0.1 mm floor.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import body_frame_experiments as bfe
import defaults_experiments as de
from licrom import Model
from licrom._io import atomic_path
from licrom.analysis.sensitivity import sensitivity
from licrom.data.dataset import IMPACT_WINDOW
from licrom.reduced.error_estimate import ERROR_THRESHOLD
from licrom.subspace.basis import RUN_BALANCE

MODEL = "model (fitted cubature)"

DEFAULT_CASES = ("cheese_train_30_0.8_az300", "cheese_train_30_0.8_az50", "cheese_test_22_0.3_az0",
                 "cheese_test_25_0.3_az120", "cheese_test_35_0.45_az50")
"""The training's validation tip-over, the training run that tips, and three held-out runs of section 67."""


def case_inputs(name: str) -> tuple[float, float, float]:
    """``(slope deg, mu, azimuth deg)`` of a cheese case from its name (``cheese_{split}_{slope}_{mu}_az{azimuth}``)."""
    _, _, slope, mu, az = name.split("_")[:5]
    return float(slope), float(mu), float(az.removeprefix("az"))


def tumble_case(fam: bfe.Family, slope: float, mu: float, azimuth: float) -> bfe.Case:
    """A held-out scene of the cheese family on another plane, dropped and tilted as the family's are."""
    plane = bfe.incline(slope, azimuth, mu)
    scene = bfe._on_plane(fam.mesh, fam.cases[0].scene, plane, bfe.CHEESE_DROP, bfe.CHEESE_TILT)
    return bfe.Case(f"cheese_tumble_{slope:g}_{mu:g}_az{azimuth:g}", f"held out: {bfe._label(plane, azimuth)}", True, scene)


def cheese_rows(fam: bfe.Family, case: bfe.Case, work: Path, full) -> dict:
    """The noise floor (0.1 mm higher) and the downhill azimuth turned by 1 deg (the cheese's own input), cached."""
    slope, mu, az = case_inputs(case.name)
    turned = bfe._on_plane(fam.mesh, case.scene, bfe.incline(slope, az + 1.0, mu), bfe.CHEESE_DROP, bfe.CHEESE_TILT)
    rows = {}
    for label, tag, scene in (("0.1 mm higher (noise floor)", "0.1_mm_higher", bfe.nudged(case.scene)),
                              ("azimuth +1 deg", "azimuth_p1_deg", turned)):
        moved = bfe.full_run(work / "sensitivity", f"{case.name}_{tag}", fam.mesh, scene, fam.steps, fam.record_every)
        rows[label] = bfe.run_metrics(full, moved)
    return rows


def reduced_rows(model: Model, case: bfe.Case, full, steps: int, every: int) -> dict:
    """The model's run with its fitted cubature and with every tet (``defaults_experiments.reduced_run``)."""
    return {MODEL: de.reduced_run(model, case, full, steps, every),
            "model, every tet": de.reduced_run(model, case, full, steps, every, cubature="full")}


def projection_bounds(model: Model, work: Path, names: list[str], tumbles: dict[str, bfe.Case]) -> dict[str, tuple[float, float]]:
    """Name -> (learned projection, POD(r) of the training frames) of each run's full run: its non-rigid error with
    each frame projected onto the model's body-frame modes, and onto as many POD modes (as ``defaults_experiments``)."""
    fam = de.family("cheese", False)
    cases = {c.name: c for c in fam.cases} | tumbles
    setting = bfe.Setting(fam, de.training_runs(work, fam), work / "models", 1)
    vertices = fam.mesh.vertices
    learned = setting.body_basis(model).values(vertices)
    pod = setting.body_basis(setting.body_pod(model.n_learned, RUN_BALANCE)).values(vertices)
    out = {}
    for name in names:
        case = cases[name]
        full = bfe.full_run(work, name, fam.mesh, case.scene, fam.steps, fam.record_every,
                            impact_window=0.0 if case.held_out else IMPACT_WINDOW)
        out[name] = (bfe.body_projection_error(full, learned), bfe.body_projection_error(full, pod))
    return out


def table(results: dict, spread: dict, bounds: dict | None = None) -> str:
    """Markdown: each run's floors and spread (non-rigid / centre of mass), the truth at h / 2, the subspace's bounds
    (:func:`projection_bounds`, where given), the model's run."""
    bounds = bounds or {}
    out = ["| run | noise floor (0.1 mm) | 1 mm higher | worst input moved | spread, chaotic? | truth at h / 2 | "
           "learned / POD(r) projection | model | model / spread (non-rigid) | estimate |", "|---|---|---|---|---|---|---|---|---|---|"]

    def pair(row):
        return f"{100 * row['nonrigid_error']:.1f} / {100 * row['com_error']:.1f} %"

    for name, rows in results.items():
        moved = {k: v for k, v in rows.items() if k not in ("0.1 mm higher (noise floor)", "h / 2") and not k.startswith("model")}
        worst = max(moved, key=lambda k: moved[k]["nonrigid_error"])
        sp = spread[name]
        model = rows.get(MODEL)
        out.append(f"| {name} | {pair(rows['0.1 mm higher (noise floor)'])} | {pair(rows['1 mm higher'])} | {worst}: {pair(moved[worst])} | "
                   f"{100 * sp['nonrigid_spread']:.1f} / {100 * sp['com_spread']:.1f} %, {'yes' if sp['chaotic'] else 'no'} | "
                   f"{pair(rows['h / 2'])} | "
                   + (f"{100 * bounds[name][0]:.1f} / {100 * bounds[name][1]:.1f} % | " if name in bounds else "- | ")
                   + (f"{pair(model)} | {model['nonrigid_error'] / sp['nonrigid_spread']:.2f}x | "
                                                 f"{100 * model['estimate']:.1f} % |" if model else "- | - | - |"))
    return "\n".join(out)


def held_out_names(model: Model, fam: bfe.Family) -> set[str]:
    """The family's training runs that the model's training held out (``trajectory_NNN``: the NNN-th training run)."""
    training = [c.name for c in fam.cases if not c.held_out]
    return {training[int(n.rsplit("_", 1)[1])] for n in model.metadata["data"]["validation"]}


def estimate_pool(results: dict, study: Path, held_out: set[str]) -> str:
    """The online estimate judged over the model's runs here on scenes it never trained on (``held_out`` and the
    ``--tumbles``) and the default-cubature runs of a defaults study (``defaults_experiments`` JSON): Spearman's rho,
    the runs above 15 % flagged, false alarms among the flags."""
    pairs = [(row[MODEL]["nonrigid_error"], row[MODEL]["estimate"]) for name, row in results.items()
             if MODEL in row and (name in held_out or name.startswith("cheese_tumble_"))]
    rows = json.loads(study.read_text())["rows"]
    pairs += [(r["runs"]["default"]["nonrigid_error"], r["runs"]["default"]["estimate"]) for r in rows if "default" in r["runs"]]
    truth, est = [t for t, _ in pairs], [e for _, e in pairs]
    flagged, bad = [e > ERROR_THRESHOLD for e in est], [t > 0.15 for t in truth]
    return (f"The estimate over {len(pairs)} default-cubature runs: Spearman's rho {de.spearman(truth, est):.2f}; runs above 15 %: "
            f"{sum(bad)}, flagged {sum(f and b for f, b in zip(flagged, bad))}; false alarms {sum(f and not b for f, b in zip(flagged, bad))} "
            f"of {sum(flagged)} flags (threshold {100 * ERROR_THRESHOLD:g} %).")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", type=Path, required=True, help="the converged cheese's full runs (defaults_experiments --runs-only)")
    ap.add_argument("--model", type=Path, default=None)
    ap.add_argument("--cases", nargs="*", default=list(DEFAULT_CASES))
    ap.add_argument("--tumbles", nargs="*", default=[], metavar="SLOPE:MU:AZIMUTH",
                    help="also these held-out scenes, placed as the family's (cheese_tumble_SLOPE_MU_azAZIMUTH)")
    ap.add_argument("--out", type=Path, default=None, help="JSON of every row (default WORK/sensitivity.json)")
    ap.add_argument("--table", type=Path, nargs="+", default=None, metavar="JSON", help="print the markdown table of these outputs, then stop")
    ap.add_argument("--estimate-pool", type=Path, default=None, metavar="DEFAULTS_JSON",
                    help="with --table and --model: also judge the estimate over the runs the model never trained on and a defaults "
                         "study's default-cubature runs")
    args = ap.parse_args()
    if args.estimate_pool and not (args.table and args.model):
        ap.error("--estimate-pool needs --table and --model")
    if args.table:
        saved = [json.loads(p.read_text()) for p in args.table]
        results = {k: v for s in saved for k, v in s["rows"].items()}
        de.CONVERGED, bfe.CHEESE_RESOLUTION = True, 10
        model = Model.load(args.model) if args.model else None
        bounds = {}
        if model is not None:
            fam = de.family("cheese", False)
            tumbles = {n: tumble_case(fam, *case_inputs(n)) for n in results if n.startswith("cheese_tumble_")}
            bounds = projection_bounds(model, args.work, list(results), tumbles)
        print(table(results, {k: v for s in saved for k, v in s["spread"].items()}, bounds))
        if args.estimate_pool:
            held_out = held_out_names(model, de.family("cheese", False))
            print("\n" + estimate_pool(results, args.estimate_pool, held_out))
        return
    de.CONVERGED, bfe.CHEESE_RESOLUTION = True, 10
    fam = de.family("cheese", False)
    cases = {c.name: c for c in fam.cases}
    for spec in args.tumbles:
        slope, mu, az = (float(v) for v in spec.split(":"))
        case = tumble_case(fam, slope, mu, az)
        cases[case.name] = case
        args.cases.append(case.name)
    model = Model.load(args.model) if args.model else None
    results, spread = {}, {}
    for name in args.cases:
        case = cases[name]
        # the training runs are cached with impact frames, the held-out ones without
        full = bfe.full_run(args.work, name, fam.mesh, case.scene, fam.steps, fam.record_every,
                            impact_window=0.0 if case.held_out else IMPACT_WINDOW)
        rows = cheese_rows(fam, case, args.work, full)
        moved = sensitivity(fam.mesh, case.scene, fam.steps, fam.record_every, reference=full)
        rows.update({label: {**row, "stick_slip_right": row["stick_slip_agree"]} for label, row in moved.rows.items()})
        spread[name] = {"nonrigid_spread": moved.nonrigid_spread, "com_spread": moved.com_spread, "chaotic": moved.chaotic}
        if model is not None:
            rows.update(reduced_rows(model, case, full, fam.steps, fam.record_every))
        results[name] = rows
        print(f"\n{name} ({case.kind}): spread {100 * moved.nonrigid_spread:.1f} % / {100 * moved.com_spread:.1f} %"
              f"{', chaotic' if moved.chaotic else ''}")
        for label, m in rows.items():
            est = f"  estimate {100 * m['estimate']:.1f} %" if "estimate" in m else ""
            print(f"  {label:28s} non-rigid {100 * m['nonrigid_error']:6.1f} %  COM {100 * m['com_error']:5.1f} %  "
                  f"stick/slip {'right' if m['stick_slip_right'] else 'WRONG'}{est}", flush=True)
    out = args.out or args.work / "sensitivity.json"
    with atomic_path(out) as tmp:
        tmp.write_text(json.dumps({"rows": results, "spread": spread}, indent=1))
    print("\n" + table(results, spread))


if __name__ == "__main__":
    main()
