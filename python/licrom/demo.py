"""The whole pipeline at small scale on the built-in scene (``licrom demo``).

A cheese block is dropped onto inclines: full-space runs over a few friction
coefficients and slopes, a LiCROM subspace trained on them (in the body frame by
default: rigid motion exact, the learned modes hold the deformation), then the reduced model
run on slopes and friction coefficients it has not seen, next to the full
simulation of the same scenes. Everything lands in one folder: a summary table,
filmstrips, an error plot, loss curves and VTU series for ParaView.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass

import click

from ._io import atomic_path, make_dir
from .errors import ConfigError
from .rigid import check_frame

__all__ = ["DemoConfig", "run_demo"]


@dataclass(frozen=True)
class DemoConfig:
    """Settings of the demo. The defaults finish in minutes on two CPU cores.

    Attributes:
        out_dir: output folder.
        resolution: cheese mesh cells along its longest side (8 -> ~900 tets).
        train_slopes: incline angles of the training runs, degrees.
        train_frictions: Coulomb coefficients of the training runs.
        test_cases: held-out ``(slope deg, friction)`` pairs run full and reduced.
        drop_height: height of the lowest point above the incline at t = 0, m.
        steps: time steps per run (h = 10 ms).
        modes: learned modes r (12 affine modes are added in the world frame; 6 affine
            modes and the exact rigid motion in the body frame).
        frame: ``"body"`` or ``"world"`` (LiCROM's world-frame model, for comparison).
        epochs: training epochs (30 reach the POD bound of the same size on this data,
            see :func:`licrom.training.subspace_report`).
        cubature_points: cubature tets of the reduced model.
        device: warp device of the full simulations.
    """

    out_dir: str = "licrom-out/demo"
    resolution: int = 8
    train_slopes: tuple[float, ...] = (10.0, 30.0)
    train_frictions: tuple[float, ...] = (0.1, 0.4, 0.7)
    test_cases: tuple[tuple[float, float], ...] = ((20.0, 0.25), (20.0, 0.55))
    drop_height: float = 0.01
    steps: int = 150
    modes: int = 8
    frame: str = "body"
    epochs: int = 30
    cubature_points: int = 400
    device: str = "cpu"

    def __post_init__(self) -> None:
        # Checked here, not where each is used, so a bad value fails before minutes of simulation.
        for name in ("resolution", "steps", "modes", "epochs", "cubature_points"):
            value = getattr(self, name)
            if not isinstance(value, int) or value < (4 if name == "resolution" else 1):
                raise ConfigError(f"DemoConfig.{name} must be an integer >= {4 if name == 'resolution' else 1}, got {value!r}")
        check_frame(self.frame, "DemoConfig.frame")
        if not self.drop_height >= 0.0:
            raise ConfigError(f"DemoConfig.drop_height (m) must be >= 0, got {self.drop_height!r}")
        if not self.train_slopes or not self.train_frictions or not self.test_cases:
            raise ConfigError("DemoConfig needs at least one training slope, training friction and test case")
        for slope, mu in self.test_cases:
            if slope in self.train_slopes and mu in self.train_frictions:
                raise ConfigError(f"test case (slope {slope}, mu {mu}) is in the training set; pick a held-out pair")


def _scene(config: DemoConfig):
    from .dataset import report_dataset_spec

    # The report's cheese material and contact stiffnesses.
    return report_dataset_spec("cheese", resolution=config.resolution).base_scene


def run_demo(config: DemoConfig = DemoConfig(), progress: bool = True) -> dict:
    """Run the pipeline; return the summary (also written as ``summary.json``/``summary.md``).

    ``progress=False`` hides the progress bars; the stage lines and the summary are printed.
    """
    from . import meshes
    from .compare import run_comparison
    from .cubature import Cubature
    from .dataset import generate_dataset
    from .model import ModelConfig
    from .placement import drop_state, initial_state_on_plane
    from .render import filmstrip, plot_errors, write_vtu_series
    from .scene import Plane
    from .training import TrainConfig, train

    out = make_dir(config.out_dir)
    t0 = time.perf_counter()
    say = click.echo

    mesh = meshes.cheese(resolution=config.resolution)
    mesh.save(out / "cheese.vtu")
    base = _scene(config)
    rest_state = drop_state(mesh, base.material.density, height=config.drop_height)
    say(f"[1/4] cheese mesh: {mesh.n_vertices} vertices, {mesh.n_tets} tets")

    say(f"[2/4] full-space training runs: slopes {config.train_slopes} deg x mu {config.train_frictions}")
    t = time.perf_counter()
    generate_dataset(
        out / "data", mesh, base, frictions=config.train_frictions, planes=config.train_slopes,
        initial_states=[rest_state], steps=config.steps, device=config.device, progress=progress,
        initial_frame="plane", name="demo",
    )
    t_data = time.perf_counter() - t

    say(f"[3/4] training r = {config.modes} learned modes in the {config.frame} frame, {config.epochs} epochs")
    t = time.perf_counter()
    model = train(
        out / "data", out / "model.lcm",
        TrainConfig(epochs=config.epochs, progress=progress, device="auto"),
        ModelConfig(latent_dim=config.modes, frame=config.frame),
    )
    t_train = time.perf_counter() - t

    say(f"[4/4] held-out scenes, full vs reduced: {list(config.test_cases)}")
    comparisons = {}
    rows = []
    cubature = Cubature.naive(mesh, config.cubature_points)
    for slope, mu in config.test_cases:
        plane = Plane.incline(slope, mu)
        scene = base.replace(planes=(plane,), initial=initial_state_on_plane(rest_state, plane, mesh, base.material.density))
        label = f"slope {slope:g} deg, mu {mu:g}"
        cmp, full, reduced = run_comparison(model, scene, mesh, steps=config.steps, device=config.device,
                                            progress=progress, cubature=cubature)
        tag = f"slope{slope:g}_mu{mu:g}"
        comparisons[label] = cmp
        filmstrip([full, reduced], ["full", "reduced"], out / f"filmstrip_{tag}.png", title=label)
        write_vtu_series(full, out / f"vtu_{tag}" / "full", "full")
        write_vtu_series(reduced, out / f"vtu_{tag}" / "reduced", "reduced")
        rows.append({"scene": label, "tan(slope)": math.tan(math.radians(slope)), **cmp.summary()})
        say(f"\n{label}\n{cmp.table()}\n")
    plot_errors(comparisons, out / "errors.png")

    summary = {
        "mesh": {"vertices": mesh.n_vertices, "tets": mesh.n_tets},
        "config": asdict(config),
        "seconds": {"full_runs": t_data, "training": t_train, "total": time.perf_counter() - t0},
        "model": {"learned_modes": config.modes, "frame": config.frame, "cubature_points": cubature.count},
        "cases": rows,
    }
    for name, text in (("summary.json", json.dumps(summary, indent=2)), ("summary.md", _markdown(summary))):
        with atomic_path(out / name) as tmp:
            tmp.write_text(text)
    say(_markdown(summary))
    say(f"outputs in {out.resolve()}:")
    for p in sorted(out.iterdir()):
        say(f"  {p.name}")
    return summary


def _markdown(summary: dict) -> str:
    head = ("| scene | mean rel. error | non-rigid error | peak deformation / size full / reduced | "
            "rotation full / reduced | final COM error / size | full | reduced | full ms/step | reduced ms/step | speedup |\n")
    head += "|---|---|---|---|---|---|---|---|---|---|---|\n"
    for r in summary["cases"]:
        head += (
            f"| {r['scene']} | {100 * r['mean_error']:.2f} % | {100 * r['nonrigid_error']:.2f} % | "
            f"{100 * r['peak_deformation_full']:.2f} % / {100 * r['peak_deformation_reduced']:.2f} % | "
            f"{r['rotation_full']:.0f} deg / {r['rotation_reduced']:.0f} deg | {100 * r['final_com_error']:.2f} % | "
            f"{'slides' if r['slid_full'] else 'sticks'} | {'slides' if r['slid_reduced'] else 'sticks'} | "
            f"{r['full_step_ms']:.2f} | {r['reduced_step_ms']:.3f} | {r['speedup']:.0f}x |\n"
        )
    s = summary["seconds"]
    model = summary["model"]
    extra = "+12 affine" if model["frame"] == "world" else "+6 symmetric affine, rigid motion exact"
    return (
        f"# licrom demo\n\ncheese: {summary['mesh']['tets']} tets; {model['frame']}-frame model, r = {model['learned_modes']} ({extra}), "
        f"{model['cubature_points']} cubature tets\n\n{head}\n"
        f"full runs {s['full_runs']:.0f} s, training {s['training']:.0f} s, total {s['total']:.0f} s\n"
    )
