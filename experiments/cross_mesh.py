"""Discretisation independence, fairly (issue 24, part 4): one model on other meshes, beside the truth's own gap.

    python experiments/cross_mesh.py [--model out/defaults/final/cheese.lcm] [--resolutions 8 12 16] [--work out/cross_mesh]
                                  [--cache 10:out/body_frame_c10 --cache 8:out/body_frame] [--docs docs] [--small]
    python experiments/cross_mesh.py --family sphere --model ball.lcm --training-resolution 32 --resolutions 28 36 \
                                  --drawn 1 --no-floors --time-step 0.0005 --integrator bdf2 --viscosity 400

A family of ``experiments/body_frame_experiments.py`` (``--family``: the soft cheese, or the soft ball): a model
trained on one mesh of it (``--model``, by default the ``licrom train`` defaults model of section 11, trained on the
1638-tet cheese, resolution ``--training-resolution`` 10) and the family's held-out scenes (with ``--drawn N`` the
first N drawn scenes of ``more_scenes.py`` too), built with the same placement code on other meshes of the same
object (``meshes.cheese(resolution=R)`` or ``meshes.sphere(...)`` for each ``--resolutions`` R). For each scene and
other mesh M:

* **(a) the model on M**: ``ReducedSim(model, scene=scene, mesh=M)`` (its fitted cubature refitted on M to the
  stored training poses, :meth:`licrom.Model.cubature_for`) against M's own full run;
* **(b) the truth's gap**: the training mesh's full run against M's full run;
* **(c) their ratio** (a) / (b), against the target of at most 1.5x;
* **(e)** the model on M against the training mesh's full run (does it follow the truth it was trained on?);

and, for reference, **(d)** the model on its own training mesh against that mesh's full run. All are measured at
M's vertices with M's lumped masses: the training mesh's run is interpolated there (barycentric coordinates in
the containing tet of its own mesh, :func:`truth_convergence.sampled_positions`; vertices of M just outside it are
clamped to the nearest tet). Non-rigid error: each frame's best rigid fit removed, mass-weighted,
``sqrt(sum_t |d_t|^2 / sum_t |u_t|^2)`` from M's first contact with u the reference's body-frame displacement
(:func:`truth_convergence.sampled_nonrigid`; at M's own vertices it is :func:`licrom.analysis.compare.nonrigid_error`);
centre of mass: the final frame's mass-weighted centre at M's vertices, distance over M's size. Noise floor: M's
full run against itself dropped 0.1 mm higher (``body_frame_experiments.nudged``; ``--no-floors`` skips those runs,
which halves the full runs where the floor is known).

Full runs are cached as ``.npz`` (``body_frame_experiments.full_run``): under ``--cache R:DIR`` where given (the
training mesh's and the 864-tet truths of the earlier sections), else under ``--work/rR``; missing ones run here
(warp, the default device: the CPU on a machine without a GPU); ``--truths-only`` runs those of ``--resolutions``
alone, so that one process a mesh can share a GPU; ``--no-training-truth`` makes none of the training mesh (one too
large for the machine at hand): then only (a) on each other mesh, and the gaps between those meshes' truths. Writes ``--work/cross_mesh.json`` and section 14 of
``docs/results.md`` (a ``### Reading`` part written by hand is kept). ``--small``: tiny meshes (resolutions 5 and 4,
6), 20 steps, one scene, a 1-epoch model trained here; writes nothing under ``--docs``, runs in under a minute.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import platform
import shlex
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import body_frame_experiments as bfe
import more_scenes
from licrom import Model, ReducedSim, Trajectory
from licrom._io import atomic_path
from licrom.analysis.compare import first_contact_frame
from licrom.full.device import resolve_device
from licrom.learn.training import TrainConfig
from licrom.scene.scene import SolverParams
from licrom.subspace.body_basis import BodyFrameBasis
from truth_convergence import sampled_nonrigid, sampled_positions

SECTION_TITLE = "## 14. Discretisation independence, fairly"
TARGET_RATIO = 1.5  # the model's cross-mesh error at most this times the truth's own gap
SMALL_STEPS = 20
Samples = tuple[np.ndarray, np.ndarray]  # rest (p, 3) and deformed (frames, p, 3) positions of material points


RESOLUTION_OF = {"cheese": "CHEESE_RESOLUTION", "sphere": "SPHERE_RESOLUTION"}
"""The ``body_frame_experiments`` setting of each family's mesh resolution."""


def family_on(name: str, resolution: int) -> bfe.Family:
    """The family ``name`` of ``body_frame_experiments`` on its mesh of ``resolution``."""
    setting = RESOLUTION_OF[name]
    saved = getattr(bfe, setting)
    setattr(bfe, setting, resolution)
    try:
        return bfe.FAMILIES[name](False)
    finally:
        setattr(bfe, setting, saved)


def held_cases(name: str, fam: bfe.Family, drawn: int) -> list[bfe.Case]:
    """The family's held-out scenes and its first ``drawn`` drawn ones (``more_scenes.py``'s seeded draws, placed on
    ``fam``'s mesh: the same scenes on every mesh)."""
    rng = np.random.default_rng(more_scenes.SEED)
    return [*fam.held_out, *(more_scenes.drawn_case(name, fam, rng, k) for k in range(drawn))]


def truths(cache: Path, fam: bfe.Family, cases: list[bfe.Case], steps: int,
           floors: bool = True) -> dict[str, tuple[Trajectory, Trajectory | None]]:
    """Each case's full run and its noise-floor run (dropped 0.1 mm higher; None without ``floors``) on the family's
    mesh, cached under ``cache``."""
    every = fam.record_every
    return {c.name: (bfe.full_run(cache, c.name, fam.mesh, c.scene, steps, every),
                     bfe.full_run(cache, c.name + bfe.NUDGED, fam.mesh, bfe.nudged(c.scene), steps, every) if floors else None)
            for c in cases}


def floor_of(full: Trajectory, nudged: Trajectory | None) -> dict:
    """The noise floor's metrics (None where its run was not made)."""
    return bfe.run_metrics(full, nudged) if nudged is not None else {"nonrigid_error": None, "com_error": None}


def difference(ref: Samples, other: Samples, weights: np.ndarray, start: int, size: float) -> dict:
    """Non-rigid difference (from frame ``start``) and final centre-of-mass distance / ``size`` of two sampled runs."""
    com = [weights @ x[-1] / weights.sum() for _, x in (ref, other)]
    return {"nonrigid": sampled_nonrigid(ref, other, weights, start), "com": float(np.linalg.norm(com[1] - com[0]) / size)}


def reduced_run(model: Model, case: bfe.Case, steps: int, mesh=None, record_every: int = 1) -> tuple[Trajectory, dict]:
    """``ReducedSim(model, scene=case.scene, mesh=mesh)`` run for ``steps`` (a frame every ``record_every``), with its
    setup time and cubature size."""
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the error estimate's AccuracyWarning: its value is recorded
        sim = ReducedSim(model, scene=case.scene, mesh=mesh)
        setup = time.perf_counter() - t0
        traj = sim.run(steps, record_every=record_every)
    est = traj.error_estimate
    return traj, {"setup_s": setup, "cubature": sim.cubature.count, "estimate": float(est[-1]) if len(est) else float("nan"),
                  "reduced_step_ms": 1e3 * float(np.median(traj.step_seconds))}


def slides(traj: Trajectory) -> bool:
    """Whether the run slides (``licrom.compare``'s slip distance over the second half of the run)."""
    return bfe.run_metrics(traj, traj)["slides"]


def own_mesh_rows(model: Model, train: dict[str, tuple[Trajectory, Trajectory]], cases: list[bfe.Case], steps: int,
                  record_every: int = 1) -> list[dict]:
    """(d): the model on its training mesh against that mesh's full runs (``train``: full and noise-floor runs by case)."""
    rows = []
    for case in cases:
        full, nudged = train[case.name]
        reduced, info = reduced_run(model, case, steps, record_every=record_every)
        rows.append({"name": case.name, "kind": case.kind, "tets": full.mesh.n_tets, "floor": floor_of(full, nudged),
                     "model": bfe.run_metrics(full, reduced), **info})
        print(f"training mesh {case.name}: non-rigid {bfe._pct(rows[-1]['model']['nonrigid_error'])}, "
              f"COM {bfe._pct(rows[-1]['model']['com_error'])}", flush=True)
    return rows


def other_mesh_rows(model: Model, train: dict[str, tuple[Trajectory, Trajectory]] | None, fam: bfe.Family, cases: list[bfe.Case],
                    steps: int, own_truths: dict[str, tuple[Trajectory, Trajectory]]) -> list[dict]:
    """(a), (b), (c), (e) for each case on the family's mesh (another mesh of the training object), against ``own_truths``;
    (a) alone where the training mesh's full runs are not given (``train`` None)."""
    mesh = fam.mesh
    t0 = time.perf_counter()
    refit = model.cubature_for(mesh)
    refit_s = time.perf_counter() - t0
    density = cases[0].scene.material.density
    weights = mesh.vertex_masses(density)
    inside = mesh_inside(model.mesh, mesh.vertices)
    modes = BodyFrameBasis(mesh, model, density=density).values(mesh.vertices)
    rows = []
    for case in cases:
        full, nudged = own_truths[case.name]
        reduced, info = reduced_run(model, case, steps, mesh=mesh, record_every=fam.record_every)
        start, size = first_contact_frame(full) or 0, mesh.size
        own, red = sampled_positions(full, mesh.vertices), sampled_positions(reduced, mesh.vertices)
        trained = None if train is None else sampled_positions(train[case.name][0], mesh.vertices)
        model_m = difference(own, red, weights, start, size)
        truth = None if trained is None else difference(own, trained, weights, start, size)
        metrics = bfe.run_metrics(full, reduced)
        rows.append({"name": case.name, "kind": case.kind, "tets": mesh.n_tets, "vertices": mesh.n_vertices,
                     "floor": floor_of(full, nudged), "model": model_m, "truth_gap": truth,
                     "ratio": None if truth is None else {k: model_m[k] / truth[k] for k in model_m},
                     "model_vs_training_truth": None if trained is None else difference(trained, red, weights, start, size),
                     "learned_projection": bfe.body_projection_error(full, modes), "model_metrics": metrics,
                     "slides": {"own": slides(full), "training": None if train is None else slides(train[case.name][0])},
                     "refit_cubature": refit.count, "refit_s": refit_s,
                     "refit_residual": refit.fit_error,
                     "inside_training_mesh": inside, "full_step_ms": 1e3 * float(np.median(full.step_seconds)), **info})
        print(f"{mesh.n_tets} tets {case.name}: model non-rigid {bfe._pct(model_m['nonrigid'])} (compare: "
              f"{bfe._pct(metrics['nonrigid_error'])}), truth gap {bfe._pct(truth and truth['nonrigid'])}; COM {bfe._pct(model_m['com'])} "
              f"against {bfe._pct(truth and truth['com'])}; {refit.count} tets refitted in {refit_s:.1f} s; step: reduced {info['reduced_step_ms']:.2f} ms, "
              f"full {rows[-1]['full_step_ms']:.1f} ms", flush=True)
    return rows


def truth_gaps(runs: dict[int, dict[str, Trajectory]]) -> list[dict]:
    """The full runs of every pair of meshes against each other (``runs``: by tet count, then case), at the finer mesh's vertices."""
    rows = []
    tets = sorted(runs)
    for i, coarse in enumerate(tets):
        for fine in tets[i + 1:]:
            for name, ref in runs[fine].items():
                mesh = ref.mesh
                weights = mesh.vertex_masses(ref.scene.material.density)
                gap = difference(sampled_positions(ref, mesh.vertices), sampled_positions(runs[coarse][name], mesh.vertices),
                                 weights, first_contact_frame(ref) or 0, mesh.size)
                rows.append({"coarse": coarse, "fine": fine, "name": name, **gap})
    return rows


def mesh_inside(mesh, points: np.ndarray, tolerance: float = 1e-9) -> float:
    """Fraction of ``points`` inside ``mesh`` (barycentric coordinates of the containing tet, before clamping, >= -tolerance)."""
    tets, _ = mesh.locate(points)
    x0 = mesh.vertices[mesh.tets[tets, 0]]
    b = np.einsum("pij,pj->pi", mesh.shape_matrix_inverses[tets], points - x0)
    return float(np.mean(np.minimum(b.min(axis=1), 1.0 - b.sum(axis=1)) >= -tolerance))


def _ratio(x: float | None) -> str:
    return f"{x:.2f}x" if x is not None and np.isfinite(x) else "-"


def report(result: dict) -> str:
    """The section's tables and summary lines from the measured ``result``."""
    model, train = result["model"], result["training_mesh"]
    damped = bool(result.get("viscosity"))
    physics = (f"{result.get('integrator', 'backward_euler')}, material viscosity {result['viscosity']:g} Pa s: section 12's converged truth"
               if damped else "backward Euler")
    device = result.get("full_device", "cpu")
    where = (f"Full runs: warp on the {'GPU' if device.startswith('cuda') else 'CPU'} of the machine named above"
             + ("." if damped else "; those of the training mesh and of the 864-tet mesh are the cached runs of sections 10-11."))
    out = [f"Model: `{model['path']}` ({'`licrom train` defaults' if damped else 'section 11' + chr(39) + 's `licrom train` defaults model'}: "
           f"r = {model['r']}, trained on the {model['tets']}-tet {result.get('family', 'cheese')}, {model['cubature']} fitted cubature tets). "
           f"Held-out scenes of section 10{' and drawn ones of section 25' if result.get('drawn') else ''}, {result['steps']} steps of "
           f"h = {1e3 * result['dt']:g} ms ({physics}), built with the same placement code on each mesh. {where}",
           "", "Measured at the other mesh M's vertices, weighted by M's lumped masses: the training mesh's full run is interpolated "
           "there (barycentric, containing tet of its own mesh). Non-rigid: each frame's best rigid fit removed, from M's first "
           "contact; COM: final centre of mass, distance over M's size. (a) the model on M (`ReducedSim(model, scene=scene, "
           "mesh=M)`, the fitted cubature refitted on M) against M's full run; (b) the truth's gap: the training mesh's full run "
           f"against M's; ratio (a) / (b), target at most {TARGET_RATIO:g}x in both; (e) the model on M against the training "
           "mesh's full run. Noise floor: M's full run against itself dropped 0.1 mm higher (non-rigid / COM). Learned projection: "
           "M's full run with its body-frame displacements projected onto the model's modes on M (each frame keeping its rigid "
           "fit), the subspace's own floor there.", "",
           "| mesh M | held-out run | noise floor of M | learned projection on M | non-rigid (a) model | (b) truth gap | ratio | "
           "COM (a) model | (b) truth gap | ratio | stick/slip (model; truths agree) | (e) model vs training truth: non-rigid / COM | "
           f"meets {TARGET_RATIO:g}x |", "|" + "---|" * 13]
    none = {"nonrigid": None, "com": None}
    for row in result["other_meshes"]:
        a, b, ratio, e, floor = row["model"], row["truth_gap"] or none, row["ratio"] or none, row["model_vs_training_truth"] or none, row["floor"]
        agree = "-" if row["slides"]["training"] is None else ("yes" if row["slides"]["own"] == row["slides"]["training"] else "no")
        meets = "-" if row["ratio"] is None else ("yes" if max(ratio.values()) <= TARGET_RATIO else "no")
        out.append(f"| {row['tets']} tets | {row['kind']} | {bfe._pct(floor['nonrigid_error'])} / {bfe._pct(floor['com_error'])} | "
                   f"{bfe._pct(row['learned_projection'])} | {bfe._pct(a['nonrigid'])} | {bfe._pct(b['nonrigid'])} | {_ratio(ratio['nonrigid'])} | {bfe._pct(a['com'])} | "
                   f"{bfe._pct(b['com'])} | {_ratio(ratio['com'])} | {'right' if row['model_metrics']['stick_slip_right'] else 'WRONG'}; "
                   f"{agree} | {bfe._pct(e['nonrigid'])} / {bfe._pct(e['com'])} | {meets} |")
    if train:
        out += ["", f"(d) For reference, the model on its own training mesh ({train[0]['tets']} tets) against that mesh's full run "
                "(section 11's default rows, rerun here):", "",
                "| held-out run | noise floor (non-rigid / COM) | non-rigid error | final COM / size | stick/slip |", "|---|---|---|---|---|"]
    else:
        out += ["", f"No full runs of the training mesh ({model['tets']} tets) here (`--no-training-truth`): (b), the ratio, (e) "
                "and (d) are not measured."]
    for row in train:
        m, floor = row["model"], row["floor"]
        out.append(f"| {row['kind']} | {bfe._pct(floor['nonrigid_error'])} / {bfe._pct(floor['com_error'])} | {bfe._pct(m['nonrigid_error'])} | "
                   f"{bfe._pct(m['com_error'])} | {'right' if m['stick_slip_right'] else 'WRONG'} |")
    gaps = result["truth_gaps"]
    kinds = {row["name"]: row["kind"] for row in train or result["other_meshes"]}
    out += ["", "Truth against truth, every pair of meshes (full runs; the coarser interpolated at the finer's vertices, against "
            "the finer's run; (b) above is measured at M's vertices, coarser or finer), non-rigid / final COM:", "",
            "| meshes (tets) | " + " | ".join(kinds.values()) + " |", "|---|" + "---|" * len(kinds)]
    for pair in dict.fromkeys((g["coarse"], g["fine"]) for g in gaps):
        cells = {g["name"]: g for g in gaps if (g["coarse"], g["fine"]) == pair}
        out.append(f"| {pair[0]} - {pair[1]} | " + " | ".join(f"{bfe._pct(cells[n]['nonrigid'])} / {bfe._pct(cells[n]['com'])}"
                                                              for n in kinds) + " |")
    out += ["", "Per mesh: cubature refitted on M (tets, relative force residual, seconds), M's vertices inside the training mesh (the rest clamped to its "
            "nearest tet), median reduced step over each run (ms, its setup s), median full step of M's cached runs (ms, when they ran):", "",
            "| mesh M | vertices | refitted cubature | M's vertices inside the training mesh | reduced ms/step | reduced setup s | full ms/step |",
            "|---|---|---|---|---|---|---|"]
    for tets in dict.fromkeys(r["tets"] for r in result["other_meshes"]):
        rows = [r for r in result["other_meshes"] if r["tets"] == tets]
        first = rows[0]
        steps = [r["model_metrics"]["step_ms"] for r in rows]
        setups = [r["setup_s"] for r in rows]
        fulls = [r["full_step_ms"] for r in rows]
        out.append(f"| {tets} tets | {first['vertices']} | {first['refit_cubature']} tets, {first['refit_residual']:.1e}, {first['refit_s']:.1f} s | "
                   f"{100 * first['inside_training_mesh']:.0f} % | {min(steps):.2f}-{max(steps):.2f} | {min(setups):.1f}-{max(setups):.1f} | "
                   f"{min(fulls):.0f}-{max(fulls):.0f} |")
    return "\n".join(out)


def small_model(path: Path, fam: bfe.Family, cache: Path) -> Model:
    """A 1-epoch model trained here with ``licrom.train`` defaults on two of the family's training runs (smoke test)."""
    import licrom

    if not path.exists():
        runs = [bfe.full_run(cache, c.name, fam.mesh, c.scene, SMALL_STEPS) for c in fam.training[:2]]
        licrom.train(runs, path, TrainConfig(epochs=1, progress=False))
    return Model.load(path)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", type=Path, default=Path("out/defaults/final/cheese.lcm"), help="model trained on the training mesh")
    ap.add_argument("--family", choices=tuple(RESOLUTION_OF), default="cheese", help="the object (sphere: the soft ball; 32: 103536 tets)")
    ap.add_argument("--training-resolution", type=int, default=10, help="resolution of the model's mesh (cheese 10: 1638 tets)")
    ap.add_argument("--drawn", type=int, default=0, help="also the first N drawn scenes of more_scenes.py")
    ap.add_argument("--no-floors", action="store_true", help="skip the noise-floor runs (the table's floor column reads -)")
    ap.add_argument("--resolutions", type=int, nargs="+", default=[8, 12, 16], help="other meshes (8: 864 tets, 12: 2748, 16: 6960)")
    ap.add_argument("--work", type=Path, default=Path("out/cross_mesh"), help="results and full runs of meshes without --cache")
    ap.add_argument("--cache", action="append", default=None, metavar="R:DIR",
                    help="full runs of resolution R cached under DIR (default: 10:out/body_frame_c10 and 8:out/body_frame)")
    ap.add_argument("--docs", type=Path, default=Path("docs"))
    ap.add_argument("--small", action="store_true", help="tiny meshes, 20 steps, one scene, a 1-epoch model: writes nothing under --docs")
    ap.add_argument("--record-unconverged", action="store_true",
                    help="held-out full runs record unconverged steps instead of stopping (SolverParams(on_failure='record'), as at 100k tets)")
    ap.add_argument("--truths-only", action="store_true", help="run and cache the full runs of every mesh, then stop (no model needed)")
    bfe.add_physics_arguments(ap)
    ap.add_argument("--section", default=SECTION_TITLE, help="title of the docs section written")
    ap.add_argument("--no-training-truth", action="store_true",
                    help="no full runs of the training mesh (one too large for this machine): (a) on each other mesh, and the gaps between those")
    args = ap.parse_args()
    t_start = time.perf_counter()
    work = args.work / "small" if args.small else args.work
    caches = {} if args.small else {10: Path("out/body_frame_c10"), 8: Path("out/body_frame")}
    caches.update({int(r): Path(d) for r, d in (c.split(":", 1) for c in args.cache or [])})
    train_res, resolutions = (5, [4, 6]) if args.small else (args.training_resolution, args.resolutions)

    def cache(resolution: int) -> Path:
        return caches.get(resolution, work / f"r{resolution}")

    def family(resolution: int) -> bfe.Family:
        return bfe.physics_of(family_on(args.family, resolution), args)

    def held(fam: bfe.Family) -> list[bfe.Case]:
        """The held-out cases on ``fam``'s mesh, recording unconverged steps with ``--record-unconverged``."""
        cases = held_cases(args.family, fam, args.drawn)
        if not args.record_unconverged:
            return cases
        return [dataclasses.replace(c, scene=c.scene.replace(solver=SolverParams(on_failure="record"))) for c in cases]

    floors = not args.no_floors
    train_fam = family(train_res)
    steps = SMALL_STEPS if args.small else train_fam.steps
    cases = held(train_fam)[:1] if args.small else held(train_fam)
    names = {c.name for c in cases}
    if args.truths_only:
        for res in resolutions:
            fam = family(res)
            truths(cache(res), fam, [c for c in held(fam) if c.name in names], steps, floors)
        return
    model_path = work / "model.lcm" if args.small else args.model
    model = small_model(model_path, train_fam, cache(train_res)) if args.small else Model.load(model_path)
    if model.mesh.n_tets != train_fam.mesh.n_tets:
        raise SystemExit(f"the model's mesh has {model.mesh.n_tets} tets, the resolution-{train_res} {args.family} {train_fam.mesh.n_tets}: "
                         "pass its --training-resolution")
    train = None if args.no_training_truth else truths(cache(train_res), train_fam, cases, steps, floors)
    result = {"family": args.family, "drawn": args.drawn, "steps": steps, "dt": cases[0].scene.dt, "integrator": cases[0].scene.integrator, "full_device": resolve_device("auto"),
              "viscosity": cases[0].scene.material.viscosity,
              "model": {"path": str(model_path), "r": model.n_learned, "tets": model.mesh.n_tets, "cubature": model.cubature.count},
              "training_mesh": [] if train is None else own_mesh_rows(model, train, cases, steps, train_fam.record_every), "other_meshes": []}
    full_runs = {} if train is None else {train_fam.mesh.n_tets: {k: v[0] for k, v in train.items()}}
    for res in resolutions:
        fam = family(res)
        own_cases = [c for c in held(fam) if c.name in names]
        own = truths(cache(res), fam, own_cases, steps, floors)
        full_runs[fam.mesh.n_tets] = {k: v[0] for k, v in own.items()}
        result["other_meshes"] += other_mesh_rows(model, train, fam, own_cases, steps, own)
    result["truth_gaps"] = truth_gaps(full_runs)
    result["wall_s"] = time.perf_counter() - t_start
    text = report(result)
    print(text)
    with atomic_path(work / "cross_mesh.json") as tmp:
        tmp.write_text(json.dumps(result, indent=1, default=float))
    if args.small:
        return
    bfe.write_section(args.docs, f"{args.section}\n\n`python experiments/cross_mesh.py {shlex.join(sys.argv[1:])}` (issue 24, part 4) on "
                      f"{platform.processor() or platform.machine()}, {time.strftime('%Y-%m-%d')}; wall time {result['wall_s']:.0f} s "
                      "(full runs read from the cache where present).\n\n" + text + "\n", args.section)


if __name__ == "__main__":
    main()
