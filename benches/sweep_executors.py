"""Wall time of one dataset sweep on each executor, and a check that they write the same files.

The sweep: a cheese (``--resolution``) dropped onto ``--slopes`` x ``--frictions`` inclines,
``--steps`` full-space steps each (8 runs by default). It runs

- ``local``: one run after the other in this process;
- ``local --jobs N`` for each N of ``--jobs``: a pool of N processes;
- ``ray``: one Ray task per run on a local Ray cluster of ``--ray-cpus`` CPUs started here
  (its start-up is timed apart; on a standing cluster a sweep does not pay it);

each into its own folder, prints the wall times (and the runs' own times summed, which over the
wall time says how many ran at once), and compares every file with the serial run's, array by
array and bit for bit (the per-step wall-clock times left out).

    python benches/sweep_executors.py --resolution 8 --steps 40
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np
from licrom import meshes
from licrom.data.dataset import generate_dataset, load_manifest
from licrom.data.presets import report_dataset_spec
from licrom.scene.placement import drop_state


def contents(out: Path) -> dict[str, dict[str, bytes]]:
    """Every trajectory file's arrays (wall-clock step times left out), as bytes, by file name."""
    result = {}
    for entry in load_manifest(out)["trajectories"]:
        with np.load(out / entry["file"], allow_pickle=False) as data:
            result[entry["file"]] = {k: data[k].tobytes() for k in data.files if k != "step_seconds"}
    return result


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--resolution", type=int, default=8, help="cheese resolution")
    ap.add_argument("--steps", type=int, default=40, help="full-space steps per run")
    ap.add_argument("--frictions", type=float, nargs="+", default=[0.1, 0.3, 0.5, 0.9], help="Coulomb coefficients")
    ap.add_argument("--slopes", type=float, nargs="+", default=[10.0, 30.0], help="incline angles, degrees")
    ap.add_argument("--jobs", type=int, nargs="+", default=[2], help="process counts of the local pool")
    ap.add_argument("--ray-cpus", type=int, default=len(os.sched_getaffinity(0)), help="CPUs of the local Ray cluster")
    ap.add_argument("--no-ray", action="store_true", help="leave Ray out")
    ap.add_argument("--work", type=Path, default=None, help="folder for the data sets (default: a temporary one)")
    args = ap.parse_args()

    spec = report_dataset_spec("cheese", resolution=args.resolution)
    mesh = meshes.cheese(resolution=args.resolution)
    state = drop_state(mesh, spec.base_scene.material.density, height=0.02, rotation=(0.15, 0.1, 0.0))
    runs = len(args.frictions) * len(args.slopes)
    print(f"sweep: cheese {mesh.n_vertices} vertices, {mesh.n_tets} tets; {runs} runs x {args.steps} steps on the CPU; "
          f"{len(os.sched_getaffinity(0))} cores available")

    with tempfile.TemporaryDirectory() as tmp:
        work = args.work or Path(tmp)

        def sweep(label: str, **kw) -> float:
            out = work / label.replace(" ", "_")
            start = time.perf_counter()
            generate_dataset(out, mesh, spec.base_scene, frictions=args.frictions, planes=args.slopes, initial_states=[state],
                             steps=args.steps, initial_frame="plane", progress=False, device="cpu", **kw)
            seconds = time.perf_counter() - start
            m = load_manifest(out)
            assert m["complete"] and len(m["trajectories"]) == runs
            # The runs' own wall times summed, over the sweep's: how many ran at once, on average.
            busy = sum(e["seconds"] for e in m["trajectories"])
            same = "" if label == "local" else ("  same files" if contents(out) == reference else "  FILES DIFFER")
            print(f"{label:<18} {seconds:8.2f} s   runs {busy:7.2f} s in all, {busy / seconds:4.2f} at a time{same}")
            if same.strip() == "FILES DIFFER":
                raise SystemExit(f"{label} wrote other files than the serial run")
            return seconds

        sweep("local")
        reference = contents(work / "local")
        for jobs in args.jobs:
            sweep(f"local jobs {jobs}", jobs=jobs)
        if not args.no_ray:
            import ray

            start = time.perf_counter()
            ray.init(address="local", num_cpus=args.ray_cpus, include_dashboard=False, log_to_driver=False)
            print(f"{'ray start-up':<18} {time.perf_counter() - start:8.2f} s  (local cluster, {args.ray_cpus} CPUs)")
            try:
                sweep("ray", executor="ray")
            finally:
                ray.shutdown()


if __name__ == "__main__":
    main()
