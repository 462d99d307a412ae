"""What a user gets by default: `licrom train` defaults, then `ReducedSim(model)` on held-out scenes.

    python experiments/defaults_experiments.py --models out/defaults/models [--work out/body_frame] [--docs docs] [--small]

The families and held-out scenes are those of ``experiments/body_frame_experiments.py`` (the cheese at
1638 tets, ``--cheese-resolution``). ``--models`` holds one model per family, ``FAMILY.lcm``, trained by
``licrom train TRAINING_RUNS -o FAMILY.lcm`` with no other option than the device (r chosen from the data,
cubature fitted and stored by the training; the training runs are the family's with `licrom generate`'s impact
frames, as ``--runs-only`` writes them under ``--work``, or ``--train-here`` trains them here). Every held-out run is then simulated with
``ReducedSim(model, scene=scene)`` and nothing else, beside its noise floor (the full run dropped 0.1 mm
higher) and subspace bounds (the run's body-frame projection onto the model's modes, and onto POD of the same
size of the training frames). The cheese is also run with the naive and the full cubature by name, and on the
864-tet cheese (another mesh of the object: the fitted cubature refitted there), against that mesh's own truth.
Each reduced run's online error estimate (``Trajectory.error_estimate``) stands beside its true non-rigid
error, with Spearman's rho over all runs and the runs the ``AccuracyWarning`` threshold flags.

``--converged`` runs every family at a converged truth (section 12): the material's Kelvin-Voigt viscosity
400 Pa s and BDF2 at ``body_frame_experiments.CONVERGED_STEPS`` (1 ms; the ball 0.5 ms), frames every 10 ms; the models are then
trained on such runs, and the section written is 16.

Writes ``--work/defaults.json`` and section 11 (16) of ``docs/results.md`` (``--small``: neither under --docs).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import platform
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import body_frame_experiments as bfe
from licrom import Model, ReducedSim
from licrom._io import atomic_path
from licrom.data.dataset import IMPACT_WINDOW
from licrom.learn.training import TrainConfig
from licrom.reduced.error_estimate import ERROR_THRESHOLD
from licrom.subspace.basis import RUN_BALANCE

SECTION_TITLE = "## 11. At defaults: what `licrom train` and `ReducedSim(model)` give"
CONVERGED_TITLE = "## 16. At defaults, against a converged truth"
CONVERGED = False  # set by --converged


def family(name: str, small: bool) -> bfe.Family:
    """The family ``name`` of ``body_frame_experiments``, at a converged truth with ``--converged``."""
    fam = bfe.FAMILIES[name](small)
    return bfe.at_converged_truth(name, fam) if CONVERGED else fam


def training_runs(work: Path, fam: bfe.Family) -> list:
    """The family's training runs as `licrom generate` writes them: a frame every ``fam.record_every`` steps and every
    step for :data:`licrom.data.dataset.IMPACT_WINDOW` after each impact (section 26; without those frames the
    converged cheese's dynamics check raised r from 120 to 250, sections 49-53)."""
    return [bfe.full_run(work, c.name, fam.mesh, c.scene, fam.steps, fam.record_every, impact_window=IMPACT_WINDOW)
            for c in fam.training]


def reduced_run(model: Model, case: bfe.Case, full, steps: int, record_every: int = 1, **options) -> dict:
    """``ReducedSim(model, scene=case.scene, **options)`` against the full run: metrics, error estimate, setup time."""
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the estimate's AccuracyWarning is reported in the table
        sim = ReducedSim(model, scene=case.scene, **options)
        setup = time.perf_counter() - t0
        reduced = sim.run(steps, record_every=record_every)
    metrics = bfe.run_metrics(full, reduced)
    est = reduced.error_estimate
    return {**metrics, "estimate": float(est[-1]) if len(est) else float("nan"), "estimate_terms": reduced.info["error_estimate_terms"],
            "cubature": sim.cubature.count,
            "cubature_scheme": sim.cubature.scheme, "setup_s": setup, "full_step_ms": float(np.median(full.step_seconds)) * 1e3}


def family_rows(name: str, model: Model, work: Path, small: bool) -> list[dict]:
    fam = family(name, small)
    every = fam.record_every
    train = training_runs(work, fam)
    setting = bfe.Setting(fam, train, work / "models", 1)
    r = model.n_learned
    cases = list(fam.held_out)
    if name == "cheese":  # a softer material than any training run: the first held-out scene at E = 10 kPa
        first = cases[0]
        soft = first.scene.replace(material=dataclasses.replace(first.scene.material, youngs_modulus=1.0e4))
        cases.append(bfe.Case(f"{first.name}_E10k", f"softer (E = 10 kPa): {first.kind}", True, soft))
    rows = []
    for case in cases:
        full = bfe.full_run(work, case.name, fam.mesh, case.scene, fam.steps, every)
        floor = bfe.run_metrics(full, bfe.full_run(work, case.name + bfe.NUDGED, fam.mesh, bfe.nudged(case.scene), fam.steps, every))
        chaotic = max(floor["nonrigid_error"], floor["com_error"]) > bfe.CHAOTIC_FLOOR
        bounds = {"learned": bfe.body_projection_error(full, setting.body_basis(model).values(fam.mesh.vertices)),
                  "pod": bfe.body_projection_error(full, setting.body_basis(setting.body_pod(r, RUN_BALANCE)).values(fam.mesh.vertices))}
        runs = {"default": reduced_run(model, case, full, fam.steps, every)}
        if name == "cheese":
            for label in ("naive", "full"):
                runs[label] = reduced_run(model, case, full, fam.steps, every, cubature=label)
        own = bfe.run_metrics(full, full)
        rows.append({"family": name, "name": case.name, "kind": case.kind, "tets": fam.mesh.n_tets, "r": r, "slides": own["slides"],
                     "noise_floor": floor, "chaotic": chaotic, "bounds": bounds, "runs": runs})
        print(f"{name} {case.name}: r {r}, floor {bfe._pct(floor['nonrigid_error'])}, learned proj {bfe._pct(bounds['learned'])}, "
              + ", ".join(f"{k}: non-rigid {bfe._pct(v['nonrigid_error'])} (est {bfe._pct(v['estimate'])}), COM {bfe._pct(v['com_error'])}, "
                          f"{v['step_ms']:.3f} ms, {v['cubature']} tets" for k, v in runs.items()), flush=True)
    return rows


def transfer_rows(model: Model, work: Path, small: bool) -> list[dict]:
    """The cheese model on the 864-tet cheese against that mesh's own truth (cached by body_frame_experiments.py)."""
    saved = bfe.CHEESE_RESOLUTION
    bfe.CHEESE_RESOLUTION = 8
    try:
        fam = family("cheese", small)
    finally:
        bfe.CHEESE_RESOLUTION = saved
    rows = []
    t0 = time.perf_counter()
    refit = model.cubature_for(fam.mesh)
    refit_s = time.perf_counter() - t0
    for case in fam.held_out:
        full = bfe.full_run(work / "other_mesh", case.name, fam.mesh, case.scene, fam.steps, fam.record_every)
        runs = {"default": reduced_run(model, case, full, fam.steps, fam.record_every, mesh=fam.mesh)}
        runs["default"]["refit_s"] = refit_s
        rows.append({"family": "cheese, another mesh", "name": case.name, "kind": case.kind, "tets": fam.mesh.n_tets, "r": model.n_learned,
                     "runs": runs})
        print(f"other mesh {case.name}: non-rigid {bfe._pct(runs['default']['nonrigid_error'])} (est {bfe._pct(runs['default']['estimate'])}), "
              f"COM {bfe._pct(runs['default']['com_error'])}, {refit.count} tets refitted in {refit_s:.1f} s", flush=True)
    return rows


def speed(model: Model, case: bfe.Case, mesh, rounds: int = 7) -> dict:
    """Full against reduced step time on the same mesh and scene, interleaved rounds in one process (after both land)."""
    from licrom import FullSim
    from licrom.analysis.compare import time_steps

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        full, reduced = FullSim(mesh, case.scene), ReducedSim(model, scene=case.scene)
        time_steps(full, 1, warmup=14)
        time_steps(reduced, 1, warmup=14)
        times = [(time_steps(full, 3)[0], time_steps(reduced, 30)[0]) for _ in range(rounds)]
    f, r = (float(np.median(x)) for x in zip(*times))
    return {"scene": case.kind, "tets": mesh.n_tets, "r": model.n_learned, "cubature": reduced.cubature.count, "full_ms": f, "reduced_ms": r,
            "ratio": f / r, "rounds": rounds, "ratios": [a / b for a, b in times]}


def spearman(x: list[float], y: list[float]) -> float:
    from scipy.stats import spearmanr

    return float(spearmanr(x, y).statistic)


def meets(row: dict, run: dict) -> bool:
    return bfe.meets_defaults_targets(run, row["noise_floor"] if row.get("chaotic") else None)


def _ratio(x: float) -> str:
    """A speed-up in words: one decimal below 10 (a reduced step slower than the full one reads below 1x)."""
    return f"{x:.1f}x" if x < 10 else f"{x:.0f}x"


def report(rows: list[dict], models: dict[str, Model]) -> str:
    where = ", ".join(f"{name} on {'a GPU' if m.metadata.get('accelerator') == 'gpu' else 'the CPU'}" for name, m in models.items())
    out = [f"Models, one per family, trained by `licrom train RUNS -o FAMILY.lcm` with every option at its default ({where}; "
           "the training's own device, `licrom.train` picks CUDA where there is one):",
           "", "| family | tets | r chosen (projection; dynamics check) | leave-runs-out error at the projection's r (RMS / worst run) | capped | "
           "fitted cubature tets | force residual | fit s | learned / POD(r) on held-out frames | training s |", "|---|---|---|---|---|---|---|---|---|---|"]
    for name, m in models.items():
        rank, cub, sub = m.metadata.get("rank", {}), m.metadata.get("cubature", {}), m.metadata.get("subspace", {})
        projection = rank.get("dynamics", {}).get("projection_rank", rank.get("rank"))
        i = rank["candidates"].index(projection) if rank.get("candidates") else None
        dynamics = rank.get("dynamics", {}).get("method")
        checked = ("not checked: trained before the check" if dynamics is None else
                   f"raised from {projection}" if rank.get("dynamics", {}).get("raised") else "kept" if dynamics == "replayed" else dynamics)
        out.append(f"| {name} | {m.mesh.n_tets} | {m.n_learned} ({checked}) | "
                   + (f"{bfe._pct(rank['errors'][i])} / {bfe._pct(rank['worst_errors'][i])}" if i is not None else "-")
                   + f" | {'yes' if rank.get('capped') else 'no'} | {cub.get('count', '-')} | {cub.get('fit_error', float('nan')):.1e} | "
                   f"{cub.get('fit_seconds', float('nan')):.1f} | {sub.get('ratio', float('nan')):.3f}x | {m.metadata.get('fit_seconds', float('nan')):.0f} |")
    out += ["", "Held-out runs with `ReducedSim(model, scene=scene)` (default: the model's fitted cubature), and for the cheese the "
            "same with `cubature=\"naive\"` (1000 random tets) and `\"full\"` (every tet). Targets: non-rigid error < 10 %, final "
            "centre of mass < 2 % of the size, stick/slip right; chaotic runs (noise floor above 2 %) within 3x their floor. "
            "Estimate: the run's own online estimate of its non-rigid error (`Trajectory.error_estimate`, last frame); "
            f"flagged: above the `AccuracyWarning` threshold {bfe._pct(ERROR_THRESHOLD)}. ms/step: median wall time of a reduced step "
            "here (2 shared cores, other jobs running); full ms/step: the same of the full run (warp on the CPU, earlier, same machine).", "",
            "| family | held-out run | tets | r | noise floor | learned / POD(r) projection | cubature | non-rigid error | estimate | flagged | "
            "final COM / size | stick/slip | ms/step (its) | full ms/step | speed-up | meets |", "|" + "---|" * 16]
    for row in rows:
        floor = row.get("noise_floor")
        for label, run in row["runs"].items():
            b = row.get("bounds", {})
            out.append(
                f"| {row['family']} | {row['kind']} | {row['tets']} | {row['r']} | "
                + (f"{bfe._pct(floor['nonrigid_error'])} / {bfe._pct(floor['com_error'])}{' chaotic' if row['chaotic'] else ''}" if floor else "-")
                + f" | {bfe._pct(b.get('learned'))} / {bfe._pct(b.get('pod'))} | {label}: {run['cubature']} ({run['cubature_scheme']}) | "
                f"{bfe._pct(run['nonrigid_error'])} | {bfe._pct(run['estimate'])} | {'yes' if run['estimate'] > ERROR_THRESHOLD else 'no'} | "
                f"{bfe._pct(run['com_error'])} | {'right' if run['stick_slip_right'] else 'WRONG'} | {run['step_ms']:.3f} ({run['iterations']:.1f}) | "
                f"{run['full_step_ms']:.1f} | {_ratio(run['full_step_ms'] / run['step_ms'])} | "
                + ("-" if floor is None else "yes" if meets(row, run) else "no") + " |")
    runs = [run for row in rows for run in row["runs"].values()]
    truth, est = [r["nonrigid_error"] for r in runs], [r["estimate"] for r in runs]
    flagged = [e > ERROR_THRESHOLD for e in est]
    bad = [t > 0.15 for t in truth]
    out += ["", f"Error estimate over these {len(runs)} runs: Spearman's rho against the true non-rigid error {spearman(truth, est):.2f}; "
            f"runs above 15 % true error: {sum(bad)}, flagged {sum(f and b for f, b in zip(flagged, bad))} of them; "
            f"false alarms: {sum(f and not b for f, b in zip(flagged, bad))} of {sum(flagged)} flags."]
    residual = [r["estimate_terms"]["residual"] for r in runs if "estimate_terms" in r]
    if len(residual) == len(runs):  # the estimate without its cubature term (results section 48)
        flagged = [e > ERROR_THRESHOLD for e in residual]
        out += [f"Without the estimate's cubature term: rho {spearman(truth, residual):.2f}; flagged {sum(f and b for f, b in zip(flagged, bad))} "
                f"of the {sum(bad)}; false alarms: {sum(f and not b for f, b in zip(flagged, bad))} of {sum(flagged)} flags."]
    return "\n".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--models", type=Path, default=Path("out/defaults/models"))
    ap.add_argument("--work", type=Path, default=Path("out/body_frame_c10"), help="cache of the full runs (cheese at --cheese-resolution)")
    ap.add_argument("--other-mesh-work", type=Path, default=Path("out/body_frame"), help="cache of the 864-tet cheese's runs")
    ap.add_argument("--docs", type=Path, default=Path("docs"))
    ap.add_argument("--families", nargs="+", default=list(bfe.FAMILIES), choices=list(bfe.FAMILIES))
    ap.add_argument("--cheese-resolution", type=int, default=10)
    ap.add_argument("--train-here", action="store_true", help="train missing models here with licrom.train defaults (slow on a CPU)")
    ap.add_argument("--small", action="store_true", help="tiny meshes, few steps, 1 epoch: a smoke test that writes nothing under --docs")
    ap.add_argument("--converged", action="store_true", help="every family at a converged truth (viscosity, BDF2, CONVERGED_STEPS)")
    ap.add_argument("--runs-only", action="store_true", help="only the full runs (training and held-out), cached under --work")
    args = ap.parse_args()
    global CONVERGED
    CONVERGED = args.converged
    title = CONVERGED_TITLE if args.converged else SECTION_TITLE
    bfe.CHEESE_RESOLUTION = args.cheese_resolution
    work = args.work / "small" if args.small else args.work
    t_start = time.perf_counter()
    if args.runs_only:
        for name in args.families:
            fam = family(name, args.small)
            training_runs(work, fam)
            for c in fam.held_out:
                bfe.full_run(work, c.name, fam.mesh, c.scene, fam.steps, fam.record_every)
                bfe.full_run(work, c.name + bfe.NUDGED, fam.mesh, bfe.nudged(c.scene), fam.steps, fam.record_every)
        return
    rows, models = [], {}
    for name in args.families:
        path = args.models / f"{name}.lcm"
        if not path.exists():
            if not (args.train_here or args.small):
                raise SystemExit(f"no model {path}: train it with `licrom train` (see the module docstring) or pass --train-here")
            fam = family(name, args.small)
            runs = training_runs(work, fam)
            import licrom

            licrom.train(runs, path, TrainConfig(epochs=1, progress=False) if args.small else TrainConfig())
        models[name] = Model.load(path)
        rows += family_rows(name, models[name], work, args.small)
    timing = None
    if "cheese" in models and not args.small:
        rows += transfer_rows(models["cheese"], args.other_mesh_work, args.small)
        fam = family("cheese", False)
        timing = speed(models["cheese"], fam.held_out[0], fam.mesh)
    wall = time.perf_counter() - t_start
    text = report(rows, models)
    if timing is not None:
        text += (f"\n\nSpeed, in one process on this machine (2 shared cores), {timing['rounds']} interleaved rounds of 3 full and 30 reduced "
                 f"steps after both landed, {timing['scene']}, {timing['tets']} tets: full (warp, CPU) {timing['full_ms']:.1f} ms, "
                 f"reduced (r = {timing['r']}, {timing['cubature']} fitted cubature tets, error estimate included) {timing['reduced_ms']:.3f} ms "
                 f"a step (medians): {timing['ratio']:.0f}x (rounds {min(timing['ratios']):.0f}-{max(timing['ratios']):.0f}x).")
    print(text)
    with atomic_path(work / "defaults.json") as tmp:
        tmp.write_text(json.dumps({"rows": rows, "speed": timing, "wall_s": wall}, indent=1, default=float))
    if args.small:
        return
    bfe.write_section(args.docs, f"{title}\n\nMeasured by `python experiments/defaults_experiments.py{' --converged' if args.converged else ''}` on "
                      f"{platform.processor() or platform.machine()}, {time.strftime('%Y-%m-%d')}; wall time {wall:.0f} s (full runs cached).\n\n"
                      + text + "\n", title)


if __name__ == "__main__":
    main()
