"""The whole pipeline at small scale on a scene file (``licrom demo``, ``licrom demo --scene my.toml``).

The built-in scene (``licrom/scenes/demo.toml``) drops a cheese block onto inclines:
full-space runs over the scene's sweep of friction coefficients and slopes, a LiCROM
subspace trained on them (in the body frame by default: rigid motion exact, the learned
modes hold the deformation), then the reduced model run on the scene's held-out slopes and
friction coefficients, next to the full simulation of the same scenes. Everything lands in
one folder (:mod:`licrom.viz.report`'s layout): ``report.html`` and a summary table with each number's
meaning, target and verdict, filmstrips and animations from a fixed camera (PyVista, or matplotlib
without it), an error plot, loss curves, the full and reduced runs
(``runs/*.npz``, for ``licrom export``) and VTU series for ParaView with contact forces,
non-rigid deformation and the planes.
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path

import click

from .._io import make_dir
from ..data.scene_file import SceneFile, load_scene
from ..errors import ConfigError
from ..rigid import check_frame
from ..scene.sweep import held_out_pairs, in_sweep, sweep_axis

__all__ = ["DemoConfig", "run_demo"]


TRAIN_DEVICES = ("cpu", "auto", "cuda")
"""Accepted values of :attr:`DemoConfig.train_device`: those :attr:`licrom.TrainConfig.device` checks, named again here
because importing the training package loads torch, which every command line call would then pay for."""


@dataclass(frozen=True)
class DemoConfig:
    """Settings of the demo. The defaults finish in under a minute on two CPU cores once warp's kernels are compiled.

    The training budget (r = 12, 10 epochs, 64 encoder points, one torch thread) was chosen by
    measurement on the built-in scene (docs/results.md, section 11, "The demo's budget"): 30 epochs at
    r = 8 took 97-127 s of training and missed the 10 % target on one held-out scene (10.5 %); 10 epochs
    at r = 12 with 64 encoder points train in under a third of the time at 5.6 and 7.1 % non-rigid
    error (the encoder's points change no mode under the POD objective); fewer epochs, fewer field points
    or larger batches stayed near or above 10 %. One torch thread: on two cores shared with other
    work, torch's two threads made an epoch 4-6 times slower than one.

    Attributes:
        out_dir: output folder.
        scene: a built-in scene name or the path of a scene file: the object, material,
            training sweep, initial state, time step and the held-out scenes (``[[held_out]]``)
            run full and reduced (see :mod:`licrom.data.scene_file`).
        resolution: mesh resolution of a procedural object, overriding the scene's
            (None: the scene's; the built-in scene's cheese at 8 has ~900 tets).
        steps: time steps per run, overriding the scene's (None: the scene's).
        modes: learned modes r (12 affine modes are added in the world frame; 6 affine
            modes and the exact rigid motion in the body frame).
        frame: ``"body"`` or ``"world"`` (LiCROM's world-frame model, for comparison).
        epochs: training epochs (10 bring the learned modes within 1.05x of the POD bound of the
            same size on this data, see :func:`licrom.learn.training.subspace_report`).
        cubature_points: most cubature tets of the reduced model: the cubature that training
            fits to the training runs' forces (:attr:`licrom.TrainConfig.cubature_points`), which
            stops earlier once it matches them.
        device: warp device of the full simulations.
        train_device: torch device of the training (:attr:`licrom.TrainConfig.device`): the CPU, where the
            budget above was measured and where it trains as fast as a GPU does at this size (on an NVIDIA
            H200 the same 10 epochs took 17 s, against 22 s on two CPU cores, and, being another draw of the
            training points, landed 7.8 and 11.4 % non-rigid error: docs/results.md section 44); ``"auto"``
            or ``"cuda"`` to train on a GPU.
        train_threads: CPU threads torch trains with (:attr:`licrom.TrainConfig.num_threads`; None:
            torch's default, every core).
        blas_threads: threads of numpy's and scipy's BLAS (their wheels' OpenBLAS) for the whole demo
            (None: the library's default, every core). Its matrices are small (the POD's SVD, about
            800 x 800, is the largest): on two shared cores a second thread only spins while it waits,
            an SVD took 2.7-3.9 s of CPU with two threads and 0.2 s with one.
    """

    out_dir: str = "licrom-out/demo"
    scene: str = "demo"
    resolution: int | None = None
    steps: int | None = None
    modes: int = 12
    frame: str = "body"
    epochs: int = 10
    cubature_points: int = 400
    device: str = "cpu"
    train_device: str = "cpu"
    train_threads: int | None = 1
    blas_threads: int | None = 1

    def __post_init__(self) -> None:
        # Checked here, not where each is used, so a bad value fails before minutes of simulation.
        for name in ("resolution", "steps", "modes", "epochs", "cubature_points", "train_threads", "blas_threads"):
            value = getattr(self, name)
            if name in ("resolution", "steps", "train_threads", "blas_threads") and value is None:
                continue
            if isinstance(value, bool) or not isinstance(value, int) or value < (4 if name == "resolution" else 1):
                raise ConfigError(f"DemoConfig.{name} must be an integer >= {4 if name == 'resolution' else 1}, got {value!r}")
        check_frame(self.frame, "DemoConfig.frame")
        if self.train_device not in TRAIN_DEVICES:
            raise ConfigError(f"DemoConfig.train_device must be one of {', '.join(map(repr, TRAIN_DEVICES))}, got {self.train_device!r}")


def demo_scene(config: DemoConfig) -> SceneFile:
    """The scene file of the demo with the config's overrides, checked for a held-out scene outside the training sweep.

    Raises:
        ConfigError: no held-out scene, or one that is a training run.
    """
    scene = load_scene(config.scene).overridden(resolution=config.resolution, steps=config.steps)
    if not scene.held_out:
        raise ConfigError(f"the demo needs held-out scenes: add [[held_out]] tables (slope, friction) to scene '{scene.name}'")
    first = scene.scene.planes[0]
    train_slopes = sweep_axis(scene.slopes, first.slope_deg)
    train_frictions = scene.frictions or tuple(dict.fromkeys(p.friction for p in scene.scene.planes))
    for slope, mu in held_out_pairs(((h.slope, h.friction) for h in scene.held_out), first):
        if in_sweep((slope, mu), train_slopes, train_frictions):
            raise ConfigError(f"held-out scene (slope {slope:g}, mu {mu:g}) is in the training sweep of scene '{scene.name}'; pick a held-out pair")
    return scene


def run_demo(config: DemoConfig = DemoConfig(), progress: bool = True) -> dict:
    """Run the pipeline; return the summary (also written as ``summary.json``, ``summary.md`` and ``report.html``,
    :mod:`licrom.viz.report`).

    ``progress=False`` hides the progress bars; the stage lines and the summary are printed.
    """
    from .._blas import blas_threads

    with blas_threads(config.blas_threads):
        return _run_demo(config, progress)


def _run_demo(config: DemoConfig, progress: bool) -> dict:
    from ..analysis.compare import run_comparison
    from ..learn.model import ModelConfig
    from ..learn.training import TrainConfig, train
    from ..records.export import write_vtu_series
    from ..viz.render import pick_renderer
    from ..viz.report import Case, case_tag, write_report

    scene_file = demo_scene(config)
    out = make_dir(config.out_dir)
    # Whether PyVista renders here (a test picture in a subprocess, about 2 s) is asked beside the simulations:
    # the answer is needed at [4/4]. The thread only waits for the subprocess.
    renderer_check = ThreadPoolExecutor(1, thread_name_prefix="licrom-render-check")
    picked = renderer_check.submit(pick_renderer)
    renderer_check.shutdown(wait=False)
    t0, c0 = time.perf_counter(), time.process_time()
    cpu: dict[str, float] = {}  # CPU seconds of each stage (this process, every thread), beside the wall seconds
    say = click.echo

    mesh = scene_file.object.build()
    object_name = Path(scene_file.object.mesh).stem
    mesh.save(out / f"{object_name}.vtu")
    say(f"[1/4] {scene_file.object.describe()} mesh: {mesh.n_vertices} vertices, {mesh.n_tets} tets (scene {scene_file.name})")

    spec = scene_file.dataset_spec(mesh)
    say(f"[2/4] full-space training runs: {spec.n_trajectories} runs, slopes {list(scene_file.slopes or ())} deg x mu {list(scene_file.frictions or ())}")
    t, c = time.perf_counter(), time.process_time()
    spec.generate(out / "data", device=config.device, progress=progress)
    t_data, cpu["full_runs"] = time.perf_counter() - t, time.process_time() - c

    say(f"[3/4] training r = {config.modes} learned modes in the {config.frame} frame, {config.epochs} epochs")
    t, c = time.perf_counter(), time.process_time()
    model = train(
        out / "data", out / "model.lcm",
        # 64 encoder points (128 to validate), not 512: the POD objective trains the field, which makes the modes,
        # apart from the encoder, so the modes and the held-out errors are the same, and an epoch takes half the time.
        TrainConfig(epochs=config.epochs, progress=progress, device=config.train_device, cubature_points=config.cubature_points,
                    num_threads=config.train_threads, encoder_points=64, val_points=128),
        ModelConfig(latent_dim=config.modes, frame=config.frame),
    )
    t_train, cpu["training"] = time.perf_counter() - t, time.process_time() - c

    cases = scene_file.cases(mesh)
    say(f"[4/4] held-out scenes, full vs reduced: {[label for label, _ in cases]}")
    renderer, why_not = picked.result()
    if why_not:
        say(f"pictures: {why_not}; drawing them with matplotlib")
    t, c = time.perf_counter(), time.process_time()
    compared: list[Case] = []
    cubature = model.cubature  # fitted to the training poses by train(), the reduced runs' default
    for label, scene in cases:
        cmp, full, reduced = run_comparison(model, scene, mesh, steps=scene_file.steps, device=config.device,
                                            progress=progress)
        tag = case_tag(label, scene, [c.tag for c in compared])
        compared.append(Case(label, tag, cmp, full, reduced))
        write_vtu_series(full, out / f"vtu_{tag}" / "full", "full")
        write_vtu_series(reduced, out / f"vtu_{tag}" / "reduced", "reduced")
        say(f"\n{label}\n{cmp.table()}\n")
    seconds = {"full_runs": t_data, "training": t_train, "held_out": time.perf_counter() - t}
    cpu["held_out"] = time.process_time() - c
    extra = "+12 affine" if config.frame == "world" else "+6 symmetric affine, rigid motion exact"
    description = (f"{scene_file.object.describe()}: {mesh.n_tets} tets; {config.frame}-frame model, r = {model.n_learned} ({extra}), "
                   f"{cubature.count} cubature tets fitted by the training")
    t_report, c_report = time.perf_counter(), time.process_time()
    summary = write_report(
        compared, out, "licrom demo", description, renderer,
        extra={"mesh": {"object": scene_file.object.describe(), "vertices": mesh.n_vertices, "tets": mesh.n_tets},
               "config": {**asdict(config), "scene": scene_file.source}, "seconds": seconds, "cpu_seconds": dict(cpu),
               "model": {"learned_modes": model.n_learned, "frame": config.frame, "cubature_points": cubature.count}},
        footer=f"full runs {t_data:.0f} s, training {t_train:.0f} s, held-out runs {seconds['held_out']:.0f} s",
    )
    say((out / "summary.md").read_text())
    say(f"outputs in {out.resolve()} (open report.html):")
    for p in sorted(out.iterdir()):
        say(f"  {p.name}")
    cpu["report"] = time.process_time() - c_report
    say(f"demo finished in {time.perf_counter() - t0:.0f} s (full runs {t_data:.0f} s, training {t_train:.0f} s, "
        f"held-out runs {seconds['held_out']:.0f} s, report {time.perf_counter() - t_report:.0f} s); "
        f"CPU time {time.process_time() - c0:.0f} s (full runs {cpu['full_runs']:.0f} s, training {cpu['training']:.0f} s, "
        f"held-out runs {cpu['held_out']:.0f} s, report {cpu['report']:.0f} s)")
    return summary
