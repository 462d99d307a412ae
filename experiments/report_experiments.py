"""The report's friction experiments at full scale, measured; writes ``docs/results.md``.

    python experiments/report_experiments.py [--work licrom-out/experiments] [--docs docs] [--small]

Every expensive product is cached in the work folder (datasets, models, full-space
reference runs), so the script resumes where it stopped and models trained elsewhere
(e.g. on a GPU) can be dropped in as ``models/cheese_r{r}.lcm`` / ``models/sphere_r{r}.lcm``.

Experiments:
1. cheese: trained on the report's 15 runs (5 friction coefficients x 3 slopes), run on
   held-out friction coefficients and slopes inside and outside the training range;
2. sphere bouncing down a slope with mu 0.5, and on a held-out slope/friction;
3. discretisation independence: the model trained on one cheese mesh runs on a coarser
   and a finer mesh of the same object and on a different hole layout;
4. r in {8, 20, 40} and naive vs optimised cubature: error and speed;
5. per-step speedup on a ~100k-tet cheese.

``--small`` runs the whole pipeline on tiny meshes for a few steps with 2-epoch models (a
smoke test of under a minute); it caches in ``WORK/small`` and writes ``results.md`` to
``WORK/small/docs`` unless ``--docs`` is given.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import platform
import time
from dataclasses import dataclass
from pathlib import Path

import licrom
import numpy as np
from licrom import AffineBasis, FullSim, MeshBasis, Plane, ReducedSim, StackedBasis, Trajectory, meshes
from licrom.analysis.compare import Comparison, compare, time_steps
from licrom.data.presets import report_dataset_spec
from licrom.learn.model import ModelConfig
from licrom.learn.training import TrainConfig
from licrom.scene.placement import initial_state_between_planes, initial_state_on_plane
from licrom.subspace.affine import apply_affine, fit_affine
from licrom.subspace.cubature import ContactPoints, Cubature
from licrom.viz.render import filmstrip, pick_renderer, plot_errors

CHEESE_HELD_OUT = [  # (slope deg, mu, where it lies w.r.t. the training set)
    (15.0, 0.2, "inside"),
    (25.0, 0.4, "inside"),
    (25.0, 0.6, "inside"),
    (15.0, 0.05, "mu outside"),
    (20.0, 1.2, "mu outside"),
    (35.0, 0.4, "slope outside"),
    (5.0, 0.3, "slope outside"),
]
KEEP_MARKER = "<!-- sections below are measured by other scripts and kept when this one reruns -->\n"
SPHERE_HELD_OUT = [(20.0, 0.5, "training scene"), (25.0, 0.3, "held out")]


@dataclass
class Row:
    experiment: str
    case: str
    c: Comparison
    extra: dict


def _cached_full(path: Path, mesh, scene, steps: int, record_every: int = 1) -> Trajectory:
    if path.exists():
        traj = Trajectory.load(path)
        if traj.scene == scene and traj.n_frames == steps // record_every + 1 and traj.rest_positions.shape == mesh.vertices.shape:
            return traj
    traj = FullSim(mesh, scene).run(steps, record_every=record_every)
    traj.save(path, precision="float64")
    return traj


def _model(work: Path, name: str, data: Path, r: int, epochs: int) -> licrom.Model:
    path = work / "models" / f"{name}_r{r}.lcm"
    if not path.exists():
        print(f"training {path.name} ({epochs} epochs)", flush=True)
        # The report measures LiCROM as published: world-frame modes (new models default to the body frame).
        licrom.train(data, path, TrainConfig(epochs=epochs, progress=False), ModelConfig(latent_dim=r, frame="world"))
    return licrom.Model.load(path)


def _scene_on(base_scene, base_plane, mesh, slope, mu):
    plane = Plane.incline(slope, mu)
    initial = initial_state_between_planes(base_scene.initial, base_plane, plane, mesh, base_scene.material.density)
    return base_scene.replace(planes=(plane,), initial=initial)


def _run(experiment, case, model, mesh, scene, full_path, steps, record_every=1, **opts) -> tuple[Row, Trajectory, Trajectory]:
    full = _cached_full(full_path, mesh, scene, steps, record_every)
    sim = ReducedSim(model, mesh, scene, **opts)
    reduced = sim.run(steps, record_every=record_every)
    c = compare(full, reduced)
    # The best any run in this subspace can do: the full run projected onto it, frame by frame.
    values = model.values(mesh.vertices)
    projected = dataclasses.replace(full, displacements=np.einsum("nik,fk->fni", values, sim.project(full.displacements)))
    extra = {"tets": mesh.n_tets, "r": model.n_learned, "cubature": sim.cubature.scheme, "cubature_points": sim.cubature.count,
             "fit_error": sim.cubature.fit_error, "projection_error": compare(full, projected).mean_error}
    print(f"{experiment} | {case}: error {100 * c.mean_error:.2f} % (projection {100 * extra['projection_error']:.2f} %), "
          f"COM {100 * c.final_com_error:.2f} %, "
          f"{'slides' if c.slid_full else 'sticks'}/{'slides' if c.slid_reduced else 'sticks'}, "
          f"{c.full_step_ms:.1f} ms vs {c.reduced_step_ms:.3f} ms", flush=True)
    return Row(experiment, case, c, extra), full, reduced


def _table(rows: list[Row]) -> str:
    out = ["| case | tets | r | cubature | mean rel. error | projection error | final COM error / size | full | reduced "
           "| full ms/step | reduced ms/step | speedup |",
           "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for row in rows:
        c = row.c
        cub = f"{row.extra['cubature']} {row.extra['cubature_points']}"
        out.append(
            f"| {row.case} | {row.extra['tets']} | {row.extra['r']} | {cub} | {100 * c.mean_error:.2f} % | "
            f"{100 * row.extra['projection_error']:.2f} % | {100 * c.final_com_error:.2f} % | "
            f"{'slides' if c.slid_full else 'sticks'} | {'slides' if c.slid_reduced else 'sticks'}{'' if c.stick_slip_agree else ' (wrong)'} | "
            f"{c.full_step_ms:.1f} | {c.reduced_step_ms:.3f} | {c.speedup:.0f}x |"
        )
    return "\n".join(out)


def _verdict(rows: list[Row]) -> str:
    errs = np.array([r.c.mean_error for r in rows])
    coms = np.array([r.c.final_com_error for r in rows])
    agree = sum(r.c.stick_slip_agree for r in rows)
    return (f"mean of mean relative errors {100 * errs.mean():.2f} % (max {100 * errs.max():.2f} %, target < 5 %); "
            f"stick/slip right in {agree}/{len(rows)}; final COM error max {100 * coms.max():.2f} % of the size (target < 2 %)")


def _misses(rows: list[Row]) -> str:
    """One line per row that misses a target (5 % mean error, 2 % COM, stick/slip), with what tells why."""
    lines = []
    for row in rows:
        c = row.c
        if c.mean_error < 0.05 and c.final_com_error < 0.02 and c.stick_slip_agree:
            continue
        onset = float(c.times[np.argmax(c.frame_errors >= 0.5 * c.frame_errors.max())])
        lines.append(
            f"- {row.case}, r {row.extra['r']}, {row.extra['cubature']} {row.extra['cubature_points']}: mean error {100 * c.mean_error:.2f} %, final COM "
            f"{100 * c.final_com_error:.2f} % of the size ({1e3 * c.final_com_error * c.object_size:.1f} mm). The subspace holds the "
            f"full run to {100 * row.extra['projection_error']:.2f} % (projection), so the gap comes from the reduced dynamics "
            f"(cubature, contact), not the subspace; the error reaches half its peak at t = {onset:.2f} s"
            + (" (the landing), after which the block rests or slides on with the offset it landed with." if onset < 0.4 else ".")
        )
    return ("Targets missed:\n\n" + "\n".join(lines) + "\n") if lines else ""


def _sphere_controls(mesh, scene, full: Trajectory, steps: int, record_every: int, row: Row, modes: int = 40) -> str:
    """Two controls that say where the sphere's centre-of-mass drift comes from.

    A full run dropped 10 um higher measures how sensitive the scene itself is; a reduced run
    in affine + the best ``modes`` POD modes of this very run (every tet a cubature point)
    measures what any linear world-frame subspace of this size does.
    """
    init = scene.initial
    nudged = scene.replace(initial=dataclasses.replace(init, translation=tuple(np.add(init.translation, (0.0, 0.0, 1e-5)))))
    c_nudged = compare(full, FullSim(mesh, nudged).run(steps, record_every=record_every))
    rest, u = mesh.vertices, full.displacements
    residual = u - apply_affine(rest, fit_affine(rest, u, mesh.vertex_masses(1.0)))
    pod, _ = MeshBasis.pod(mesh, residual, modes)
    c_pod = compare(full, ReducedSim(StackedBasis(AffineBasis(), pod), mesh, scene, cubature=Cubature.full(mesh))
                    .run(steps, record_every=record_every))
    com = full.centers_of_mass()
    travel = float(np.linalg.norm(com[-1] - com[0]))
    size = float(np.linalg.norm(rest.max(0) - rest.min(0)))
    radius = 0.5 * float(rest.max(0)[0] - rest.min(0)[0])
    turns = travel / (2 * math.pi * radius)
    print(f"sphere controls: nudged full COM {100 * c_nudged.final_com_error:.3f} %, affine+POD{modes} COM "
          f"{100 * c_pod.final_com_error:.2f} %", flush=True)
    return (f"**Centre-of-mass target missed** (2 % of the size): the reduced sphere ends {100 * row.c.final_com_error:.0f} % of its "
            f"size ({100 * row.c.final_com_error * size:.1f} cm) from the full one after rolling {travel:.2f} m "
            f"({100 * row.c.final_com_error * size / travel:.1f} % of the distance), with its shape right to "
            f"{100 * row.c.mean_error:.1f} % throughout. The scene is not chaotic: the full simulation dropped 10 um higher ends "
            f"{100 * c_nudged.final_com_error:.3f} % of the size away. Nor is it the learned field: the subspace holds every frame of "
            f"the full run (projection error {100 * row.extra['projection_error']:.2f} %), and a run in affine + the {modes} best POD "
            f"modes of this very run, with every tet a cubature point, drifts as far ({100 * c_pod.final_com_error:.0f} %). "
            "It is the reduced dynamics of rolling contact: the deformation is tiny next to the travel, but the sphere rolls "
            f"about {turns:.0f} turns, so the contact flattening travels round its whole surface, and a linear world-frame "
            "subspace, which needs modes for every orientation of a deformation that turns with the body, lets the contact "
            "patch flatten less freely; the bounces and the rolling differ a little each time and add up. The body-frame "
            "model (section 10) was built as the remedy; on a soft ball it still ends 4.6 % of the size away even in its "
            "own run's 40 body-frame POD modes, so rolling contact stays a limit of the reduced dynamics in either frame. "
            "The held-out cheese runs of section 1, which slide or stick without turning over, meet it.\n")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--work", default="licrom-out/experiments")
    ap.add_argument("--docs", default=None, help="folder of results.md and figures/ (default docs, or WORK/small/docs with --small)")
    ap.add_argument("--epochs", type=int, default=300, help="epochs for models trained here (CPU)")
    ap.add_argument("--cubature", type=int, default=1000)
    ap.add_argument("--speed-resolution", type=int, default=42, help="cheese resolution of the speed test (~110k tets)")
    ap.add_argument("--skip", nargs="*", default=[], help="experiments to skip: cheese sphere mesh sweep speed")
    ap.add_argument("--small", action="store_true",
                    help="smoke test: tiny meshes, few steps, 2 epochs, 40 cubature tets, a tiny speed mesh; never writes into docs/")
    args = ap.parse_args()
    work = Path(args.work) / "small" if args.small else Path(args.work)
    docs = Path(args.docs) if args.docs is not None else (work / "docs" if args.small else Path("docs"))
    if args.small:
        args.epochs, args.cubature, args.speed_resolution = 2, 40, 5
    # Sizes: (resolution, steps[, record_every]) of the data sets (the sphere's one run needs more frames than
    # the 20 modes), the resolutions of the other cheese meshes, and the steps of the speed test.
    cheese_size, sphere_size = ((5, 10), (4, 25, 1)) if args.small else ((None, None), (None, None, None))
    other_resolutions = (4, 6, 5) if args.small else (9, 16, 12)
    full_timed, reduced_timed, warmup = (2, 5, 2) if args.small else (6, 200, 10)
    figs = docs / "figures"
    for d in (work / "full", work / "models", figs):
        d.mkdir(parents=True, exist_ok=True)
    sections: list[str] = []
    t_start = time.perf_counter()

    # --- data ---------------------------------------------------------------------------
    cheese = report_dataset_spec("cheese", resolution=cheese_size[0], steps=cheese_size[1])
    cheese.generate(work / "cheese-data", progress=False)
    base_plane = Plane.incline(20.0, 0.5)  # the spec's frame for carrying the drop onto other slopes
    base_scene = cheese.base_scene.replace(
        planes=(base_plane,),
        initial=initial_state_on_plane(cheese.initial_states[0], base_plane, cheese.mesh, cheese.base_scene.material.density),
    )
    model20 = _model(work, "cheese", work / "cheese-data", 20, args.epochs)
    naive = Cubature.naive(cheese.mesh, args.cubature)

    # --- 1. cheese held out ---------------------------------------------------------------
    if "cheese" not in args.skip:
        rows, curves = [], {}
        for slope, mu, where in CHEESE_HELD_OUT:
            scene = _scene_on(base_scene, base_plane, cheese.mesh, slope, mu)
            case = f"{slope:g} deg, mu {mu:g} ({where}; tan = {math.tan(math.radians(slope)):.2f})"
            row, full, reduced = _run("cheese", case, model20, cheese.mesh, scene, work / "full" / f"cheese_{slope:g}_{mu:g}.npz",
                                      cheese.steps, cubature=naive)
            rows.append(row)
            curves[f"{slope:g} deg, mu {mu:g}"] = row.c
            if where != "inside" or mu == 0.4:
                filmstrip([full, reduced], ["full", "reduced"], figs / f"cheese_{slope:g}_{mu:g}.png", title=case,
                          renderer=pick_renderer()[0])
        plot_errors(curves, figs / "cheese_errors.png")
        sections.append("## 1. Cheese on held-out slopes and friction coefficients\n\n"
                        "Training: the report's 15 runs (mu 0.1, 0.3, 0.5, 0.7, 0.9 x slopes 10, 20, 30 deg; "
                        f"{cheese.mesh.n_tets} tets, dropped from 2 cm, 2 s at h = 10 ms). Model r = 20 (+12 affine), "
                        f"naive cubature with {naive.count} tets, all {len(cheese.mesh.boundary_vertices)} boundary vertices as contact points.\n\n"
                        + _table(rows) + "\n\n" + _verdict(rows) + "\n\n" + _misses(rows) + "\n![errors](figures/cheese_errors.png)\n\n"
                        "![25 deg mu 0.4](figures/cheese_25_0.4.png)\n")

    # --- 2. sphere ------------------------------------------------------------------------
    if "sphere" not in args.skip:
        sphere = report_dataset_spec("sphere", *sphere_size)
        sphere.generate(work / "sphere-data", progress=False)
        sphere_model = _model(work, "sphere", work / "sphere-data", 20, args.epochs)
        splane = Plane.incline(20.0, 0.5)
        sbase = sphere.base_scene.replace(planes=(splane,), initial=initial_state_on_plane(
            sphere.initial_states[0], splane, sphere.mesh, sphere.base_scene.material.density))
        rows = []
        for slope, mu, where in SPHERE_HELD_OUT:
            scene = _scene_on(sbase, splane, sphere.mesh, slope, mu)
            row, full, reduced = _run("sphere", f"{slope:g} deg, mu {mu:g} ({where})", sphere_model, sphere.mesh, scene,
                                      work / "full" / f"sphere_{slope:g}_{mu:g}.npz", sphere.steps, sphere.record_every,
                                      cubature=Cubature.naive(sphere.mesh, args.cubature))
            rows.append(row)
            filmstrip([full, reduced], ["full", "reduced"], figs / f"sphere_{slope:g}_{mu:g}.png", frames=8, title=row.case,
                      renderer=pick_renderer()[0])
            if where == "training scene":
                controls = _sphere_controls(sphere.mesh, scene, full, sphere.steps, sphere.record_every, row,
                                            modes=2 if args.small else 40)
        sections.append("## 2. Sphere bouncing down a slope\n\n"
                        f"Training: the report's sphere run (20 deg, mu 0.5, {sphere.mesh.n_tets} tets, h = 2 ms). Model r = 20.\n\n"
                        + _table(rows) + "\n\n" + controls + "\n![sphere](figures/sphere_20_0.5.png)\n")

    # --- 3. other meshes of the object ---------------------------------------------------------
    if "mesh" not in args.skip:
        rows = []
        coarse, fine, same = other_resolutions
        others = [(f"coarser (resolution {coarse})", meshes.cheese(resolution=coarse)),
                  (f"finer (resolution {fine})", meshes.cheese(resolution=fine)),
                  ("other hole layout (seed 3)", meshes.cheese(resolution=same, holes=meshes.CheeseHoles(seed=3)))]
        for name, mesh in others:
            for slope, mu in ((25.0, 0.4), (15.0, 0.6)):
                scene = _scene_on(base_scene, base_plane, mesh, slope, mu)
                row, *_ = _run("mesh", f"{name}: {slope:g} deg, mu {mu:g}", model20, mesh, scene,
                               work / "full" / f"mesh_{name.split()[0]}_{slope:g}_{mu:g}.npz", cheese.steps,
                               cubature=Cubature.naive(mesh, args.cubature))
                rows.append(row)
        sections.append("## 3. Discretisation independence\n\nThe r = 20 model trained on the resolution-12 cheese, "
                        "run on other meshes, each compared with the full simulation on that mesh.\n\n" + _table(rows) + "\n\n"
                        + _misses(rows))

    # --- 4. r and cubature ---------------------------------------------------------------------
    if "sweep" not in args.skip:
        rows = []
        cases = [(25.0, 0.4), (15.0, 0.6)]
        for r in (8, 20, 40):
            model = model20 if r == 20 else _model(work, "cheese", work / "cheese-data", r, args.epochs)
            samples = model.project(np.stack([t.displacements[::10] for t in
                                              (Trajectory.load(p) for p in sorted((work / "cheese-data").glob("traj_*.npz")))]).reshape(
                -1, cheese.mesh.n_vertices, 3))
            optimized = Cubature.optimized(cheese.mesh, model, cheese.base_scene.material, samples, count=args.cubature // 4)
            for cub in (naive, Cubature.naive(cheese.mesh, args.cubature // 4), optimized):
                for slope, mu in cases:
                    scene = _scene_on(base_scene, base_plane, cheese.mesh, slope, mu)
                    row, *_ = _run("sweep", f"{slope:g} deg, mu {mu:g}", model, cheese.mesh, scene,
                                   work / "full" / f"cheese_{slope:g}_{mu:g}.npz", cheese.steps, cubature=cub)
                    rows.append(row)
        sections.append("## 4. Subspace size and cubature\n\nOptimised cubature: non-negative least squares on the reduced elastic "
                        f"forces of training frames (An et al. 2008), {args.cubature // 4} tets, "
                        "against the naive scheme with as many and with 4x as many tets.\n\n" + _table(rows) + "\n\n"
                        + _misses(rows))

    # --- 5. speed on ~100k tets ------------------------------------------------------------------
    if "speed" not in args.skip:
        big = meshes.cheese(resolution=args.speed_resolution)
        scene = _scene_on(base_scene, base_plane, big, 25.0, 0.4)
        # Timed over the same steps, after the 2 cm drop has landed (10 steps).
        fm, f_its = time_steps(FullSim(big, scene), full_timed, warmup=warmup)
        sim = ReducedSim(model20, big, scene, cubature=Cubature.naive(big, args.cubature), contact_points=ContactPoints.subset(big, 1000))
        rm, r_its = time_steps(sim, reduced_timed, warmup=warmup)
        sections.append(f"## 5. Speed on a {big.n_tets}-tet cheese\n\n| | ms/step (median) |\n|---|---|\n"
                        f"| full (warp, CPU; {f_its:.1f} Newton iterations) | {fm:.1f} |\n"
                        f"| reduced (r = 20 + 12, {args.cubature} cubature tets, 1000 contact points; {r_its:.1f} Newton iterations) | {rm:.3f} |\n"
                        f"| speedup | {fm / rm:.0f}x |\n")
        print(f"speed: {big.n_tets} tets, full {fm:.1f} ms, reduced {rm:.3f} ms, {fm / rm:.0f}x", flush=True)

    header = (f"# Results\n\nMeasured by `experiments/report_experiments.py` on {platform.processor() or platform.machine()}, "
              f"{time.strftime('%Y-%m-%d')}; wall time {time.perf_counter() - t_start:.0f} s. Errors are mass-weighted relative "
              "displacement errors averaged over the frames; the projection error is that of the full run projected onto the "
              "model's subspace (the best a run in it can do); COM errors are fractions of the object's bounding-box diagonal; "
              "stick/slip is judged on the second half of each run (slip of the contact points above 1% of the size).\n\n")
    # Sections measured by other scripts (training, peer comparison) follow the marker and are kept.
    results = docs / "results.md"
    kept = results.read_text().partition(KEEP_MARKER)[2] if results.exists() else ""
    results.write_text(header + "\n".join(sections) + "\n" + KEEP_MARKER + kept)
    (work / "results.json").write_text(json.dumps({"sections": sections}, indent=1))
    print(f"wrote {docs / 'results.md'}")


if __name__ == "__main__":
    main()
