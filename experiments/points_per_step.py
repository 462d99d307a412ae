"""More points a training step for fewer epochs on a large mesh (issue 24): the 104k-tet ball.

    python experiments/points_per_step.py --work out/points generate --jobs 6        # the runs, on the GPU
    python experiments/points_per_step.py --work out/points train --points 8192 --epochs 300
    python experiments/points_per_step.py --work out/points all --variants 2048:300 8192:300 32768:300
    python experiments/points_per_step.py --work out/points all --variants 2048:300:width=1024 2048:300:lr=0.01 2048:300:fourier=128
    python experiments/points_per_step.py --work out/points all --variants 2048:300:seed=1 2048:300:seed=2 2048:300:seed=3

On a 100k-tet mesh a training step's 2048 points (``TrainConfig.points_per_frame``) fall one to every ten vertices,
and the large-mesh defaults need 800-1200 epochs to bring the learned subspace near its POD (docs/results.md,
sections 35-36). A step is bound by its operator calls, not by its points (section 41), so more points a step cost
nothing. This study asks whether they buy the epochs back.

1. **generate**: the ball family of ``scale_end_to_end.py --family sphere`` at its converged physics (BDF2,
   h = 0.5 ms, 400 Pa s; 103536 tets): its 4 training runs (impact frames as ``licrom train`` gets them), the
   family's held-out roll and the first drawn roll of ``more_scenes.py``, ``--jobs`` at once (cached);
2. **train**: ``licrom.train`` with its defaults except ``points_per_frame`` and ``epochs`` (and no extension, so that
   every variant stops at the epochs it was given; a variant may also set ``seed``, ``lr``, ``width`` (the field's) or
   ``fourier`` (its Fourier features)), then ``ReducedSim(model, scene=...)`` on each held-out run
   against its full run: the learned subspace against POD(r) of the validation frames, the non-rigid error, the
   final centre of mass, stick/slip, the estimate and the step time (one CPU thread). One variant a process:
   ``all`` starts one process per variant at once (they share the GPU), writes ``--work/points.json`` and fails where
   a variant's process did.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import licrom
from licrom import Trajectory
from licrom.data.dataset import IMPACT_WINDOW, local_devices
from licrom.executors import run_tasks
from licrom.learn.model.config import ModelConfig
from licrom.learn.training import TrainConfig

sys.path.insert(0, str(Path(__file__).resolve().parent))
import scale_end_to_end as see


def family(args):
    ns = argparse.Namespace(family="sphere", resolution=see.DEFAULT_RESOLUTION["sphere"], small=args.small,
                            time_step=0.0005, integrator="bdf2", viscosity=400.0, held=1, drawn=1)
    if args.small:
        ns.resolution = 5
    fam = see.study_family(ns)
    return fam, see.held_cases(ns, fam)


def run_files(args):
    """Training and held-out runs generated (``--jobs`` at once on ``--device``) or found cached under ``--work/runs``."""
    fam, held = family(args)
    runs = Path(args.work) / "runs"
    runs.mkdir(parents=True, exist_ok=True)
    train = [see.recording_failures(c) for c in fam.training]
    cases = train + held
    devices = local_devices(args.device, args.jobs)
    steps = 20 if args.small else fam.steps
    tasks = [(c, fam.mesh, steps, devices[i % len(devices)], runs, fam.record_every, 0.0 if c.held_out else IMPACT_WINDOW)
             for i, c in enumerate(cases)]
    done = dict(run_tasks(see.generate, tasks, jobs=args.jobs))
    files = [done[i][0] for i in range(len(cases))]
    return fam, held, files[: len(train)], files[len(train):], steps


VARIANT_OPTIONS = ("seed", "lr", "width", "fourier")
"""What a variant may set beside its points and epochs (``POINTS:EPOCHS:name=value,...``)."""


def variant_tag(args) -> str:
    extra = "".join(f"_{k}{getattr(args, k)}" for k in VARIANT_OPTIONS if getattr(args, k) is not None)
    return f"{args.points}_{args.epochs}{extra}"


def train_variant(args) -> dict:
    fam, held, train_files, held_files, steps = run_files(args)
    tag = variant_tag(args)
    path = Path(args.work) / "models" / f"ball_{tag}.lcm"
    path.parent.mkdir(parents=True, exist_ok=True)
    given = {k: v for k, v in (("seed", args.seed), ("lr", args.lr)) if v is not None}
    cfg = TrainConfig(progress=False, points_per_frame=args.points, epochs=args.epochs, extension=0.0,
                      device=args.device if args.device == "cpu" else "auto", **given)
    field = {k: v for k, v in (("field_width", args.width), ("fourier_features", args.fourier)) if v is not None}
    t0 = time.perf_counter()
    model = licrom.train([str(p) for p in train_files], path, cfg, ModelConfig(**field) if field else None)
    md = model.metadata
    out = {"tag": tag, "points": args.points, "epochs": args.epochs, **{k: getattr(args, k) for k in VARIANT_OPTIONS}, "train_s": time.perf_counter() - t0, "r": int(model.n_learned),
           "fit_s": md.get("fit_seconds"), "s_per_epoch": md.get("mean_train_seconds_per_epoch"),
           "subspace": md.get("subspace"), "cubature": {k: md.get("cubature", {}).get(k) for k in ("count", "fit_error")},
           "final": md.get("final", {}), "held_out": []}
    see.log(f"{tag}: trained in {out['train_s']:.0f} s, {out['s_per_epoch']} s an epoch, subspace {out['subspace']}")
    for case, p in zip(held, held_files):
        out["held_out"].append(see.reduced_stage(model, case, Trajectory.load(p), steps, record_every=fam.record_every))
    (Path(args.work) / f"variant_{tag}.json").write_text(json.dumps(out, indent=1, default=str))
    return out


def all_variants(args) -> None:
    run_files(args)
    procs, logs = [], []
    for v in args.variants:
        points, epochs, *rest = v.split(":")
        extra = [f"--{kv.split('=')[0]}={kv.split('=')[1]}" for kv in ",".join(rest).split(",") if kv]
        cmd = [sys.executable, __file__, "--work", args.work, "--device", args.device, *(["--small"] if args.small else []),
               "train", "--points", points, "--epochs", epochs, *extra]
        env = {**os.environ, "OMP_NUM_THREADS": str(max(1, (os.cpu_count() or 2) // len(args.variants)))}
        logs.append(open(Path(args.work) / f"train_{v.replace(':', '_').replace('=', '').replace(',', '_')}.log", "w"))
        procs.append(subprocess.Popen(cmd, env=env, stdout=logs[-1], stderr=subprocess.STDOUT))
    rcs = [p.wait() for p in procs]
    for f in logs:
        f.close()
    res = [json.loads(p.read_text()) for p in sorted(Path(args.work).glob("variant_*.json"))]
    (Path(args.work) / "points.json").write_text(json.dumps({"rcs": rcs, "variants": res}, indent=1))
    for r in res:
        rows = ", ".join(f"{h['name']} {100 * h['nonrigid_error']:.1f} % / {100 * h['com_error']:.2f} %" for h in r["held_out"])
        print(f"{r['tag']}: {r['s_per_epoch']:.2f} s an epoch, subspace {r['subspace']['ratio']:.3f}x POD; {rows}")
    if any(rcs):
        sys.exit(f"a variant's training failed (return codes {rcs}); see --work's train_*.log")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--work", default="out/points")
    ap.add_argument("--device", default="cuda", choices=("cuda", "cpu"))
    ap.add_argument("--jobs", type=int, default=6, help="full runs at once")
    ap.add_argument("--small", action="store_true", help="the 5-resolution ball, 20 steps, on the CPU: a smoke test")
    sub = ap.add_subparsers(dest="stage", required=True)
    sub.add_parser("generate")
    t = sub.add_parser("train")
    t.add_argument("--points", type=int, required=True)
    t.add_argument("--epochs", type=int, required=True)
    t.add_argument("--seed", type=int, help="TrainConfig.seed (default: its own)")
    t.add_argument("--lr", type=float, help="TrainConfig.lr")
    t.add_argument("--width", type=int, help="ModelConfig.field_width")
    t.add_argument("--fourier", type=int, help="ModelConfig.fourier_features")
    a = sub.add_parser("all")
    a.add_argument("--variants", nargs="+", default=["2048:300", "8192:300", "32768:300"], metavar="POINTS:EPOCHS[:name=value,...]",
                   help=f"one training each; name is one of {', '.join(VARIANT_OPTIONS)}")
    args = ap.parse_args()
    if args.small:
        args.device = "cpu"
    {"generate": run_files, "train": train_variant, "all": all_variants}[args.stage](args)


if __name__ == "__main__":
    main()
