"""Is the truth converged? The full simulation's mesh and time-step convergence (issue 24, part 1).

Two held-out scenes of ``experiments/body_frame_experiments.py``, built with the same placement code
on other meshes of the same object:

* the soft cheese (E = 20 kPa) "soft, slides: 22 deg az 0, mu 0.3", 1.5 s (h = 10 ms: 150 steps);
* the soft ball (radius 5 cm) rolling down 25 deg, mu 0.3, 1 s (h = 5 ms: 200 steps).

Studies, each against its finest member at matching frame times:

* **mesh**: several resolutions (up to >= 100k tets) at the family's time step;
  non-rigid difference on a common set of material points (the coarsest mesh's vertices,
  weighted by its lumped masses): each run's displacement is interpolated to them with the
  barycentric coordinates of the containing tet of its own mesh (:meth:`licrom.Mesh.locate`),
  each frame's best rigid fit removed (:func:`licrom.rigid.body_frame_displacements`), and
  ``sqrt(sum_t |d_t|_w^2 / sum_t |u_t|_w^2)`` taken over frames from the finest run's first contact;
* **time step**: h = 10, 5, 2.5, 1 and 0.5 ms on one mesh for the same simulated time, frames
  recorded every 10 ms; non-rigid difference by :func:`licrom.analysis.compare.nonrigid_error`.
  ``--integrator bdf2`` runs the steps with BDF2 and ``--reference-integrator backward_euler`` measures
  them against backward Euler at the smallest step (the reference runs first; each row is saved as it
  is measured).

Both report the final centre of mass distance over the object's size. Full runs are cached as
``.npz`` under ``--work/runs`` (with their wall time beside them), so reruns skip them; the script
writes ``--work/results.json`` and section 12 of ``docs/results.md``. ``--section-only`` rewrites
the section from a ``results.json`` (e.g. one computed on a GPU machine). ``--small`` runs tiny
meshes for 0.2 s on the CPU (a smoke test, under a minute) and writes nothing under ``docs``.

Section 12 was made on an H100 with, per family (``--work`` one folder per family, the results
merged by ``--section-only``): the default (mesh study at the family's step, time study on the
~33k-tet mesh), ``--studies mesh --mesh-time-step 0.001``, and ``--studies time
--time-resolutions 27 42`` (ball: ``22 32``) ``--time-steps 0.01 0.005 0.0025 0.001 0.0005 0.00025 0.000125``.
Its BDF2 tables: ``--studies time --integrator bdf2 --reference-integrator backward_euler --time-steps 0.01 0.005
0.0025 0.001 0.0005 0.000125`` on the ~33k-tet meshes.
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import licrom
import numpy as np
from licrom import Material, Scene, Trajectory, meshes
from licrom.analysis.compare import first_contact_frame, nonrigid_error
from licrom.rigid import body_frame_displacements
from licrom.scene.scene import INTEGRATORS, SolverParams

sys.path.insert(0, str(Path(__file__).resolve().parent))
from body_frame_experiments import _on_plane, incline, write_section

SECTION_TITLE = "## 12. Is the truth converged? Mesh and time step"
FRAME_DT = 0.01  # s: frames compared in the time-step study (the largest step)
COM_TARGET, NONRIGID_TARGET = 0.02, 0.05  # of the finest: final COM / size, non-rigid difference

# family -> mesh builder, base time step, duration, resolutions (>= 100k tets last), time-study resolution
FAMILIES = {
    "cheese": dict(label="soft cheese, slides: 22 deg az 0, mu 0.3 (E = 20 kPa, 6 cm drop)", dt=0.01, duration=1.5,
                   resolutions=(8, 16, 27, 42), time_resolution=27, small_resolutions=(4, 5, 6), small_time_resolution=5),
    "sphere": dict(label="soft ball, rolls: 25 deg az 0, mu 0.3 (E = 20 kPa, thrown from 10 cm)", dt=0.005, duration=1.0,
                   resolutions=(7, 14, 22, 32), time_resolution=22, small_resolutions=(4, 5, 6), small_time_resolution=5),
}
TIME_STEPS = (0.01, 0.005, 0.0025, 0.001, 0.0005)
BE = "backward_euler"
INTEGRATOR_NAMES = {BE: "backward Euler", "bdf2": "BDF2"}


def build_mesh(family: str, resolution: int) -> licrom.Mesh:
    if family == "cheese":
        return meshes.cheese(resolution=resolution)
    return meshes.sphere(radius=0.05, resolution=resolution)


def build_scene(family: str, mesh: licrom.Mesh, dt: float, integrator: str = BE, viscosity: float = 0.0) -> Scene:
    """The held-out scene of ``body_frame_experiments`` on ``mesh`` with time step ``dt``, ``integrator`` and the
    material's Kelvin-Voigt ``viscosity`` (Pa s)."""
    # Unconverged steps (a 100-Newton-iteration cap met at a residual a few times the tolerance on fine meshes)
    # are recorded and counted rather than stopping the run.
    base = Scene(material=Material(youngs_modulus=2.0e4, poisson_ratio=0.3, density=1000.0, viscosity=viscosity), dt=dt,
                 integrator=integrator, solver=SolverParams(on_failure="record"))
    if family == "cheese":
        return _on_plane(mesh, base, incline(22.0, 0.0, 0.3), 0.06, (0.15, 0.1, 0.0))
    return _on_plane(mesh, base, incline(25.0, 0.0, 0.3), 0.1, velocity=(0.5, 0.0, -1.0))


def run_name(family: str, resolution: int, dt: float, record_every: int, integrator: str = BE, viscosity: float = 0.0) -> str:
    return (f"{family}_r{resolution}_h{dt * 1e3:g}ms_every{record_every}" + ("" if integrator == BE else f"_{integrator}")
            + (f"_eta{viscosity:g}" if viscosity else ""))


def full_run(work: Path, family: str, resolution: int, dt: float, duration: float, frame_dt: float,
             integrator: str = BE, viscosity: float = 0.0) -> tuple[Trajectory, dict]:
    """The full run (cached under ``work/runs``) and its timing: frames every ``frame_dt``."""
    steps, every = round(duration / dt), max(1, round(frame_dt / dt))
    name = run_name(family, resolution, dt, every, integrator, viscosity)
    path, meta_path = work / "runs" / f"{name}.npz", work / "runs" / f"{name}.json"
    if path.exists() and meta_path.exists():
        return Trajectory.load(path), json.loads(meta_path.read_text())
    mesh = build_mesh(family, resolution)
    sim = licrom.FullSim(mesh, build_scene(family, mesh, dt, integrator, viscosity))
    t0 = time.perf_counter()
    traj = sim.run(steps, record_every=every)
    wall = time.perf_counter() - t0
    path.parent.mkdir(parents=True, exist_ok=True)
    traj.save(path, precision="float32")
    meta = {"family": family, "resolution": resolution, "dt": dt, "integrator": integrator, "steps": steps, "record_every": every,
            "n_tets": int(mesh.n_tets), "n_vertices": int(mesh.vertices.shape[0]), "wall_s": wall,
            "step_ms": 1e3 * wall / steps, "median_step_ms": 1e3 * float(np.median(traj.step_seconds)) if len(traj.step_seconds) else None,
            "newton_its": float(np.mean(traj.iterations)) if len(traj.iterations) else None,
            "unconverged": int(traj.info.get("unconverged_steps", 0)), "device": str(traj.info.get("device")),
            "size": float(mesh.size)}
    meta_path.write_text(json.dumps(meta, indent=1))
    print(f"  {name}: {mesh.n_tets} tets, {steps} steps in {wall:.1f} s ({meta['step_ms']:.1f} ms/step, "
          f"{meta['newton_its']:.1f} Newton its/step, {meta['unconverged']} unconverged) on {meta['device']}", flush=True)
    return traj, meta


# --- metrics --------------------------------------------------------------------------------
def sampled_positions(traj: Trajectory, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rest and deformed positions (frames, p, 3) of the material points ``points`` (barycentric in the containing tet)."""
    mesh = traj.mesh
    tets, bary = mesh.locate(points)
    corners = mesh.tets[tets]  # (p, 4)
    rest = np.einsum("pk,pkj->pj", bary, traj.rest_positions[corners])
    x = traj.rest_positions[None] + traj.displacements
    return rest, np.einsum("pk,tpkj->tpj", bary, x[:, corners])


def sampled_nonrigid(ref: tuple[np.ndarray, np.ndarray], other: tuple[np.ndarray, np.ndarray], weights: np.ndarray, start: int) -> float:
    """Relative weighted difference of the body-frame displacements of two runs sampled at the same material points."""
    u = body_frame_displacements(ref[1][start:], ref[0], weights)
    v = body_frame_displacements(other[1][start:], other[0], weights)
    num = float(np.einsum("p,tpj->", weights, (v - u) ** 2))
    den = float(np.einsum("p,tpj->", weights, u**2))
    return math.sqrt(num / den) if den > 0 else float("inf")


def mesh_study(work: Path, family: str, spec: dict, resolutions: tuple[int, ...], duration: float, dt: float | None = None,
               viscosity: float = 0.0) -> list[dict]:
    """Against the finest mesh at time step ``dt`` (default the family's, every step a frame; otherwise frames every 10 ms)."""
    frame_dt = spec["dt"] if dt is None or dt == spec["dt"] else max(dt, FRAME_DT)
    dt = spec["dt"] if dt is None else dt
    coarse = build_mesh(family, resolutions[0])
    points, weights = coarse.vertices, coarse.vertex_masses(1000.0)  # common material points, the coarsest mesh's masses
    runs = [full_run(work, family, r, dt, duration, frame_dt, viscosity=viscosity) for r in resolutions]
    ref, _ = runs[-1]
    size = ref.mesh.size
    start = first_contact_frame(ref) or 0
    ref_s = sampled_positions(ref, points)
    ref_com = ref.centers_of_mass()[-1]
    rows = []
    for traj, meta in runs:
        s = sampled_positions(traj, points)
        rows.append({**meta, "com": float(np.linalg.norm(traj.centers_of_mass()[-1] - ref_com) / size),
                     "nonrigid": sampled_nonrigid(ref_s, s, weights, start), "start_frame": start,
                     "peak": float(np.abs(body_frame_displacements(s[1], s[0], weights)).max() / size)})
    return rows


def time_study(work: Path, family: str, resolution: int, duration: float, dts: tuple[float, ...], frame_dt: float,
               integrator: str = BE, reference: str | None = None, viscosity: float = 0.0) -> Iterator[list[dict]]:
    """Rows of ``dts`` with ``integrator`` against the smallest step with ``reference`` (default the same run).

    Yields the rows measured so far after each run (the reference first), so that a long study keeps its results.
    """
    reference = reference or integrator
    ref, ref_meta = full_run(work, family, resolution, min(dts), duration, frame_dt, reference, viscosity)
    size, ref_com = ref.mesh.size, ref.centers_of_mass()[-1]
    rows = []
    for dt in dts:
        traj, meta = (ref, ref_meta) if dt == min(dts) and reference == integrator else full_run(work, family, resolution, dt, duration, frame_dt, integrator, viscosity)
        rows.append({**meta, "com": float(np.linalg.norm(traj.centers_of_mass()[-1] - ref_com) / size),
                     "nonrigid": float(nonrigid_error(ref, traj)), "start_frame": int(first_contact_frame(ref) or 0)})
        yield rows + ([] if reference == integrator else [{**ref_meta, "com": 0.0, "nonrigid": 0.0, "start_frame": rows[-1]["start_frame"]}])


# --- the section ----------------------------------------------------------------------------
def _pct(x: float) -> str:
    return f"{100 * x:.1f} %"


def _ms(x) -> str:
    return "-" if x is None else f"{x:.1f}"


def choose(rows: list[dict], key: str) -> dict | None:
    """The cheapest row (first) within the targets of the finest, or None."""
    ok = [r for r in rows if r["com"] <= COM_TARGET and r["nonrigid"] <= NONRIGID_TARGET]
    return ok[0] if ok else None


def section(results: dict) -> str:
    out = [SECTION_TITLE, "",
           "`experiments/truth_convergence.py` (issue 24, part 1). The held-out scenes of section 10 built with the same "
           "placement code on finer meshes of the same object: the soft cheese that slides (22 deg az 0, mu 0.3, "
           "E = 20 kPa, 1.5 s) and the soft ball that bounces and rolls (25 deg, mu 0.3, 1 s). Backward Euler, full "
           "simulation (warp) on the GPU; the families marked with a viscosity have the material's Kelvin-Voigt damping "
           "(`licrom.Material.viscosity`, `licrom.full.damping`), the others none. Each study is measured against its finest member at matching frame times: "
           "final centre of mass distance over the object's size, and the non-rigid difference (each frame's best "
           "rigid fit removed, from the finest run's first contact). Across meshes the displacements are compared at "
           "common material points, the coarsest mesh's vertices (weighted by its lumped masses), each run "
           "interpolated barycentrically in the containing tet of its own mesh; across time steps on one mesh by "
           "`licrom.analysis.compare.nonrigid_error` on frames every 10 ms. Step time: wall time of the run over its steps "
           "(median of the steps beside it), with the mean Newton iterations per step.",
           "", f"Machine: {results.get('machine', '?')}.", ""]
    choices = []
    for family, fam in results["families"].items():
        out += [f"### {fam['label']}", ""]
        rows = fam.get("mesh", [])
        for mrows in [rows] + [fam["mesh_h"][k] for k in sorted(fam.get("mesh_h", {}), key=float, reverse=True)]:
            if not mrows:
                continue
            out += [f"Mesh, h = {1e3 * mrows[0]['dt']:g} ms, against the finest ({mrows[-1]['n_tets']} tets):", "",
                    "| resolution | tets | vertices | final COM / size | non-rigid difference | step ms (median) | Newton its/step | run s |",
                    "| --- | --- | --- | --- | --- | --- | --- | --- |"]
            for r in mrows:
                out.append(f"| {r['resolution']} | {r['n_tets']} | {r['n_vertices']} | {_pct(r['com'])} | {_pct(r['nonrigid'])} | "
                           f"{_ms(r['step_ms'])} ({_ms(r['median_step_ms'])}) | {r['newton_its']:.1f} | {r['wall_s']:.1f} |")
            out.append("")
        for key, integrator in _time_keys(fam):
            for res, trows in fam[key].items():
                ref = trows[-1]
                ref_integrator = ref.get("integrator", BE)
                # Backward Euler against itself keeps the headings of the first tables; any other pair names both.
                plain = integrator == ref_integrator == BE
                against = f"h = {1e3 * ref['dt']:g} ms" if plain else f"{INTEGRATOR_NAMES[ref_integrator]} at h = {1e3 * ref['dt']:g} ms"
                which = "" if plain else f", {INTEGRATOR_NAMES[integrator]},"
                out += [f"Time step{which} on the {trows[0]['n_tets']}-tet mesh (resolution {res}), against {against}:", "",
                        "| h (ms) | steps | final COM / size | non-rigid difference | step ms (median) | Newton its/step | unconverged steps | run s |",
                        "| --- | --- | --- | --- | --- | --- | --- | --- |"]
                for r in trows:
                    other = "" if r.get("integrator", BE) == integrator else f" ({INTEGRATOR_NAMES[r.get('integrator', BE)]})"
                    out.append(f"| {1e3 * r['dt']:g}{other} | {r['steps']} | {_pct(r['com'])} | {_pct(r['nonrigid'])} | "
                               f"{_ms(r['step_ms'])} ({_ms(r['median_step_ms'])}) | {r['newton_its']:.1f} | {r['unconverged']} | {r['wall_s']:.1f} |")
                out.append("")
        if not rows and fam.get("mesh_h"):  # only studies at other steps: the smallest step's
            rows = fam["mesh_h"][min(fam["mesh_h"], key=float)]
        m = choose(rows, "mesh") if rows else None
        choices.append((family, m, rows, [(integrator, fam[key]) for key, integrator in _time_keys(fam)] or [(BE, {})]))
    out += ["### Choice", "",
            f"Targets: final centre of mass within {_pct(COM_TARGET)} of the size and non-rigid deformation within "
            f"{_pct(NONRIGID_TARGET)} of the finest. Smallest mesh and largest step that meet both, measured:", ""]
    for family, m, rows, studies in choices:
        at = f" at h = {1e3 * rows[0]['dt']:g} ms" if rows else ""
        ms = (f"resolution {m['resolution']} ({m['n_tets']} tets){at}" if m and m is not rows[-1] else
              f"only the finest measured ({rows[-1]['n_tets']} tets)" if m else
              f"none short of the finest{at}" if rows else "not measured")
        steps = []
        for integrator, times in studies:
            trows = times[max(times, key=int)] if times else []
            # The reference row of a study against another integrator is not a candidate.
            candidates = [r for r in trows if r.get("integrator", BE) == integrator]
            t = choose(candidates, "time") if candidates else None
            ts = (f"h = {1e3 * t['dt']:g} ms" if t and t is not trows[-1] else
                  f"none above the smallest measured h ({1e3 * trows[-1]['dt']:g} ms)" if trows else "not measured")
            steps.append(f"time step{'' if integrator == BE else ' with ' + INTEGRATOR_NAMES[integrator]} {ts}")
        out.append(f"- {family}: mesh {ms}; {'; '.join(steps)}.")
    return "\n".join(out) + "\n"


def _time_keys(fam: dict) -> list[tuple[str, str]]:
    """``(results key, integrator)`` of a family's time-step studies: ``time`` (backward Euler), ``time_bdf2``, ..."""
    return [("time" if i == BE else f"time_{i}", i) for i in INTEGRATORS if fam.get("time" if i == BE else f"time_{i}")]


def machine() -> str:
    """The GPU (name and driver, from nvidia-smi) or else the CPU the runs are made on."""
    import shutil
    import subprocess

    if shutil.which("nvidia-smi"):
        q = subprocess.run(["nvidia-smi", "--query-gpu=name,driver_version", "--format=csv,noheader"], capture_output=True, text=True)
        if q.returncode == 0 and q.stdout.strip():
            name, _, driver = q.stdout.strip().splitlines()[0].partition(",")
            return f"{name.strip()} (driver {driver.strip()}), {platform.machine()}"
    return f"CPU {platform.processor() or platform.machine()}, {platform.node()}"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--work", type=Path, default=Path("out/truth_convergence"))
    p.add_argument("--docs", type=Path, default=Path("docs"))
    p.add_argument("--families", nargs="+", default=list(FAMILIES), choices=list(FAMILIES))
    p.add_argument("--studies", nargs="+", default=["mesh", "time"], choices=["mesh", "time"])
    p.add_argument("--resolutions", type=int, nargs="+", help="mesh study resolutions, coarsest first (default: per family)")
    p.add_argument("--mesh-time-step", type=float, help="s: the mesh study at this step (default the family's)")
    p.add_argument("--time-resolutions", type=int, nargs="+", help="meshes of the time-step study (default: per family)")
    p.add_argument("--time-steps", type=float, nargs="+", default=list(TIME_STEPS), help="s, largest first")
    p.add_argument("--integrator", choices=INTEGRATORS, default=BE, help="of the time-step study's runs")
    p.add_argument("--reference-integrator", choices=INTEGRATORS, help="of its reference at the smallest step (default: --integrator)")
    p.add_argument("--viscosity", type=float, default=0.0, help="Pa s: the material's Kelvin-Voigt damping (a family of its own in the results)")
    p.add_argument("--small", action="store_true", help="tiny meshes, 0.2 s (a smoke test on the CPU)")
    p.add_argument("--section-only", type=Path, nargs="+", metavar="RESULTS_JSON",
                   help="write the section from these results (families merged) and stop")
    a = p.parse_args()
    if a.section_only:
        merged: dict = {"families": {}}
        for path in a.section_only:
            r = json.loads(path.read_text())
            merged["machine"] = r.get("machine", "?")
            for family, studies in r["families"].items():  # one family's studies may come from several files
                fam = merged["families"].setdefault(family, {})
                for key, value in studies.items():
                    fam[key] = {**fam.get(key, {}), **value} if isinstance(value, dict) and key != "label" else value
        write_section(a.docs, section(merged), SECTION_TITLE)
        return
    results_path = a.work / "results.json"
    results = json.loads(results_path.read_text()) if results_path.exists() else {"families": {}}
    results["machine"] = machine()
    for family in a.families:
        spec = FAMILIES[family]
        duration = 0.2 if a.small else spec["duration"]
        label = spec["label"] if not a.viscosity else spec["label"].replace(")", f", viscosity {a.viscosity:g} Pa s)")
        fam = results["families"].setdefault(family + (f"_eta{a.viscosity:g}" if a.viscosity else ""), {"label": label})
        if "mesh" in a.studies:
            res = tuple(a.resolutions or (spec["small_resolutions"] if a.small else spec["resolutions"]))
            dt = a.mesh_time_step
            if dt is None or dt == spec["dt"]:
                fam["mesh"] = mesh_study(a.work, family, spec, res, duration, viscosity=a.viscosity)
            else:
                fam.setdefault("mesh_h", {})[f"{dt:g}"] = mesh_study(a.work, family, spec, res, duration, dt, a.viscosity)
            results_path.parent.mkdir(parents=True, exist_ok=True)
            results_path.write_text(json.dumps(results, indent=1))
        if "time" in a.studies:
            dts = tuple(a.time_steps[:2] if a.small else a.time_steps)
            key = "time" if a.integrator == BE else f"time_{a.integrator}"
            for r in a.time_resolutions or [spec["small_time_resolution"] if a.small else spec["time_resolution"]]:
                for rows in time_study(a.work, family, r, duration, dts, max(dts), a.integrator, a.reference_integrator, a.viscosity):
                    fam.setdefault(key, {})[str(r)] = rows
                    results_path.parent.mkdir(parents=True, exist_ok=True)
                    results_path.write_text(json.dumps(results, indent=1))
    text = section(results)
    print(text)
    if not a.small:
        write_section(a.docs, text, SECTION_TITLE)


if __name__ == "__main__":
    main()
