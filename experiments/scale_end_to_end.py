"""The pipeline end to end on a >= 100k-tet mesh, every stage timed (issue 24, part 2).

    python experiments/scale_end_to_end.py --device cuda --resolution 42 --runs 20 --work out/scale
    python experiments/scale_end_to_end.py --device cuda --azimuths 10 --jobs 4 --work out/wide  # 40 runs over a machine's GPUs
    python experiments/scale_end_to_end.py --device cuda --azimuths 10 --paired --jobs 8 --work out/paired  # 20 runs, 10 azimuths
    python experiments/scale_end_to_end.py --section-only --work out/scale   # docs/results.md section 13
    python experiments/scale_end_to_end.py --small --work /tmp/scale          # a CPU smoke test, under a minute
    python experiments/scale_end_to_end.py --family sphere --device cuda --time-step 0.0005 --integrator bdf2 --viscosity 400 --work out/ball  # the ball, 103536 tets
    python experiments/scale_end_to_end.py --bounds out/scale/model/cheese.lcm --work out/scale  # subspace bounds only
    python experiments/scale_end_to_end.py --cubatures out/scale/model/cheese.lcm --every-tet --own-pod --work out/scale  # cubature, dynamics
    python experiments/scale_end_to_end.py --speed out/scale/model/cheese.lcm --work out/speed  # speed alone, one run at a time

The cheese family of ``experiments/body_frame_experiments.py`` (the same scenes and placement code)
on ``licrom.meshes.cheese(resolution=42)`` (120378 tets, 23398 vertices), or with ``--family sphere`` its ball
family on ``licrom.meshes.sphere(resolution=32)`` (103536 tets, 19789 vertices; 4 training runs, 1 held out):

1. **generate**: the family's training runs (``--runs`` of its 20: the first ones, azimuth by
   azimuth; ``--azimuths N``: 4 runs at each of N azimuths evenly spaced from 0 deg in place of the
   family's 5; ``--paired``: 2 runs at each, two corners of the slope x friction grid alternating
   between azimuths) and its held-out runs with the full simulation (``licrom.FullSim(mesh, scene,
   device=--device)``; ``--jobs`` runs at once, in processes that take the machine's GPUs in turn),
   each saved with ``Trajectory.save`` (float32, the CLI's default; file size noted);
2. **train**: ``licrom.train(run_files, path)`` with its defaults (r chosen from the data, cubature
   fitted and stored); wall time, the training and cubature fit times and the rank choice from
   ``model.metadata``, the peak GPU memory (``torch.cuda.max_memory_allocated``);
3. **reduce**: ``ReducedSim(model, scene=held_out_scene)`` for each held-out scene (the family's, and ``--drawn N``
   more drawn as ``more_scenes.py`` draws them; ``--noise-floor``: each also run in full dropped 0.1 mm higher): setup time (with
   its largest parts by a profile), per-step time (median), non-rigid error and final centre of
   mass against the full run of the same scene (``licrom.analysis.compare.compare``), the online error
   estimate, and the learned subspace's projection error of the run;
4. **speed-up**: the reduced step against the full step on ``--device`` and, with ``--cpu-steps``,
   a short full run on the CPU.

Everything goes to ``--work/scale.json`` (trajectories under ``--work/runs``, the model under
``--work/model``); ``--section-only`` writes section 13 of ``docs/results.md`` from it.
``--small`` runs the tiny cheese for 20 steps on the CPU with 1-epoch training and writes nothing under ``docs``.
``--bounds MODEL`` generates only the held-out runs (cached under ``--work/runs``) and writes to
``--work/bounds.json``, for each, the projection error (non-rigid, body frame) of the run onto MODEL's
learned modes and onto POD(r) of the run's own frames (r = MODEL's; the best r-dimensional subspace
for that run, the floor no training set can beat), beside each other. ``--cubatures MODEL`` runs the same
held-out runs with MODEL's stored cubature, with refits of it to the model's stored training poses at up to
``--cubature-counts`` tets, with every tet (``--every-tet``) and, with ``--own-pod``, on POD(r) of each run's own frames
with every tet, and with ``--training-pod`` on POD(r) of the training runs' frames (what the learned modes are trained
towards) with every tet (``--work/cubatures.json``): how much of the reduced error is the cubature's, the dynamics', the network's.
With ``--against-every-tet`` each variant is measured against the model run with every tet in place of the full run: a
cubature's share, on a machine without the GPU that a large mesh's full runs need.
``--speed MODEL`` times on one machine, one run at a time, each held-out scene's full step on ``--device`` (its run
generated alone) and MODEL's reduced step (one CPU thread), with ``--cpu-steps`` of the first scene's full run on
the CPU (``--work/speed.json``): the speed-ups without the other jobs of a study sharing the GPU.
"""

from __future__ import annotations

import argparse
import cProfile
import dataclasses
import json
import os
import platform
import pstats
import sys
import time
import warnings
from pathlib import Path

import licrom
import numpy as np
from licrom import BodyFrameSim, ReducedSim, Trajectory
from licrom.data.dataset import IMPACT_WINDOW, local_devices
from licrom.executors import run_tasks
from licrom.learn.model.config import ModelConfig
from licrom.learn.training import TrainConfig
from licrom.reduced.error_estimate import ERROR_THRESHOLD
from licrom.scene.scene import SolverParams
from licrom.subspace.body_basis import BodyFrameBasis
from licrom.subspace.cubature import ContactPoints, Cubature

sys.path.insert(0, str(Path(__file__).resolve().parent))
import body_frame_experiments as bfe
import more_scenes

FAMILY_AZIMUTHS = bfe.TRAINING_AZIMUTHS  # the family's own, before --azimuths replaces them
SECTION_TITLE = "## 13. End to end at 120k tets"
CONVERGED_TITLE = "## 17. End to end at 120k tets against a converged truth"  # the runs with a viscosity
PAIRED_TITLE = "## 20. End to end at 120k tets, trained at ten azimuths"  # --paired: 20 runs over 10 azimuths


def log(msg: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {msg}", flush=True)


def peak_gpu() -> tuple[float | None, callable]:
    try:
        import torch
    except ImportError:
        return None, lambda: None
    if not torch.cuda.is_available():
        return None, lambda: None
    torch.cuda.reset_peak_memory_stats()
    return 0.0, lambda: torch.cuda.max_memory_allocated() / 2**30


def generate(case: bfe.Case, mesh: licrom.Mesh, steps: int, device: str, runs: Path, record_every: int = 1,
             impact_window: float = 0.0) -> tuple[Path, dict]:
    """The full run of ``case`` on ``device`` (a frame every ``record_every`` steps, impact frames for
    ``impact_window`` s after each impact), saved (cached: a file already there is kept with its timing)."""
    path, meta = runs / f"{case.name}.npz", runs / f"{case.name}.json"
    if path.exists() and meta.exists():
        return path, json.loads(meta.read_text())
    t0 = time.perf_counter()
    sim = licrom.FullSim(mesh, case.scene, device=device)
    setup = time.perf_counter() - t0
    t1 = time.perf_counter()
    traj = sim.run(steps, record_every=record_every, impact_window=impact_window)
    wall = time.perf_counter() - t1
    t2 = time.perf_counter()
    traj.save(path)
    save = time.perf_counter() - t2
    info = {"name": case.name, "kind": case.kind, "held_out": case.held_out, "device": str(sim.device), "setup_s": setup, "run_s": wall,
            "save_s": save, "impact_frames": len(traj.impact_times), "steps": steps, "step_ms": 1e3 * wall / steps, "median_step_ms": 1e3 * float(np.median(traj.step_seconds)),
            "first10_step_ms": 1e3 * float(np.median(traj.step_seconds[:10])), "newton_its": float(np.mean(traj.iterations)),
            "unconverged": int(traj.info.get("unconverged_steps", 0)), "file_mb": path.stat().st_size / 2**20,
            # the truth's own validity: frames with an inverted tet (the landing of the soft cheese inverts some at 120k)
            "min_det_f": float(np.min(traj.min_det_f)), "inverted_frames": int(np.sum(traj.min_det_f <= 0.0))}
    meta.write_text(json.dumps(info, indent=1))
    log(f"full {case.name} on {info['device']}: setup {setup:.1f} s, {steps} steps in {wall:.1f} s (median {info['median_step_ms']:.1f} ms, "
        f"{info['newton_its']:.1f} its/step, min det F {info['min_det_f']:.3f}), saved {info['file_mb']:.0f} MiB in {save:.1f} s")
    return path, info


def profile_top(prof: cProfile.Profile, n: int = 8) -> list[dict]:
    """The ``n`` functions of the profile with the largest cumulative time, outside the profiler's own frames."""
    st = pstats.Stats(prof)
    rows = []
    for (file, _line, name), (_cc, _nc, _tt, ct, _callers) in st.stats.items():
        if "licrom" in file and not name.startswith("<"):
            rows.append({"function": f"{Path(file).name}:{name}", "s": ct})
    rows.sort(key=lambda r: -r["s"])
    return rows[:n]


def reduced_stage(model: licrom.Model, case: bfe.Case, full: Trajectory, steps: int, contact_points: int | None = None,
                  cubature: str | Cubature | None = None, projection: bool = True, record_every: int = 1) -> dict:
    """``ReducedSim(model, scene=case.scene)`` against the full run: setup (profiled), steps, errors, estimate.

    ``contact_points``: a farthest-point subset of that many boundary vertices (``ContactPoints.subset``, its
    setup time included) in place of the default. ``cubature``: ``ReducedSim``'s argument (None: the model's
    stored fit). ``projection``: also the learned subspace's projection error of the run."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the estimate's AccuracyWarning is reported in the table
        prof = cProfile.Profile()
        t0 = time.perf_counter()
        prof.enable()
        subset = None if contact_points is None else ContactPoints.subset(full.mesh, contact_points)
        sim = ReducedSim(model, scene=case.scene, contact_points=subset, cubature=cubature)
        prof.disable()
        setup = time.perf_counter() - t0
        t1 = time.perf_counter()
        reduced = sim.run(steps, record_every=record_every)
        run_s = time.perf_counter() - t1
    t2 = time.perf_counter()
    metrics = bfe.run_metrics(full, reduced)
    compare_s = time.perf_counter() - t2
    t3 = time.perf_counter()
    learned = float("nan")
    if projection:
        values = BodyFrameBasis(full.mesh, model, density=case.scene.material.density).values(full.mesh.vertices)
        learned = bfe.body_projection_error(full, values)
    proj_s = time.perf_counter() - t3
    est = reduced.error_estimate
    steps_ms = 1e3 * np.asarray(reduced.step_seconds)
    row = {"name": case.name, "kind": case.kind, "setup_s": setup, "setup_profile": profile_top(prof), "run_s": run_s,
           "median_step_ms": float(np.median(steps_ms)), "p90_step_ms": float(np.percentile(steps_ms, 90)),
           "cubature": sim.cubature.count, "cubature_scheme": sim.cubature.scheme, "cubature_fit_error": sim.cubature.fit_error,
           "contact_points": sim.contact_points.count, "nonrigid_error": metrics["nonrigid_error"], "com_error": metrics["com_error"],
           "stick_slip_right": metrics["stick_slip_right"], "estimate": float(est[-1]) if len(est) else float("nan"),
           "estimate_terms": reduced.info["error_estimate_terms"],
           "learned_projection": learned, "compare_s": compare_s, "projection_s": proj_s,
           "full_median_step_ms": 1e3 * float(np.median(full.step_seconds))}
    log(f"reduced {case.name} ({row['contact_points']} contact points, {row['cubature']} {row['cubature_scheme']} cubature tets): "
        f"setup {setup:.2f} s, median step {row['median_step_ms']:.3f} ms, non-rigid {bfe._pct(row['nonrigid_error'])} "
        f"(est {bfe._pct(row['estimate'])}: residual {bfe._pct(row['estimate_terms']['residual'])}, "
        f"cubature {bfe._pct(row['estimate_terms']['cubature'])}; learned proj {bfe._pct(learned)}), COM {bfe._pct(row['com_error'])}, compare {compare_s:.1f} s, "
        f"projection {proj_s:.1f} s")
    return row


def own_pod_projection(full: Trajectory, r: int) -> float:
    """Non-rigid error of ``full`` projected onto POD(r) of its own body-frame frames from first contact on."""
    values = BodyFrameBasis(full.mesh, own_pod(full, r), density=full.scene.material.density).values(full.mesh.vertices)
    return bfe.body_projection_error(full, values)


def recording_failures(case: bfe.Case) -> bfe.Case:
    """``case`` with unconverged steps recorded and counted rather than stopping the run (the 100-Newton-iteration
    cap is met a few times above the tolerance on the 120k-tet mesh, as in section 12)."""
    return dataclasses.replace(case, scene=case.scene.replace(solver=SolverParams(on_failure="record")))


def held_cases(args, fam: bfe.Family) -> list[bfe.Case]:
    """The family's first ``--held`` held-out scenes and ``--drawn`` drawn ones, recording failures."""
    rng = np.random.default_rng(more_scenes.SEED)
    drawn = [more_scenes.drawn_case(args.family, fam, rng, k) for k in range(args.drawn)]
    return [recording_failures(c) for c in [*fam.held_out[: args.held], *drawn]]


def floor_case(case: bfe.Case) -> bfe.Case:
    """``case`` dropped 0.1 mm higher: its noise floor's run."""
    return dataclasses.replace(case, name=case.name + bfe.NUDGED, scene=bfe.nudged(case.scene))


def full_runs(args, fam: bfe.Family, cases: list[bfe.Case], floors: bool = True):
    """Each of ``cases`` (recording failures) with its full run, its timing and (``--noise-floor`` and ``floors``) its
    noise floor (generated on ``--device``, ``--jobs`` at once, cached)."""
    cases = list(map(recording_failures, cases))
    floors = floors and args.noise_floor
    runs = [*cases, *map(floor_case, cases)] if floors else cases
    devices = local_devices(args.device, args.jobs)
    tasks = [(c, fam.mesh, fam.steps, devices[i % len(devices)], Path(args.work) / "runs", fam.record_every) for i, c in enumerate(runs)]
    generated = dict(run_tasks(generate, tasks, jobs=args.jobs))
    for i, case in enumerate(cases):
        path, info = generated[i]
        full = Trajectory.load(path)
        if floors:
            info = {**info, **noise_floor(case, full, generated[len(cases) + i][0])}
        yield case, full, info


def noise_floor(case: bfe.Case, full: Trajectory, nudged: Path) -> dict:
    """``{"floor", "floor_com"}``: non-rigid error and final centre of mass of ``case``'s full run against its run
    dropped 0.1 mm higher (the file ``nudged``)."""
    m = bfe.run_metrics(full, Trajectory.load(nudged))
    log(f"  noise floor of {case.name}: non-rigid {bfe._pct(m['nonrigid_error'])}, COM {bfe._pct(m['com_error'])}")
    return {"floor": m["nonrigid_error"], "floor_com": m["com_error"]}


FAMILY_TEXT = {
    "cheese": ("The cheese family of section 10 (soft cheese, E = 20 kPa, 6 cm drop; scenes from "
               "`body_frame_experiments.cheese_family`, same placement code)", "meshes.cheese"),
    "sphere": ("The ball family of section 10 (soft ball of radius 5 cm, E = 20 kPa, thrown down a slope to bounce and "
               "roll; scenes from `body_frame_experiments.sphere_family`, same placement code)", "meshes.sphere"),
}
"""Each family's description in the section, and the mesh function it runs on."""

TRUTH_TEXT = {
    "cheese": ("The truth here is the full run at the same h, integrator and viscosity, which section 12 measures as converged "
               "in time (on the 33k-tet mesh: backward Euler at 0.5 ms and BDF2 at 1 ms within 2 % of the size and 5 % non-rigid of "
               "h = 0.25 ms) and, on the mesh, 2.7 % / 5.0 % from 33k to this 120k mesh."),
    "sphere": ("The truth here is the full run at the same h, integrator and viscosity, which section 12 measures as converged "
               "in time (BDF2 at 0.5 ms within 0.7 % of the size and 4.0 % non-rigid of h = 0.25 ms) and, on the mesh, 0.3 % / "
               "6.6 % from 34k to this 104k mesh (backward Euler at 0.5 ms)."),
}
"""How converged each family's truth is at its default resolution with damping (section 12)."""

DEFAULT_RESOLUTION = {"cheese": 42, "sphere": 32}
"""``--resolution`` where it is not given: 120378 cheese tets, 103536 ball tets."""


def study_family(args) -> bfe.Family:
    """``--family`` on ``--resolution``, at ``--time-step``, ``--integrator`` and ``--viscosity`` where given."""
    if args.family == "sphere":
        bfe.SPHERE_RESOLUTION = args.resolution
        return bfe.physics_of(bfe.sphere_family(args.small), args)
    bfe.CHEESE_RESOLUTION = args.resolution
    return bfe.physics_of(bfe.cheese_family(args.small), args)


def held_out_family(args) -> bfe.Family:
    (Path(args.work) / "runs").mkdir(parents=True, exist_ok=True)
    return study_family(args)


def pod_dynamics(full: Trajectory, case: bfe.Case, pod, steps: int, label: str, record_every: int = 1) -> dict:
    """The body-frame reduced run of ``case`` on the POD modes ``pod``, every tet as cubature, against ``full``."""
    basis = BodyFrameBasis(full.mesh, pod, density=case.scene.material.density)
    t0 = time.perf_counter()
    reduced = BodyFrameSim(basis, full.mesh, case.scene, cubature=Cubature.full(full.mesh)).run(steps, record_every=record_every)
    metrics = bfe.run_metrics(full, reduced)
    row = {"name": case.name, "kind": case.kind, "variant": label, "run_s": time.perf_counter() - t0,
           "median_step_ms": 1e3 * float(np.median(reduced.step_seconds)), "cubature": int(full.mesh.n_tets),
           "nonrigid_error": metrics["nonrigid_error"], "com_error": metrics["com_error"], "stick_slip_right": metrics["stick_slip_right"],
           "projection": bfe.body_projection_error(full, basis.values(full.mesh.vertices))}
    log(f"{label} {case.name}: non-rigid {bfe._pct(row['nonrigid_error'])} (projection {bfe._pct(row['projection'])}), "
        f"COM {bfe._pct(row['com_error'])}, median step {row['median_step_ms']:.1f} ms")
    return row


def own_pod(full: Trajectory, r: int):
    """POD(r) of ``full``'s own body-frame frames from first contact on: the best r-dimensional subspace for that run."""
    return bfe.residual_pod(full.mesh, [bfe.body_displacements(full)[bfe.contact_start(full):]], bfe.masses_of(full), r)


def training_pod(args, fam: bfe.Family, r: int):
    """POD(r) of the first ``--runs`` training runs' body-frame frames from first contact on, run-balanced as training
    balances them (generated on ``--device``, cached): what the learned modes are trained towards."""
    frames, masses = [], None
    for _, run, _ in full_runs(args, fam, fam.training[: args.runs], floors=False):
        masses = bfe.masses_of(run)
        frames.append(bfe.body_displacements(run)[bfe.contact_start(run):])
    t0 = time.perf_counter()
    pod = bfe.residual_pod(fam.mesh, frames, masses, r)
    log(f"training POD({r}) of {len(frames)} runs, {sum(len(f) for f in frames)} frames: {time.perf_counter() - t0:.1f} s")
    return pod


def bounds_study(args) -> dict:
    """The held-out runs' subspace bounds for the model ``args.bounds``: learned and own-POD(r) projection errors."""
    work = Path(args.work)
    fam = held_out_family(args)
    model = licrom.Model.load(args.bounds)
    values = BodyFrameBasis(fam.mesh, model, density=fam.cases[0].scene.material.density).values(fam.mesh.vertices)
    rows = []
    for case, full, info in full_runs(args, fam, held_cases(args, fam)):
        t0 = time.perf_counter()
        row = {"name": case.name, "kind": case.kind, "tets": int(fam.mesh.n_tets), "r": int(model.n_learned),
               "learned_projection": bfe.body_projection_error(full, values), "own_pod_projection": own_pod_projection(full, model.n_learned),
               "full_median_step_ms": info["median_step_ms"]}
        log(f"bounds {case.name}: learned {bfe._pct(row['learned_projection'])}, own POD({model.n_learned}) "
            f"{bfe._pct(row['own_pod_projection'])} ({time.perf_counter() - t0:.1f} s)")
        rows.append(row)
        (work / "bounds.json").write_text(json.dumps({"model": str(args.bounds), "device": args.device, "rows": rows}, indent=1))
    return {"rows": rows}


def every_tet_runs(args, fam: bfe.Family, model: licrom.Model, cases: list[bfe.Case]):
    """Each of ``cases`` with ``model`` run on it with every tet as its cubature (cached under ``--work/every_tet``), in
    place of its full run (``--against-every-tet``): the share of a cubature in the error, on a machine without the GPU
    that the full runs of a large mesh need."""
    for case in cases:
        path = Path(args.work) / "every_tet" / f"{case.name}.npz"
        if path.exists():
            reference = Trajectory.load(path)
        else:
            t0 = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # its estimate is reported beside each variant's
                reference = ReducedSim(model, scene=case.scene, cubature="full").run(fam.steps, record_every=fam.record_every)
            log(f"reference {case.name}: the model with every tet, {time.perf_counter() - t0:.0f} s")
            path.parent.mkdir(parents=True, exist_ok=True)
            reference.save(path)
        yield case, reference, {"median_step_ms": 1e3 * float(np.median(reference.step_seconds))}


def cubature_study(args) -> dict:
    """The held-out runs with the model ``args.cubatures``' stored cubature, refits of it to its stored training
    poses at ``--cubature-counts`` tets (tolerance ``--cubature-tolerance``), every tet (``--every-tet``), the stored
    cubature with ``--contact-points`` subsets (a count of at least the boundary's vertices: every one), the
    stored cubature solved to other reduced tolerances (``--reduced-tolerances``), and
    on each run's own POD(r) (``--own-pod``) and the training runs' (``--training-pod``); to ``--work/cubatures.json``."""
    work = Path(args.work)
    fam = held_out_family(args)
    model = licrom.Model.load(args.cubatures)
    variants: list[tuple[str, str | Cubature | None, float, int | None]] = [("stored", None, 0.0, None)]
    for count in args.cubature_counts:
        t0 = time.perf_counter()
        fit = Cubature.fitted(model, model.cubature_samples, count=count, tolerance=args.cubature_tolerance, candidates=args.cubature_candidates)
        fit_s = time.perf_counter() - t0
        log(f"cubature refit at most {count} tets: {fit.count} tets, residual {fit.fit_error:.2e}, {fit_s:.1f} s")
        variants.append((f"refit {count}", fit, fit_s, None))
    variants += [(f"stored, {n} contact points", None, 0.0, n) for n in args.contact_points]
    if args.every_tet and not args.against_every_tet:
        variants.append(("every tet", "full", 0.0, None))
    pods = [(f"training POD({model.n_learned}), every tet", training_pod(args, fam, model.n_learned))] if args.training_pod else []
    rows = []

    def save() -> None:
        (work / "cubatures.json").write_text(json.dumps({"model": str(args.cubatures), "device": args.device, "rows": rows}, indent=1, default=str))

    cases = held_cases(args, fam)
    references = every_tet_runs(args, fam, model, cases) if args.against_every_tet else full_runs(args, fam, cases)
    for case, full, info in references:
        for label, cubature, fit_s, points in variants:
            row = reduced_stage(model, case, full, fam.steps, contact_points=points, cubature=cubature, projection=label == "stored",
                                record_every=fam.record_every)
            rows.append({**row, "variant": label, "fit_s": fit_s, "tets": int(fam.mesh.n_tets), "r": int(model.n_learned),
                         "full_step_ms_device": info["median_step_ms"], "floor": info.get("floor"), "floor_com": info.get("floor_com")})
            save()
        for tol in args.reduced_tolerances:
            tight = dataclasses.replace(case, scene=case.scene.replace(solver=dataclasses.replace(case.scene.solver, reduced_tolerance=tol)))
            row = reduced_stage(model, tight, full, fam.steps, projection=False, record_every=fam.record_every)
            rows.append({**row, "variant": f"stored, reduced tolerance {tol:g} m/s", "fit_s": 0.0, "tets": int(fam.mesh.n_tets),
                         "r": int(model.n_learned), "full_step_ms_device": info["median_step_ms"]})
            save()
        for label, pod in pods:
            rows.append(pod_dynamics(full, case, pod, fam.steps, label, fam.record_every))
            save()
        if args.own_pod:
            rows.append(pod_dynamics(full, case, own_pod(full, model.n_learned), fam.steps, f"own POD({model.n_learned}), every tet",
                                     fam.record_every))
            save()
            (work / "cubatures.json").write_text(json.dumps({"model": str(args.cubatures), "device": args.device, "rows": rows}, indent=1, default=str))
    return {"rows": rows}


def speed_study(args) -> dict:
    """``--speed MODEL``: the held-out scenes' full step on ``--device`` and MODEL's reduced step, one run at a time."""
    work = Path(args.work)
    fam = held_out_family(args)
    model = licrom.Model.load(args.speed)
    import torch  # licrom's training dependency, imported where it is used

    out = {"model": str(args.speed), "device": args.device, "gpu": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
           "cpus": os.cpu_count(), "date": time.strftime("%Y-%m-%d"), "rows": []}
    for case, full, info in full_runs(args, fam, held_cases(args, fam)):
        row = reduced_stage(model, case, full, fam.steps, projection=False, record_every=fam.record_every)
        row.update(full_device=info["device"], full_device_step_ms=info["median_step_ms"], speedup_device=info["median_step_ms"] / row["median_step_ms"])
        out["rows"].append(row)
        log(f"speed {case.name}: reduced {row['median_step_ms']:.3f} ms, full {info['median_step_ms']:.2f} ms on {info['device']}: "
            f"{row['speedup_device']:.1f}x")
        (work / "speed.json").write_text(json.dumps(out, indent=1, default=str))
    if args.cpu_steps and out["rows"]:
        case = fam.held_out[0]
        traj = licrom.FullSim(fam.mesh, recording_failures(case).scene, device="cpu").run(args.cpu_steps)
        cpu_ms = 1e3 * float(np.median(traj.step_seconds))
        first = json.loads((work / "runs" / f"{case.name}.json").read_text())["first10_step_ms"]
        out["cpu_full"] = {"scene": case.kind, "steps": args.cpu_steps, "median_step_ms": cpu_ms, "device_first_steps_ms": first,
                           "speedup_cpu": cpu_ms / out["rows"][0]["median_step_ms"]}
        log(f"full on the CPU: {args.cpu_steps} steps, median {cpu_ms:.0f} ms (same steps on {args.device}: {first:.1f} ms); "
            f"{out['cpu_full']['speedup_cpu']:.0f}x the reduced step")
        (work / "speed.json").write_text(json.dumps(out, indent=1, default=str))
    log("done")
    return out


def main_study(args) -> dict:
    work = Path(args.work)
    (work / "runs").mkdir(parents=True, exist_ok=True)
    (work / "model").mkdir(parents=True, exist_ok=True)
    out = {"machine": platform.machine(), "python": platform.python_version(), "device": args.device, "resolution": args.resolution,
           "family": args.family,
           "small": args.small, "date": time.strftime("%Y-%m-%d"), "stages": {}}
    try:
        import torch
        out["torch"] = torch.__version__
        if torch.cuda.is_available():
            out["gpu"] = torch.cuda.get_device_name(0)
        out["torch_threads"] = torch.get_num_threads()
    except ImportError:
        pass
    out["cpus"] = os.cpu_count()
    t_all = time.perf_counter()

    t0 = time.perf_counter()
    fam = study_family(args)
    if args.runs is None:
        args.runs = len(fam.training)
    mesh = fam.mesh
    out["stages"]["mesh"] = {"s": time.perf_counter() - t0, "tets": int(mesh.n_tets), "vertices": int(mesh.n_vertices)}
    log(f"mesh and scenes: {mesh.n_tets} tets, {mesh.n_vertices} vertices in {out['stages']['mesh']['s']:.1f} s")
    train_cases = [recording_failures(c) for c in fam.training[: args.runs]]
    held = held_cases(args, fam)
    floor_cases = list(map(floor_case, held)) if args.noise_floor else []
    steps = fam.steps

    # 1. generate
    t0 = time.perf_counter()
    cases = train_cases + held + floor_cases
    first_process = os.environ.get("LOCAL_RANK", "0") == "0"
    if not first_process:
        # Another process of a DDP training, started again by its launcher once the first reached the fit: the runs
        # are on disk. (A pool of --jobs processes here hung three such processes of a 4-GPU training for 19 minutes.)
        devices = [args.device]
        generated = {i: (work / "runs" / f"{case.name}.npz", json.loads((work / "runs" / f"{case.name}.json").read_text()))
                     for i, case in enumerate(cases)}
    else:
        devices = local_devices(args.device, args.jobs)
        tasks = [(case, mesh, steps, devices[i % len(devices)], work / "runs", fam.record_every, 0.0 if case.held_out else args.impact_window)
                 for i, case in enumerate(cases)]
        generated = dict(run_tasks(generate, tasks, jobs=args.jobs))
    files, gen = zip(*(generated[i] for i in range(len(cases))))
    train_files = list(files[: len(train_cases)])
    held_files = list(files[len(train_cases): len(train_cases) + len(held)])
    floor_files = dict(zip([c.name for c in held], files[len(train_cases) + len(held):]))
    out["stages"]["generate"] = {"s": time.perf_counter() - t0, "runs": list(gen), "steps": steps, "dt": fam.cases[0].scene.dt,
                                 "integrator": fam.cases[0].scene.integrator, "viscosity": fam.cases[0].scene.material.viscosity,
                                 "record_every": fam.record_every,
                                 "jobs": args.jobs, "devices": devices, "training_azimuths": list(bfe.TRAINING_AZIMUTHS),
                                 "paired": bfe.PAIRED_DESIGN}
    if first_process:  # the others would overwrite the generation's timing with their reading of the files
        (work / "scale.json").write_text(json.dumps(out, indent=1))

    # 2. train
    model_path = work / "model" / f"{fam.name}.lcm"
    # --gpus N trains with DDP, whose launcher starts this script again in N - 1 more processes.
    gpus = {} if args.gpus is None else {"devices": args.gpus, "join_timeout_s": 900.0}
    cfg = TrainConfig(epochs=1, progress=False, **gpus) if args.small else TrainConfig(progress=False, **gpus)
    mcfg = None if args.rank is None else ModelConfig(latent_dim=args.rank)
    _, peak = peak_gpu()
    t0 = time.perf_counter()
    model = licrom.train([str(p) for p in train_files], model_path, cfg, mcfg)
    wall = time.perf_counter() - t0
    if not first_process:
        sys.exit(0)  # another process of a DDP run: the first one goes on
    md = model.metadata
    rank, cub, sub = md.get("rank", {}), md.get("cubature", {}), md.get("subspace", {})
    out["stages"]["train"] = {"s": wall, "fit_seconds": md.get("fit_seconds"), "cubature": cub, "rank": rank, "subspace": sub,
                              "r": int(model.n_learned), "data_seconds": md.get("data_seconds"), "epochs_trained": md.get("epochs_trained"),
                              "s_per_epoch": md.get("mean_train_seconds_per_epoch"), "peak_gpu_gib": peak(), "model_mb": model_path.stat().st_size / 2**20,
                              "final": md.get("final", {})}
    log(f"trained in {wall:.0f} s (fit {md.get('fit_seconds', float('nan')):.0f} s, cubature {cub.get('count')} tets in "
        f"{cub.get('fit_seconds', float('nan')):.1f} s), r = {model.n_learned}, peak GPU {out['stages']['train']['peak_gpu_gib']} GiB, "
        f"rank choice {rank.get('seconds', rank.get('fit_seconds'))}")
    (work / "scale.json").write_text(json.dumps(out, indent=1, default=str))

    # 3. reduce
    t0 = time.perf_counter()
    model = licrom.Model.load(model_path)
    load_s = time.perf_counter() - t0
    rows = []
    # Written after each run, so that a job cut short (a lent machine's time spent) leaves a section-ready file.
    out["stages"]["reduce"] = {"model_load_s": load_s, "rows": rows}
    for case, p in zip(held, held_files):
        full = Trajectory.load(p)
        rows.append(reduced_stage(model, case, full, steps, record_every=fam.record_every))
        if case.name in floor_files:
            rows[-1].update(noise_floor(case, full, floor_files[case.name]))
        (work / "scale.json").write_text(json.dumps(out, indent=1, default=str))
    sample_rows = []
    for count in args.contact_points:
        for case, p in zip(held, held_files):
            sample_rows.append(reduced_stage(model, case, Trajectory.load(p), steps, contact_points=count, record_every=fam.record_every))
            out["stages"]["contact_sample"] = sample_rows
            (work / "scale.json").write_text(json.dumps(out, indent=1, default=str))

    # 4. the full step on the CPU
    if args.cpu_steps and held:
        case = held[0]
        t0 = time.perf_counter()
        sim = licrom.FullSim(mesh, case.scene, device="cpu")
        setup = time.perf_counter() - t0
        t1 = time.perf_counter()
        traj = sim.run(args.cpu_steps)
        wall = time.perf_counter() - t1
        same = next(g for g in gen if g["name"] == case.name)
        out["stages"]["cpu_full"] = {"scene": case.kind, "steps": args.cpu_steps, "setup_s": setup, "run_s": wall,
                                     "median_step_ms": 1e3 * float(np.median(traj.step_seconds)), "newton_its": float(np.mean(traj.iterations)),
                                     "device_first_steps_ms": same["first10_step_ms"]}
        log(f"full on the CPU: {args.cpu_steps} steps, median {out['stages']['cpu_full']['median_step_ms']:.0f} ms "
            f"(same steps on {args.device}: {same['first10_step_ms']:.1f} ms)")
    out["total_s"] = time.perf_counter() - t_all
    (work / "scale.json").write_text(json.dumps(out, indent=1, default=str))
    log(f"done in {out['total_s']:.0f} s")
    return out


# --- section ---------------------------------------------------------------------------------
def _inverted(runs: list[dict]) -> str:
    """How many of ``runs`` invert a tet in some frame (runs of older studies did not record it)."""
    known = [g for g in runs if "inverted_frames" in g]
    bad = [g for g in known if g["inverted_frames"]]
    if not known:
        return "inverted tets not recorded"
    if not bad:
        return "no inverted tet"
    return (f"{len(bad)} of {len(known)} invert tets: " + ", ".join(f"{g['name']} ({g['inverted_frames']} frames, min det F {g['min_det_f']:.2f})" for g in bad))


def _f(x, fmt=".1f") -> str:
    return "-" if x is None else format(x, fmt)


def section_title(res: dict) -> str:
    """Section 13 for the family as it was (no material damping), 17 for runs with a viscosity, 20 for the paired design."""
    gen = res["stages"]["generate"]
    return PAIRED_TITLE if gen.get("paired") else CONVERGED_TITLE if gen.get("viscosity") else SECTION_TITLE


def training_design(gen: dict, runs: int, family: str = "cheese") -> str:
    """The training runs of a study in words: how many, at which azimuths, which slopes and frictions."""
    if family == "sphere":
        return f"{runs} training runs downhill along x, slopes 20 and 30 deg, mu 0.2 and 0.5, thrown at 0.5 m/s along x and 1 m/s down"
    az = gen.get("training_azimuths") or list(bfe.TRAINING_AZIMUTHS)
    where = f"at azimuths {', '.join(f'{a:g}' for a in az)} deg"
    if gen.get("paired"):
        return (f"{runs} training runs {where}, 2 at each (slope 15 deg with mu 0.2 and 30 deg with mu 0.8 at every other "
                "azimuth, 15 deg with mu 0.8 and 30 deg with mu 0.2 at the rest)")
    return f"{runs} training runs {where}, slopes 15 and 30 deg, mu 0.2 and 0.8" + (" (the first azimuths)" if runs < 4 * len(az) else "")


def section(res: dict, title: str | None = None) -> str:
    st = res["stages"]
    gen, train, red = st["generate"], st["train"], st["reduce"]
    runs = gen["runs"]
    tr = [g for g in runs if not g["held_out"]]
    # The held-out scenes' runs, and apart from them (--noise-floor) the same scenes dropped higher.
    ho = [g for g in runs if g["held_out"] and not g["name"].endswith(bfe.NUDGED)]
    floors = [g for g in runs if g["held_out"] and g["name"].endswith(bfe.NUDGED)]
    mesh = st["mesh"]
    cub, rank = train.get("cubature", {}), train.get("rank", {})
    rows = red["rows"]
    med_full = float(np.median([g["median_step_ms"] for g in ho])) if ho else float("nan")
    med_red = float(np.median([r["median_step_ms"] for r in rows])) if rows else float("nan")
    az = gen.get("training_azimuths") or []
    given = res["stages"].get("train", {}).get("rank", {})
    design = (f" --rank {given['rank']}" if str(given.get("method", "")).startswith("given") else "")
    design += (f" --azimuths {len(az)}" if az and list(az) != list(FAMILY_AZIMUTHS) else "") + (" --paired" if gen.get("paired") else "")
    family = res.get("family", "cheese")
    text, mesh_fn = FAMILY_TEXT[family]
    flag = "" if family == "cheese" else f" --family {family}"
    physics = (f" --time-step {gen['dt']:g} --integrator {gen['integrator']} --viscosity {gen['viscosity']:g}"
               if gen.get("viscosity") else "")
    out = [title or section_title(res), "",
           f"`python experiments/scale_end_to_end.py{flag} --device {res['device']} --resolution {res['resolution']} --runs {len(tr)}{design}{physics}` "
           f"(issue 24, part 2) on {res.get('gpu', 'no GPU')}, {res.get('cpus')} CPU cores, {res['date']}. {text} "
           f"on `{mesh_fn}(resolution={res['resolution']})`: {mesh['tets']} tets, {mesh['vertices']} vertices; {training_design(gen, len(tr), family)} "
           f"and its {len(ho)} held-out runs, "
           f"{gen['steps']} steps of h = {gen['dt'] * 1e3:g} ms each"
           + (f" ({gen['integrator']}, material viscosity {gen['viscosity']:g} Pa s, a frame every {gen['record_every']} steps)"
              if gen.get("viscosity") else "") + f", full simulation on {res['device']}.", "",
           "| stage | time | size / memory |", "|---|---|---|",
           f"| mesh and scenes (`{mesh_fn}`, placement) | {mesh['s']:.1f} s | {mesh['tets']} tets, {mesh['vertices']} vertices |"]
    if tr:
        where = ", ".join(sorted({g["device"] for g in tr}))
        busy = sum(g["setup_s"] + g["run_s"] + g["save_s"] for g in tr)
        # With several jobs the runs overlap: the stage's wall time (held-out runs included) beside the runs' own sum.
        took = f"{busy:.0f} s" if gen.get("jobs", 1) <= 1 else f"{gen['s']:.0f} s wall for these and the held-out runs, {gen['jobs']} jobs; {busy:.0f} s summed over the runs"
        out.append(f"| 1. generate: {len(tr)} training runs, full sim on {where} | {took} "
                   f"(per run: setup {np.median([g['setup_s'] for g in tr]):.1f} s, run {np.median([g['run_s'] for g in tr]):.1f} s, "
                   f"save {np.median([g['save_s'] for g in tr]):.1f} s; step {np.median([g['median_step_ms'] for g in tr]):.1f} ms median, "
                   f"{np.mean([g['newton_its'] for g in tr]):.1f} Newton its; {sum(g['unconverged'] for g in tr)} unconverged steps; "
                   f"{_inverted(tr)}) | "
                   f"{np.median([g['file_mb'] for g in tr]):.0f} MiB a run (float32), "
                   f"{sum(g['file_mb'] for g in tr):.0f} MiB in all |")
    if ho:
        also = f" and their {len(floors)} noise-floor runs (dropped 0.1 mm higher)" if floors else ""
        out.append(f"| 1b. the {len(ho)} held-out runs{also}, same ({_inverted(ho + floors)}) | "
                   f"{sum(g['setup_s'] + g['run_s'] + g['save_s'] for g in ho + floors):.0f} s | {sum(g['file_mb'] for g in ho + floors):.0f} MiB |")
    rest = train["s"] - sum(train.get(k) or 0.0 for k in ("data_seconds", "fit_seconds")) - (cub.get("fit_seconds") or 0.0)
    out.append(f"| 2. `licrom.train(runs, path)`, defaults | {train['s']:.0f} s: loading the runs {_f(train.get('data_seconds'), '.0f')} s, "
               f"training (`fit_seconds`) {_f(train.get('fit_seconds'), '.0f')} s ({train.get('epochs_trained')} epochs, "
               f"{_f(train.get('s_per_epoch'), '.2f')} s each), cubature fit {_f(cub.get('fit_seconds'))} s, the rest (rank choice by "
               f"{rank.get('method', '?')}, subspace check, saving) {rest:.0f} s | r = {train['r']} chosen"
               f"{' (capped)' if rank.get('capped') else ''}; {cub.get('count')} cubature tets of {mesh['tets']} "
               f"(force residual {_f(cub.get('fit_error'), '.1e')}); peak GPU memory {_f(train.get('peak_gpu_gib'), '.2f')} GiB; model "
               f"{train['model_mb']:.1f} MiB |")
    if rows:
        out.append(f"| 3. `ReducedSim(model, scene=...)` setup | {np.median([r['setup_s'] for r in rows]):.1f} s median "
                   f"({min(r['setup_s'] for r in rows):.1f}-{max(r['setup_s'] for r in rows):.1f}); model load {red['model_load_s']:.1f} s | - |")
        out.append(f"| 3b. reduced run, {gen['steps']} steps (CPU) | {np.median([r['run_s'] for r in rows]):.2f} s median; "
                   f"{med_red:.2f} ms a step | - |")
        out.append(f"| 3c. `compare(full, reduced)`; learned projection error | {np.median([r['compare_s'] for r in rows]):.1f} s; "
                   f"{np.median([r['projection_s'] for r in rows]):.1f} s a run | - |")
    if "cpu_full" in st:
        c = st["cpu_full"]
        out.append(f"| 4. full sim on the CPU, {c['steps']} steps | setup {c['setup_s']:.1f} s, {c['run_s']:.1f} s | "
                   f"{c['median_step_ms']:.0f} ms a step ({c['device_first_steps_ms']:.1f} ms for the same steps on the GPU) |")
    out += ["", f"Held-out runs (`ReducedSim(model, scene=scene)`, its defaults: the stored fitted cubature) against the full GPU run of "
            f"the same scene on the same mesh and h (`licrom.analysis.compare.compare`); learned projection: the non-rigid error of the full run "
            f"projected onto the model's body-frame modes (each frame keeping its rigid fit), the subspace's own floor; estimate: "
            f"the run's online error estimate (last frame, flagged above {ERROR_THRESHOLD * 100:g} %). ms/step: medians over the run, "
            f"reduced on the machine's CPU, full on the GPU; run wall / step: the whole `run(steps)` over its steps (recording "
            f"every frame, the estimate included).", "",
            "| held-out run | noise floor (non-rigid / COM) | learned projection | non-rigid error | final COM / size | estimate | stick/slip | "
            "setup s | reduced ms/step | full ms/step (GPU) | speed-up | run wall / step: reduced, full | speed-up (wall) |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    full_by_name = {g["name"]: g for g in ho}
    for r in rows:
        floor = f"{bfe._pct(r['floor'])} / {bfe._pct(r['floor_com'])}" if "floor" in r else "-"
        out.append(f"| {r['kind']} | {floor} | {bfe._pct(r['learned_projection'])} | {bfe._pct(r['nonrigid_error'])} | {bfe._pct(r['com_error'])} | "
                   f"{bfe._pct(r['estimate'])} | {'right' if r['stick_slip_right'] else 'wrong'} | {r['setup_s']:.1f} | "
                   f"{r['median_step_ms']:.2f} | {r['full_median_step_ms']:.1f} | {r['full_median_step_ms'] / r['median_step_ms']:.1f}x | "
                   f"{1e3 * r['run_s'] / gen['steps']:.1f} ms, {full_by_name[r['name']]['step_ms']:.1f} ms | "
                   f"{full_by_name[r['name']]['step_ms'] / (1e3 * r['run_s'] / gen['steps']):.1f}x |")
    if rows:
        out += ["", f"Median over the held-out runs: reduced {med_red:.2f} ms, full {med_full:.1f} ms on the GPU: "
                f"{med_full / med_red:.1f}x per step."]
        if "cpu_full" in st:
            c = st["cpu_full"]
            out[-1] += (f" The full step on the CPU ({c['steps']} steps of the first held-out scene, the drop before contact): "
                        f"{c['median_step_ms']:.0f} ms, {c['median_step_ms'] / med_red:.0f}x the reduced step.")
        prof = rows[0]["setup_profile"]
        out += ["", "Largest parts of the first held-out run's `ReducedSim` setup (cumulative, profiled): "
                + "; ".join(f"`{p['function']}` {p['s']:.2f} s" for p in prof[:6]) + "."]
    sample = st.get("contact_sample", [])
    if sample:
        every = {r["name"]: r for r in rows}
        out += ["", "Contact sampled: the same held-out runs with a farthest-point subset of the boundary vertices as contact points "
                "(`ContactPoints.subset(mesh, N)`: each boundary vertex gives its area to the nearest chosen point), beside the "
                "default run above (`ContactPoints.default`). Same model, cubature and machine.", "",
                "| held-out run | contact points | non-rigid error | final COM / size | estimate | stick/slip | reduced ms/step | "
                "full ms/step (GPU) | speed-up | run wall / step |", "|---|---|---|---|---|---|---|---|---|---|"]
        for r in sorted(rows + sample, key=lambda r: (r["name"], -r["contact_points"])):
            out.append(f"| {every[r['name']]['kind']} | {r['contact_points']} | {bfe._pct(r['nonrigid_error'])} | {bfe._pct(r['com_error'])} | "
                       f"{bfe._pct(r['estimate'])} | {'right' if r['stick_slip_right'] else 'wrong'} | {r['median_step_ms']:.2f} | "
                       f"{r['full_median_step_ms']:.1f} | {r['full_median_step_ms'] / r['median_step_ms']:.1f}x | {1e3 * r['run_s'] / gen['steps']:.1f} ms |")
    if gen.get("viscosity"):
        out += ["", TRUTH_TEXT[family]]
    else:
        out += ["", "The truth here is the full run at the same h = 10 ms, which is not converged in time (section 12: at h = 10 ms the "
                "120k-tet slide ends 176 % of the size from h = 0.125 ms); these errors measure how well the reduced model "
                "reproduces that same-h full run, not the converged motion."]
    return "\n".join(out) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--device", default="cuda", choices=("cuda", "cpu"), help="device of the full runs")
    ap.add_argument("--family", default="cheese", choices=tuple(FAMILY_TEXT), help="the object and its scenes")
    ap.add_argument("--resolution", type=int, default=None,
                    help="mesh resolution (default: 42 for the cheese, 120378 tets; 32 for the ball, 103536 tets)")
    ap.add_argument("--runs", type=int, default=None, help="training runs (the first of the family's; default: all)")
    ap.add_argument("--azimuths", type=int, default=None, metavar="N",
                    help="N training azimuths evenly spaced from 0 deg (4 runs each) in place of the family's 5")
    ap.add_argument("--paired", action="store_true",
                    help="2 runs at each training azimuth (two corners of the slope x friction grid, alternating) in place of 4")
    ap.add_argument("--gpus", type=int, default=None, help="GPUs of the training (TrainConfig.devices; default: licrom.train's)")
    ap.add_argument("--rank", type=int, default=None, help="r given (ModelConfig.latent_dim) in place of the choice from the data")
    ap.add_argument("--jobs", type=int, default=1,
                    help="full runs generated at once, in processes that take the machine's GPUs in turn (licrom.executors)")
    ap.add_argument("--held", type=int, default=4, help="held-out runs (of 4)")
    ap.add_argument("--drawn", type=int, default=0, metavar="N",
                    help="also N drawn held-out scenes of the family (more_scenes.drawn_case, its seed: the first N of its draws)")
    ap.add_argument("--noise-floor", action="store_true",
                    help="also each held-out scene dropped 0.1 mm higher in full: its noise floor beside the reduced run's error")
    ap.add_argument("--impact-window", type=float, default=IMPACT_WINDOW,
                    help="s of impact frames kept in the training runs (licrom generate's default; 0: none, as sections 13-23)")
    ap.add_argument("--contact-points", type=int, nargs="*", default=[], metavar="N",
                    help="also run the held-out scenes with farthest-point subsets of N contact points (ContactPoints.subset)")
    ap.add_argument("--cpu-steps", type=int, default=10, help="steps of a full run on the CPU (0: none)")
    bfe.add_physics_arguments(ap)
    ap.add_argument("--work", default="out/scale")
    ap.add_argument("--docs", default="docs")
    ap.add_argument("--small", action="store_true", help="tiny cheese, 20 steps, CPU, 1 epoch: a smoke test")
    ap.add_argument("--section-only", action="store_true", help="write the docs section from --work/scale.json")
    ap.add_argument("--section", help="title of the section --section-only writes (default: by the study's design, e.g. section 20 for --paired)")
    ap.add_argument("--bounds", type=Path, metavar="MODEL", help="only the held-out runs' subspace bounds for MODEL (--work/bounds.json)")
    ap.add_argument("--cubatures", type=Path, metavar="MODEL",
                    help="only the held-out runs with MODEL's stored cubature, its refits and every tet (--work/cubatures.json)")
    ap.add_argument("--speed", type=Path, metavar="MODEL",
                    help="only the speed: held-out full steps on --device, one run at a time, against MODEL's reduced step (--work/speed.json)")
    ap.add_argument("--cubature-counts", type=int, nargs="*", default=[3000], metavar="N", help="most tets of each refit (--cubatures)")
    ap.add_argument("--every-tet", action="store_true", help="also every tet as cubature (--cubatures)")
    ap.add_argument("--against-every-tet", action="store_true",
                    help="each --cubatures variant against the model run with every tet in place of the full run (no GPU needed)")
    ap.add_argument("--training-pod", action="store_true",
                    help="also each held-out run on POD(r) of the --runs training runs' frames, every tet (--cubatures; generates them)")
    ap.add_argument("--own-pod", action="store_true", help="also each held-out run on POD(r) of its own frames, every tet (--cubatures)")
    ap.add_argument("--reduced-tolerances", type=float, nargs="*", default=[], metavar="T",
                    help="also the stored cubature with SolverParams.reduced_tolerance = T m/s (--cubatures)")
    ap.add_argument("--cubature-candidates", type=int, default=None, metavar="N",
                    help="candidate tets of each refit (--cubatures; default: as many as the fit's memory holds)")
    ap.add_argument("--cubature-tolerance", type=float, default=1e-2, help="force residual at which a refit stops (--cubatures)")
    args = ap.parse_args()
    if args.resolution is None:
        args.resolution = DEFAULT_RESOLUTION[args.family]
    bfe.PAIRED_DESIGN = args.paired
    if args.azimuths is not None:
        bfe.TRAINING_AZIMUTHS = tuple(360.0 * k / args.azimuths for k in range(args.azimuths))
    if args.section_only:
        res = json.loads((Path(args.work) / "scale.json").read_text())
        title = args.section or section_title(res)
        bfe.write_section(Path(args.docs), section(res, title), title)
        return
    if args.small:
        args.device, args.resolution = "cpu", 5
    if args.bounds is not None:
        bounds_study(args)
        return
    if args.cubatures is not None:
        cubature_study(args)
        return
    if args.speed is not None:
        speed_study(args)
        return
    res = main_study(args)
    print(section(res))


if __name__ == "__main__":
    main()
