"""What a user does with a run at 104k tets, timed: save and load it, export it, picture it (results section 35).

    python experiments/scale_outputs.py --model out/ball100k/long/sphere.lcm --work out/scale_outputs
    python experiments/scale_outputs.py --small --work /tmp/scale_outputs   # a tiny full run, seconds

Issue 24 asks that whatever crawls at 100k tets be made to work and timed; the trajectory files, export and
rendering had not been. With ``--model`` (a model of the ball family of ``experiments/scale_end_to_end.py
--family sphere``, on ``meshes.sphere(resolution=32)``: 103536 tets, 19789 vertices) it runs ``ReducedSim(model,
scene=held_out_scene)`` on this machine's CPU for the scene's 2000 steps (a frame every 20), then times each output
of that trajectory: ``Trajectory.save`` (float32) and ``Trajectory.load``, ``licrom.export.write_vtu_series``,
``licrom.export.write_usd``, ``licrom.render.filmstrip`` (6 frames) and ``licrom.render.animation`` (the GIF of at
most 60 frames) with each renderer available (PyVista, matplotlib), with the file sizes. ``--small``: the same on a
tiny full run (a 4-resolution ball, 40 steps). Rows go to ``--work/outputs.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import time
import warnings
from pathlib import Path

import body_frame_experiments as bfe
import licrom
from licrom._io import atomic_path
from licrom.viz.render import pyvista_unavailable


def _size(path: Path) -> int:
    return sum(f.stat().st_size for f in path.rglob("*") if f.is_file()) if path.is_dir() else path.stat().st_size


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", type=Path, help="a model of the ball family at --resolution (its held-out scene is run)")
    ap.add_argument("--resolution", type=int, default=32, help="meshes.sphere resolution of the model's mesh")
    ap.add_argument("--small", action="store_true", help="a tiny full run in place of the model's reduced run")
    ap.add_argument("--work", type=Path, default=Path("out/scale_outputs"))
    args = ap.parse_args()
    if (args.model is None) == (not args.small):
        ap.error("give --model or --small")
    bfe.SPHERE_RESOLUTION = 4 if args.small else args.resolution
    fam = bfe.with_physics(bfe.sphere_family(False), 0.0005, "bdf2", 400.0)
    case = fam.held_out[0]
    args.work.mkdir(parents=True, exist_ok=True)
    rows: list[dict] = []

    def timed(stage: str, fn, out: Path | None = None) -> object:
        t0 = time.perf_counter()
        result = fn()
        rows.append({"stage": stage, "seconds": time.perf_counter() - t0, "bytes": None if out is None else _size(out)})
        print(f"{stage}: {rows[-1]['seconds']:.2f} s" + ("" if out is None else f", {rows[-1]['bytes'] / 2**20:.1f} MiB"), flush=True)
        return result

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", licrom.LicromWarning)
        if args.small:
            traj = timed("full run (40 steps)", lambda: licrom.FullSim(fam.mesh, case.scene, device="cpu").run(40, record_every=2))
        else:
            model = licrom.Model.load(args.model)
            sim = timed("ReducedSim(model, scene=...) setup", lambda: licrom.ReducedSim(model, scene=case.scene))
            traj = timed(f"reduced run ({fam.steps} steps, a frame every {fam.record_every})",
                         lambda: sim.run(fam.steps, record_every=fam.record_every))
    run_file = args.work / "run.npz"
    timed("Trajectory.save (float32)", lambda: traj.save(run_file), run_file)
    traj = timed("Trajectory.load", lambda: licrom.Trajectory.load(run_file))
    timed("export.write_vtu_series", lambda: licrom.export.write_vtu_series(traj, args.work / "vtu"), args.work / "vtu")
    timed("export.write_usd", lambda: licrom.export.write_usd(traj, args.work / "run.usdc"), args.work / "run.usdc")
    renderers = ["matplotlib"] if pyvista_unavailable() else ["pyvista", "matplotlib"]
    for renderer in renderers:
        png, gif = args.work / f"strip_{renderer}.png", args.work / f"run_{renderer}.gif"
        timed(f"render.filmstrip ({renderer}, 6 frames)", lambda r=renderer, p=png: licrom.render.filmstrip([traj], ["reduced"], p, renderer=r), png)
        timed(f"render.animation ({renderer}, GIF of up to 60 frames)",
              lambda r=renderer, p=gif: licrom.render.animation([traj], ["reduced"], p, renderer=r), gif)
    result = {"tets": int(fam.mesh.n_tets), "vertices": int(fam.mesh.n_vertices), "frames": int(traj.n_frames),
              "cpus": os.cpu_count(), "date": time.strftime("%Y-%m-%d"), "rows": rows}
    with atomic_path(args.work / "outputs.json") as tmp:
        Path(tmp).write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
