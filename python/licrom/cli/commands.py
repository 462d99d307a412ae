"""The ``licrom`` command line.

Each subcommand is a thin wrapper over the Python API; errors of the
:class:`~licrom.errors.LicromError` family are printed as one line and exit
with status 2 instead of a traceback.
"""

from __future__ import annotations

import math
import sys
import time
import warnings
from pathlib import Path

import click

from ..data.scene_file import builtin_scenes
from ..errors import ConfigError, LicromError, LicromWarning
from .demo import DemoConfig

__all__ = ["cli", "main"]


# An incline angle: steeper than 90 degrees would be a plane facing down (it read as 180 - angle).
SLOPE = click.FloatRange(0, 90, max_open=True)
# A Coulomb coefficient: the range of licrom.scene.sweep.check_friction, as a click type for a usage error.
FRICTION = click.FloatRange(min=0)


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="licrom")
def cli() -> None:
    """licrom: reduced-order simulation of elastic solids in frictional contact."""


def _cubature_option(value: str, model, mesh):
    """``--cubature``: a name of ``licrom.reduced.base.CUBATURES`` or a count of naive tets (a model without a
    fitted cubature falls back to the naive default, with a warning, for ``fitted``)."""
    from ..reduced.base import CUBATURES
    from ..subspace.cubature import Cubature

    if value == "fitted" and model.cubature is None:
        return None
    if value in CUBATURES:
        return value
    try:
        count = int(value)
    except ValueError:
        raise click.BadParameter(f"must be one of {', '.join(CUBATURES)} or a number of naive tets >= 1, got {value!r}", param_hint="--cubature") from None
    if count < 1:
        raise click.BadParameter(f"a number of naive tets must be >= 1, got {count}", param_hint="--cubature")
    return Cubature.naive(mesh, count)


def _print_mesh_summary(mesh, seconds: float | None = None) -> None:
    q = mesh.quality()
    lo, hi = mesh.bounds
    click.echo(f"vertices          {mesh.n_vertices}")
    click.echo(f"tets              {mesh.n_tets}")
    click.echo(f"boundary faces    {len(mesh.boundary_faces)}")
    click.echo(f"boundary vertices {len(mesh.boundary_vertices)}")
    click.echo(f"bounds (m)        [{lo[0]:.4g}, {lo[1]:.4g}, {lo[2]:.4g}] .. [{hi[0]:.4g}, {hi[1]:.4g}, {hi[2]:.4g}]")
    click.echo(f"volume (m^3)      {mesh.volume:.6g}")
    click.echo(f"surface (m^2)     {mesh.surface_area:.6g}")
    click.echo(f"dihedral (deg)    min {q.min_dihedral_deg:.2f}  max {q.max_dihedral_deg:.2f}")
    click.echo(f"tet volume (m^3)  min {q.min_volume:.3e}  max {q.max_volume:.3e}")
    if seconds is not None:
        click.echo(f"time (s)          {seconds:.2f}")


@cli.command("mesh")
@click.argument("source")
@click.option("--resolution", "-r", type=int, default=None, help="Cells along the longest side (procedural meshes).")
@click.option("--size", type=float, nargs=3, default=None, help="Box or cheese edge lengths in m.")
@click.option("--radius", type=float, default=None, help="Sphere radius in m.")
@click.option("--holes", type=int, default=None, help="Cheese: number of holes.")
@click.option("--seed", type=int, default=None, help="Cheese: hole layout seed.")
@click.option("--edge-length", type=float, default=None,
              show_default="0.05", help="Surfaces: target tet edge length as a fraction of the bounding-box diagonal, in (0, 1].")
@click.option("--epsilon", type=float, default=None,
              show_default="1e-3", help="Surfaces: largest distance of the tet boundary from the surface, fraction of the diagonal, in (0, 0.1].")
@click.option("--stop-energy", type=float, default=None, show_default="10", help="Surfaces: tet shape target (AMIPS energy > 3; lower: better, slower).")
@click.option("--scale", type=float, default=None, show_default="1", help="Surfaces: multiply the coordinates by this first (0.001 for mm).")
@click.option("--allow-open", is_flag=True,
              help="Surfaces: mesh a surface that is not closed anyway (fTetWild fills it into another shape; the change is printed).")
@click.option("--output", "-o", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Write the mesh here (.mesh, .msh, .vtu, ...).")
def mesh_command(source, resolution, size, radius, holes, seed, edge_length, epsilon, stop_energy, scale, allow_open, output) -> None:
    """Make a tet mesh from a surface (.obj, .stl, .ply, .off) or a procedural shape (box, sphere, cheese), or inspect a tet mesh file.

    SOURCE is a surface file (filled with tets by fTetWild), 'box', 'sphere', 'cheese',
    or the path of a tet mesh file. Prints counts and tet quality; with --output, writes the mesh.
    """
    from ..geometry import meshes
    from ..geometry.mesh import Mesh
    from ..geometry.surface import SURFACE_SUFFIXES, Surface, TetrahedralizeParams, tetrahedralize

    surface = None
    start = time.perf_counter()
    is_surface = Path(source).suffix.lower() in SURFACE_SUFFIXES
    given = [flag for flag, v in (("--edge-length", edge_length), ("--epsilon", epsilon), ("--stop-energy", stop_energy),
                                  ("--scale", scale), ("--allow-open", allow_open or None)) if v is not None]
    if given and not is_surface:
        raise ConfigError(f"{', '.join(given)}: only for surface files ({', '.join(SURFACE_SUFFIXES)}), not for {source!r}")
    if is_surface:
        tkw = {k: v for k, v in (("edge_length", edge_length), ("epsilon", epsilon), ("stop_energy", stop_energy), ("scale", scale))
               if v is not None}
        params = TetrahedralizeParams(**tkw)
        surface = Surface.load(source)
        click.echo(f"surface {source}: {len(surface.vertices)} vertices, {len(surface.faces)} triangles, "
                   f"{'closed' if surface.is_closed else 'NOT closed (holes or open edges)'}")
        click.echo(f"tetrahedralising (fTetWild, edge length {params.edge_length:g} x diagonal, epsilon {params.epsilon:g}) ...")
        with warnings.catch_warnings():
            # The open surface's difference is printed below, not also as a warning.
            warnings.filterwarnings("ignore", message="the open surface was meshed", category=LicromWarning)
            mesh = tetrahedralize(surface, params, allow_open=allow_open)
    elif source in meshes.PROCEDURAL:
        kwargs: dict = {}
        if resolution is not None:
            kwargs["resolution"] = resolution
        if size is not None and source in ("box", "cheese"):
            kwargs["size"] = tuple(size)
        if radius is not None and source == "sphere":
            kwargs["radius"] = radius
        if source == "cheese" and (holes is not None or seed is not None):
            base = meshes.CheeseHoles()
            kwargs["holes"] = meshes.CheeseHoles(
                count=base.count if holes is None else holes, min_radius=base.min_radius,
                max_radius=base.max_radius, seed=base.seed if seed is None else seed,
            )
        mesh = meshes.PROCEDURAL[source](**kwargs)
        click.echo(f"{source} mesh")
    else:
        mesh = Mesh.load(source)
        click.echo(f"mesh file {source}")
    elapsed = time.perf_counter() - start
    _print_mesh_summary(mesh, elapsed)
    if surface is not None and surface.is_closed:
        enclosed = Surface(surface.vertices * params.scale, surface.faces).enclosed_volume  # not scale**3: 1e299**3 overflows
        click.echo(f"surface volume    {enclosed:.6g} m^3 (tets {100 * (mesh.volume / enclosed - 1):+.2f} %)")
    elif surface is not None:
        from ..geometry.surface import _difference

        click.echo(f"NOT the surface's shape: {_difference(surface, params.scale, mesh)}")
    if output is not None:
        mesh.save(output)
        click.echo(f"wrote {output}")


@cli.command("scene")
@click.argument("source")
@click.option("--output", "-o", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Copy the scene file here (a template to edit).")
@click.option("--mesh", "mesh_file", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="With --output: the copy's object is this tet mesh file (its procedural resolution removed).")
def scene_command(source, output, mesh_file) -> None:
    """Check a scene file (or a built-in scene: cheese, sphere, demo) and print what it describes.

    With --output, copy it there: `licrom scene demo -o my-scene.toml --mesh my.msh` starts a
    scene of your own on your mesh.
    """
    from .._io import atomic_path
    from ..data.scene_file import builtin_scene_text, load_scene, with_mesh_file

    def checked(path_or_name: str | Path, name: str | None = None):
        scene = load_scene(path_or_name)
        name = scene.source if name is None else name
        try:
            scene.object.check()  # generate would stop at a missing mesh file; say so here
        except LicromError as exc:
            raise type(exc)(f"scene file {name}: object.mesh: {exc}") from None
        return scene

    if mesh_file is not None and output is None:
        raise ConfigError("--mesh needs --output: it sets the mesh of the copy")
    if output is None:
        click.echo(checked(source).summary())
        return
    text = Path(source).read_text(encoding="utf-8") if Path(source).is_file() else builtin_scene_text(source)
    if mesh_file is not None:
        text = with_mesh_file(text, mesh_file, output)
    with atomic_path(output) as tmp:  # the copy is checked beside where it goes, and kept only if it passes
        tmp.write_text(text, encoding="utf-8")
        scene = checked(tmp, f"'{output}'")
    click.echo(scene.summary())
    click.echo(f"wrote {output}")


@cli.command("generate")
@click.argument("out_dir", type=click.Path(file_okay=False, path_type=Path))
@click.option("--scene", "scene_source", default="cheese", show_default=True,
              help=f"Scene file (.toml) or built-in scene ({', '.join(builtin_scenes())}): object, material, planes, sweep, time.")
@click.option("--mesh", "mesh_source", default=None, show_default="the scene's", help="Object: a tet mesh file, or box / sphere / cheese[:RES].")
@click.option("--resolution", "-r", type=click.IntRange(min=1), default=None, help="Procedural mesh resolution (cells along the longest side).")
@click.option("--youngs-modulus", "-E", type=click.FloatRange(min=0, min_open=True), default=None, show_default="the scene's", help="Young's modulus in Pa.")
@click.option("--poisson-ratio", type=click.FloatRange(-1, 0.5, min_open=True, max_open=True), default=None, show_default="the scene's", help="Poisson ratio in (-1, 0.5).")
@click.option("--density", type=click.FloatRange(min=0, min_open=True), default=None, show_default="the scene's", help="Density in kg/m^3.")
@click.option("--viscosity", type=click.FloatRange(min=0), default=None, show_default="the scene's",
              help="Material damping: Kelvin-Voigt viscosity in Pa s (0: none).")
@click.option("--friction", "--mu", type=FRICTION, multiple=True, show_default="the scene's", help="Friction sweep: Coulomb coefficient (repeatable).")
@click.option("--slope", type=SLOPE, multiple=True, show_default="the scene's", help="Slope sweep: first plane's incline in degrees, [0, 90) (repeatable).")
@click.option("--dt", type=click.FloatRange(min=0, min_open=True), default=None, show_default="the scene's", help="Time step in s.")
@click.option("--steps", type=click.IntRange(min=1), default=None, show_default="the scene's", help="Time steps per trajectory.")
@click.option("--record-every", type=click.IntRange(min=1), default=None, show_default="the scene's", help="Record every n-th step.")
@click.option("--impact-window", type=click.FloatRange(min=0), default=None, show_default="the scene's, else 0.05",
              help="Where --record-every > 1: keep every step's frame this long after each impact, in s, for training (0: none).")
@click.option("--device", default="auto", show_default=True, help="Simulation device: auto (CUDA when visible), cpu, cuda or cuda:N.")
@click.option("--executor", type=click.Choice(["local", "ray"]), default="local", show_default=True,
              help="local: this machine (--jobs processes); ray: one task per run on a Ray cluster (RAY_ADDRESS, else a local one).")
@click.option("--jobs", "-j", type=int, default=None, show_default="1", help="Processes of the local executor.")
@click.option("--ray-timeout", type=click.FloatRange(min=0, min_open=True), default=None,
              show_default="LICROM_RAY_TIMEOUT, else 30", help="Seconds to wait for the Ray cluster at RAY_ADDRESS to answer.")
@click.option("--quiet", "-q", is_flag=True, help="No progress bars.")
def generate_command(out_dir, scene_source, mesh_source, resolution, youngs_modulus, poisson_ratio, density, viscosity, friction, slope,
                     dt, steps, record_every, impact_window, device, executor, jobs, ray_timeout, quiet) -> None:
    """Simulate a dataset of full-space trajectories into OUT_DIR (resumable: finished files are skipped).

    The runs are the scene file's sweep (friction x slope x initial state); the options
    replace the scene's values. Writes one traj_XXX_*.npz per run, mesh.vtu and
    manifest.json, and prints what it wrote.
    """
    from ..data.scene_file import load_scene
    from ..executors import check_executor
    from ..full import check_device_name, resolve_device

    start = time.perf_counter()
    executor, n_jobs = check_executor(executor, jobs)
    device = resolve_device(device) if executor == "local" else check_device_name(device)
    where = f"{n_jobs} process{'es' if n_jobs > 1 else ''}" if executor == "local" else "Ray"
    scene = load_scene(scene_source).overridden(
        mesh=mesh_source, resolution=resolution, youngs_modulus=youngs_modulus, poisson_ratio=poisson_ratio, density=density,
        viscosity=viscosity, frictions=friction or None, slopes=slope or None, dt=dt, steps=steps, record_every=record_every,
        impact_window=impact_window,
    )
    spec = scene.dataset_spec()
    impacts = f"; every step for {spec.impact_window:g} s after each impact" if spec.record_every > 1 and spec.impact_window else ""
    click.echo(f"scene {spec.name} ({scene.source}): {spec.description}".rstrip(": "))
    click.echo(f"mesh {scene.object.describe()}: {spec.mesh.n_vertices} vertices, {spec.mesh.n_tets} tets; {spec.n_trajectories} trajectories x "
               f"{spec.steps} steps of {spec.base_scene.dt:g} s (record every {spec.record_every}{impacts}) on {device}, {where}")
    manifest_path = spec.generate(out_dir, device=device, progress=not quiet, executor=executor, jobs=jobs, ray_timeout=ray_timeout)
    import json

    manifest = json.loads(manifest_path.read_text())
    total = 0
    for t in manifest["trajectories"]:
        size = t.get("bytes") or 0
        total += size
        state = "skipped (exists)" if t.get("skipped") else t["status"]
        seconds = "" if t.get("seconds") is None else f"{t['seconds']:.1f} s"
        click.echo(f"  {t['file']:<36} {state:<17} {seconds:>9} {size / 1e6:8.2f} MB  {t.get('device') or ''}")
    mesh_file = Path(out_dir) / manifest["mesh"]
    total += mesh_file.stat().st_size + manifest_path.stat().st_size
    done = sum(t["status"] == "done" for t in manifest["trajectories"])
    click.echo(f"wrote {mesh_file} and {manifest_path}")
    click.echo(f"{done}/{len(manifest['trajectories'])} trajectories done, {total / 1e6:.2f} MB in all, "
               f"wall time {time.perf_counter() - start:.1f} s")
    if done < len(manifest["trajectories"]):
        failed = [t for t in manifest["trajectories"] if t["status"] != "done"]
        raise click.ClickException(f"{len(failed)} trajectories failed (see {manifest_path}); rerun to retry them")


def _frames_of(split: dict, side: str) -> str:
    """``N frames``, with how many of them are impact frames where there are any (the training data's summary)."""
    impacts = split.get(f"{side}_impact_frames") or 0
    return f"{split.get(f'{side}_frames')} frames" + (f", {impacts} of them impact frames" if impacts else "")


class _Rank(click.ParamType):
    """``-r``: an integer >= 1 or ``auto``."""

    name = "INTEGER|auto"

    def convert(self, value, param, ctx):
        if value == "auto":
            return value
        if isinstance(value, str) and not value.strip().lstrip("+-").isdigit():
            self.fail(f"{value!r} is neither auto nor an integer.", param, ctx)
        return click.IntRange(min=1).convert(value, param, ctx)  # its range message, as the other flags'


RANK = _Rank()
# The train command's size flags, by the config field they set.
_SIZE_FLAGS = {"points_per_frame": "--points", "batch_frames": "--batch-frames", "latent_dim": "--modes / -r", "field_width": "--width",
               "field_layers": "--layers", "fourier_features": "--fourier", "max_rank": "--max-rank",
               "dynamics_max_rank": "--dynamics-max-rank"}


@cli.command("train")
@click.argument("data", type=click.Path(exists=True, path_type=Path))
@click.option("--output", "-o", type=click.Path(dir_okay=False, path_type=Path), required=True,
              help="Model file to write (.lcm); the loss CSV/PNG and checkpoints go beside it.")
@click.option("--modes", "-r", type=RANK, default="auto", show_default=True,
              help="Learned modes r (on top: 12 affine modes in the world frame; 6 affine modes and the rigid motion in the body frame), "
                   "or auto: the smallest r whose leave-runs-out projection error meets --rank-tolerance.")
@click.option("--rank-tolerance", type=click.FloatRange(0, 1, min_open=True, max_open=True), default=None,
              show_default="0.04", help="With -r auto: held-out relative projection error to meet.")
@click.option("--max-rank", type=click.IntRange(min=1), default=None, show_default="120", help="With -r auto: the largest r.")
@click.option("--dynamics-max-rank", type=click.IntRange(min=0), default=None, show_default="250",
              help="With -r auto (body frame): the largest r to which replays of training runs on POD(r) may raise it (0: no replays).")
@click.option("--frame", type=click.Choice(["body", "world"]), default="body", show_default=True,
              help="body: learn the non-rigid deformation in the body frame (rigid motion exact); world: LiCROM's world-frame modes.")
@click.option("--objective", type=click.Choice(["pod", "autoencoder"]), default=None,
              show_default="pod", help="pod: regress the field onto the POD modes of the training frames; autoencoder: LiCROM's training.")
@click.option("--pod-weighting", type=click.Choice(["run", "frame"]), default=None,
              show_default="run", help="run: the training runs balanced in the POD (a run that deforms a lot counts little more than a gentle one); frame: every frame counts the same (plain POD).")
@click.option("--epochs", type=click.IntRange(min=1), default=None, show_default="auto",
              help="Passes over the training frames (auto: 200, and 800 on a mesh above 5000 tets).")
@click.option("--lr", type=float, default=None, show_default="3e-3", help="Initial Adam learning rate.")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of weights, split and sampling.")
@click.option("--device", type=click.Choice(["auto", "cpu", "cuda"]), default="auto", show_default=True,
              help="Training device (auto: CUDA when available).")
@click.option("--gpus", type=int, default=None, show_default="all visible", help="GPUs to use (more than 1 trains with DDP).")
@click.option("--nodes", type=int, default=None, show_default="1", help="Machines of a multi-node DDP run, each with --gpus GPUs (see docs/scaling.md).")
@click.option("--join-timeout", type=float, default=None,
              show_default="120", help="Seconds the processes of a multi-GPU or multi-node run wait for each other to join.")
@click.option("--batch-frames", type=int, default=None, show_default="16", help="Frames per step.")
@click.option("--points", type=int, default=None, show_default="2048", help="Points sampled per step, shared by its frames.")
@click.option("--val-fraction", type=float, default=None, show_default="0.2", help="Fraction of trajectories held out.")
@click.option("--width", type=int, default=None, show_default="auto", help="Width of the neural field W(X); auto: twice r, at least 256.")
@click.option("--layers", type=int, default=None, show_default="5", help="Linear layers of the neural field W(X).")
@click.option("--projection-weight", type=float, default=None, show_default="1; 0: plain LiCROM", help="Weight of the projection loss term.")
@click.option("--fourier", type=int, default=None, show_default="32; 0: plain LiCROM", help="Random Fourier features of X fed to W(X).")
@click.option("--cubature-points", type=click.IntRange(min=1), default=None, show_default="auto",
              help="Most tets of the cubature fitted at the end (auto: 1000; above 5000 tets a fit of 1000 and one of 3000, keeping the one "
                   "whose held-out runs land nearer their targets: docs/results.md, section 47).")
@click.option("--cubature-candidates", type=click.IntRange(min=1), default=None, show_default="as many as 1 GiB holds; 8192 above 5000 tets",
              help="Tets that fit chooses from; at high r on large meshes a small pool limits it "
                   "(the 104k-tet ball at r = 250: 19 % force residual from 2001, 3.9 % from 8192; docs/results.md, section 34).")
@click.option("--cuda-graph/--no-cuda-graph", default=True, show_default=True,
              help="On one GPU, replay each step's forward and backward pass from a CUDA graph (3-4x faster a step, the same "
                   "weights; docs/results.md, section 44); --no-cuda-graph runs every step eagerly.")
@click.option("--resume", is_flag=True, help="Continue from the last checkpoint beside the output file.")
@click.option("--quiet", "-q", is_flag=True, help="No progress bar.")
def train_command(data, output, modes, rank_tolerance, max_rank, dynamics_max_rank, frame, objective, pod_weighting, epochs, lr, seed, device, gpus, nodes, join_timeout, batch_frames,
                  points, val_fraction, width, layers, projection_weight, fourier, cubature_points, cubature_candidates, cuda_graph, resume, quiet) -> None:
    """Train a LiCROM subspace on the trajectories in DATA (a directory of .npz files, or one file).

    Prints the choice of r (with -r auto), the held-out errors and the learned subspace against
    POD of its size, and writes the model, OUTPUT.losses.csv, OUTPUT.losses.png and the
    checkpoints in OUTPUT.checkpoints/.
    """
    from ..learn.model import ModelConfig
    from ..learn.training import TrainConfig, output_paths, train
    from ..learn.training.config import check_training_memory
    from ..learn.training.dynamics import dynamics_lines
    from ..learn.training.held_out import held_out_lines
    from ..learn.training.rank import RankChoice

    start = time.perf_counter()
    tkw: dict = {"seed": seed, "device": device, "resume": resume, "progress": not quiet, "cuda_graph": cuda_graph}
    for key, value in (("objective", objective), ("pod_weighting", pod_weighting), ("epochs", epochs), ("lr", lr), ("batch_frames", batch_frames), ("points_per_frame", points),
                       ("val_fraction", val_fraction), ("projection_weight", projection_weight), ("devices", gpus), ("nodes", nodes), ("join_timeout_s", join_timeout),
                       ("rank_tolerance", rank_tolerance), ("max_rank", max_rank), ("dynamics_max_rank", dynamics_max_rank),
                       ("cubature_points", cubature_points), ("cubature_candidates", cubature_candidates)):
        if value is not None:
            tkw[key] = value
    mkw: dict = {"latent_dim": modes, "frame": frame}
    if width is not None:
        mkw["field_width"] = width
    if layers is not None:
        mkw["field_layers"] = layers
    if fourier is not None:
        mkw["fourier_features"] = fourier
    try:
        train_config, model_config = TrainConfig(**tkw), ModelConfig(**mkw)
        check_training_memory(train_config, model_config)  # --points x --width together, before the data is read
    except ConfigError as exc:  # the configs name their fields: name the flag too
        import re

        field = re.search(r"Config\.(\w+)", str(exc))
        if field is None or field.group(1) not in _SIZE_FLAGS:
            raise
        raise ConfigError(f"{_SIZE_FLAGS[field.group(1)]}: {exc}") from exc
    model = train(data, output, train_config, model_config)
    import os

    if os.environ.get("LOCAL_RANK", "0") != "0" or os.environ.get("NODE_RANK", "0") != "0":
        return  # another process of a multi-GPU run: rank 0 reports
    meta = model.metadata
    final = meta.get("final", {})
    split = meta.get("data", {})
    on_top = f"+{model.n_affine} affine" if model.frame == "world" else "+6 affine and the rigid motion"
    click.echo(f"trained r = {model.n_learned} ({on_top}, {model.frame} frame) on {len(split.get('train', []))} trajectories "
               f"({_frames_of(split, 'train')}), held out {len(split.get('validation', []))} ({_frames_of(split, 'validation')})")
    if "candidates" in meta.get("rank", {}):
        click.echo(RankChoice.from_dict(meta["rank"]).describe())
        for line in dynamics_lines(meta["rank"].get("dynamics")):
            click.echo(line)
    click.echo(f"epochs            {meta.get('epochs_trained')}")
    click.echo(f"final train loss  {final.get('train_loss', float('nan')):.4e}")
    for key, label in (("val_proj_residual", "held-out projection error (residual)"), ("val_enc_residual", "held-out encoder error (residual)"),
                       ("val_proj_full", "held-out projection error (full)"), ("val_enc_full", "held-out encoder error (full)")):
        value = final.get(key)
        if value is not None and value == value:
            click.echo(f"{label:<38} {100 * value:.3f} %")
    sub = meta.get("subspace")
    if sub:
        extended = (f", {sub['ratio_before_extension']:.3f}x before {sub['extended_epochs']} more epochs" if "extended_epochs" in sub else "")
        click.echo(f"learned subspace  {100 * sub['model']:.3f} % projection error of the {sub['split']} frames, "
                   f"{sub['ratio']:.3f}x POD({sub['r']}) it was trained towards ({100 * sub['pod']:.3f} %){extended}; plain POD {100 * sub['plain_pod']:.3f} %")
    if meta.get("mean_train_seconds_per_epoch") is not None:
        click.echo(f"time per epoch    {meta['mean_train_seconds_per_epoch']:.3f} s (training only, mean)")
    cub = meta.get("cubature")
    if cub:
        click.echo(f"cubature          {cub['count']} of {model.mesh.n_tets} tets fitted to {cub['samples']} training poses, "
                   f"force residual {100 * cub['fit_error']:.2f} % (tolerance {100 * cub['tolerance']:g} %), {cub['fit_seconds']:.1f} s; "
                   "stored in the model, the reduced runs' default")
        for row in cub.get("choice") or []:
            kept = "kept" if row["max_count"] == cub["max_count"] else "not kept"
            ratio = f", worst held-out run {row['target_ratio']:.2f}x its targets" if "target_ratio" in row else ""
            click.echo(f"  fit of at most {row['max_count']} tets: {row['count']} tets, force residual {100 * row['fit_error']:.2f} %{ratio} ({kept})")
    held = meta.get("held_out")
    if held and held.get("runs"):
        click.echo(f"held-out runs, ReducedSim(model) with its defaults against each run (estimate: the run's own; flagged above "
                   f"{100 * held['threshold']:.0f} %):")
        for line in held_out_lines(held):
            click.echo(line)
    paths = output_paths(output)
    click.echo(f"wrote {paths['model']}, {paths['csv'].name}, {paths['png'].name}")
    click.echo(f"wall time {time.perf_counter() - start:.1f} s")


@cli.command("compare")
@click.argument("model_path", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--scene", "scene_source", default=None,
              show_default="the model's scene", help="Scene file (.toml) or built-in scene: its held-out scenes (or its sweep), object and time.")
@click.option("--slope", type=SLOPE, multiple=True, show_default="the scene's", help="Incline angle in degrees, [0, 90) (repeatable).")
@click.option("--friction", "--mu", type=FRICTION, multiple=True, show_default="the scene's", help="Coulomb coefficient (repeatable).")
@click.option("--mesh", "mesh_source", default=None,
              show_default="the scene's, else the model's", help="Mesh to run on: a tet mesh file, or cheese:RES / sphere:RES / box:RES.")
@click.option("--steps", type=click.IntRange(min=1), default=None, show_default="the scene's; 150 without --scene", help="Time steps.")
@click.option("--cubature", default="fitted", show_default=True,
              help="Cubature: fitted (the model's, refitted on another mesh), full (every tet), naive (1000 random tets) or a number N (N naive tets).")
@click.option("--solver", type=click.Choice(["newton", "prefactored"]), default="newton", show_default=True)
@click.option("--device", default="auto", show_default=True, help="Full simulation device: auto (CUDA when visible), cpu, cuda or cuda:N.")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Write report.html, summary.md/json (with --sensitivity, each scene's spread under \"sensitivity\"), filmstrips, "
                   "animations, the error plot and the runs (runs/*.npz, for licrom export) here.")
@click.option("--sensitivity", is_flag=True,
              help="Also run each scene in full space with one input moved a little (licrom.analysis.sensitivity, 6 more full "
                   "runs a scene) and set the reduced error beside how far the scene's own run moves.")
@click.option("--quiet", "-q", is_flag=True, help="No progress bars.")
def compare_command(model_path, scene_source, slope, friction, mesh_source, steps, cubature, solver, device, out, sensitivity, quiet) -> None:
    """Run full and reduced side by side on scenes, and report how they differ.

    With --scene, the scenes are the scene file's held-out scenes (else every run of its
    sweep), on its object. Without, every (slope, friction) pair is one scene: the model's
    scene with that incline, the object placed on it as in the model's scene. Prints
    per-scene error, non-rigid deformation error, peak deformation and total rotation of
    both, centre-of-mass error, stick/slip agreement, penetration and per-step time of both.
    With --sensitivity, also how far each scene's own full run moves when an input moves a little:
    a reduced run cannot be held closer than that.
    """
    from .._io import make_dir
    from ..analysis.compare import run_comparison
    from ..analysis.sensitivity import sensitivity as scene_sensitivity
    from ..data.scene_file import ObjectSpec, load_scene
    from ..learn.model import Model
    from ..scene.placement import initial_state_between_planes
    from ..scene.scene import Plane
    from ..scene.sweep import slope_friction_pairs
    from ..viz.report import Case, case_tag, write_report

    scene_file = None if scene_source is None else load_scene(scene_source)
    model = Model.load(model_path)
    if mesh_source:
        mesh = ObjectSpec.parse(mesh_source).build()
    else:
        mesh = model.mesh if scene_file is None else scene_file.object.build()
    cubature_choice = _cubature_option(cubature, model, mesh)
    if scene_file is not None:
        cases = scene_file.cases(mesh, slope, friction)
        steps = steps or scene_file.steps
    else:
        base = model.default_scene
        steps = steps or 150
        planes = [base.planes[0]] if base.planes else []
        if slope or friction:
            planes = [Plane.incline(s, m) for s, m in slope_friction_pairs(slope, friction, planes[0] if planes else None)]
        cases = []
        for plane in planes:
            # Keep the model scene's placement relative to its plane.
            initial = base.initial
            if base.planes:
                initial = initial_state_between_planes(initial, base.planes[0], plane, mesh, base.material.density)
            cases.append((f"slope {plane.slope_deg:.1f} deg, mu {plane.friction:g}", base.replace(planes=(plane,), initial=initial)))
    if out is not None:
        make_dir(out)  # a folder that cannot be made fails before the simulations
    compared, spreads = [], {}
    bar = None
    if not quiet:
        from tqdm import tqdm

        bar = tqdm(total=len(cases), desc="compare", unit="scene")
    echo = click.echo if bar is None else bar.write  # tables above the bar, not through it
    try:
        for label, scene in cases:
            if bar is not None:
                bar.set_postfix_str(label)
            cmp, full, reduced = run_comparison(model, scene, mesh, steps=steps, device=device, solver=solver,
                                                cubature=cubature_choice, progress=not quiet)
            echo(f"\n{label}  ({mesh.n_tets} tets, r = {model.n_learned} learned modes, {model.frame} frame)\n{cmp.table()}")
            if sensitivity:
                spread = scene_sensitivity(mesh, scene, steps, reference=full, device=device)
                echo(_sensitivity_lines(spread, cmp))
                spreads[label] = {**spread.summary(), "reduced_over_spread": _over_spread(spread, cmp)}
            compared.append(Case(label, case_tag(label, scene, [c.tag for c in compared]), cmp, full, reduced))
            if bar is not None:
                bar.update(1)
    finally:
        if bar is not None:
            bar.close()
    if out is not None:
        from ..viz.render import pick_renderer

        renderer, why_not = pick_renderer()
        if why_not:
            click.echo(f"pictures: {why_not}; drawing them with matplotlib")
        description = (f"{Path(model_path).name} on {mesh.n_tets} tets: r = {model.n_learned} learned modes, {model.frame} frame, "
                       f"cubature {cubature}")
        footer = "; ".join(f"{label}: its own full run moves {100 * v['nonrigid_spread']:.1f} % non-rigid when an input moves a little "
                           f"({'chaotic' if v['chaotic'] else 'well conditioned'}), the reduced run's error is {v['reduced_over_spread']:.1f}x that"
                           for label, v in spreads.items())
        write_report(compared, out, "licrom compare", description, renderer, extra={"sensitivity": spreads} if spreads else None,
                     footer=f"Scene sensitivity (licrom.analysis.sensitivity): {footer}." if spreads else "")
        click.echo(f"\nwrote {out}/report.html, summary.md, summary.json, errors.png, filmstrips, animations and the runs (runs/*.npz)")


def _sensitivity_lines(s, cmp) -> str:
    """How far a scene's own full run moves when an input moves (:class:`licrom.analysis.sensitivity.Sensitivity`),
    beside the reduced run's errors (``cmp``)."""
    from ..analysis.sensitivity import HALF_STEP

    lines = ["scene sensitivity (its own full run, one input moved; non-rigid / centre of mass over the size):"]
    lines += [f"  {label:28s} {100 * r['nonrigid_error']:6.1f} % / {100 * r['com_error']:5.1f} %" for label, r in s.rows.items()]
    kind = "chaotic at a model's scale" if s.chaotic else "well conditioned"
    lines.append(f"  spread {100 * s.nonrigid_spread:.1f} % / {100 * s.com_spread:.1f} % ({kind}); the reduced run's non-rigid "
                 f"error is {_over_spread(s, cmp):.1f}x it")
    if HALF_STEP in s.rows:
        lines.append(f"  the truth at half the step moves {100 * s.rows[HALF_STEP]['nonrigid_error']:.1f} %: "
                     "the full run's own error in time")
    return "\n".join(lines)


def _over_spread(s, cmp) -> float:
    """The reduced run's non-rigid error over the scene's non-rigid spread (infinite for a spread of 0)."""
    return cmp.nonrigid_error / s.nonrigid_spread if s.nonrigid_spread > 0 else math.inf


@cli.command("export")
@click.argument("runs", nargs=-1, required=True, type=click.Path(dir_okay=False, path_type=Path))
@click.option("--format", "fmt", type=click.Choice(["vtu", "usd", "png", "gif"]), required=True,
              help="vtu: ParaView series (forces, deformation, planes); usd: time-sampled stage; png: filmstrip; gif: animation.")
@click.option("--output", "-o", type=click.Path(path_type=Path), required=True,
              help="vtu: a folder; usd: a .usd/.usda/.usdc file; png/gif: the picture file.")
@click.option("--label", "labels", multiple=True, show_default="file names", help="Name of each run, in order (repeatable).")
@click.option("--color-by", type=click.Choice(["deformation", "error"]), default="deformation", show_default=True,
              help="png/gif: colour by non-rigid deformation, or by distance from the first run.")
@click.option("--frames", type=int, default=6, show_default=True, help="png: snapshots per run.")
@click.option("--fps", type=float, default=20.0, show_default=True, help="gif: frames per second.")
@click.option("--max-frames", type=int, default=60, show_default=True, help="gif: at most this many frames.")
@click.option("--title", default=None, help="png/gif: text above the views.")
@click.option("--renderer", type=click.Choice(["auto", "pyvista", "matplotlib"]), default="auto", show_default=True,
              help="png/gif: pyvista (smooth shading, needs licrom[render]) or matplotlib (flat shading); auto: pyvista where it renders.")
def export_command(runs, fmt, output, labels, color_by, frames, fps, max_frames, title, renderer) -> None:
    """Export recorded runs (.npz trajectories from generate, demo or compare) for other tools.

    Several runs of one scene (e.g. full and reduced) go into one picture side by side, one
    USD stage, or one VTU folder (a series per run).
    """
    import re

    from ..records.trajectory import Trajectory

    start = time.perf_counter()
    trajectories = [Trajectory.load(p) for p in runs]
    names = list(labels) or [Path(p).stem for p in runs]
    if len(names) != len(trajectories) or len(set(names)) != len(names):
        raise ConfigError(f"--label must be given once per run with distinct names: {len(trajectories)} runs, labels {list(labels)}")
    if fmt == "vtu":
        from ..records.export import write_vtu_series

        written = [write_vtu_series(t, output, re.sub(r"[^A-Za-z0-9_.-]", "_", n)) for t, n in zip(trajectories, names)]
    elif fmt == "usd":
        from ..records.export import write_usd

        written = [write_usd(trajectories, output, names)]
    else:
        from ..viz.render import RenderStyle, animation, filmstrip, pick_renderer

        style = RenderStyle(color_by=color_by)
        renderer = pick_renderer()[0] if renderer == "auto" else renderer
        if fmt == "png":
            written = [filmstrip(trajectories, names, output, frames=frames, title=title, style=style, renderer=renderer)]
        else:
            written = [animation(trajectories, names, output, fps=fps, max_frames=max_frames, title=title, style=style, renderer=renderer)]
    frames_in = trajectories[0].n_frames
    for p in written:
        click.echo(f"wrote {p} ({p.stat().st_size / 1e6:.2f} MB)")
    click.echo(f"{len(trajectories)} run(s) of {frames_in} frames, wall time {time.perf_counter() - start:.1f} s")


DEMO_DEFAULTS = DemoConfig()


@cli.command("demo")
@click.option("--scene", "scene_source", default=DEMO_DEFAULTS.scene, show_default=True,
              help="Scene file (.toml) or built-in scene with [[held_out]] scenes: training sweep and held-out scenes.")
@click.option("--out", type=click.Path(file_okay=False), default=DEMO_DEFAULTS.out_dir, show_default=True,
              help="Output folder.")
@click.option("--resolution", type=click.IntRange(min=4), default=None, show_default="the scene's", help="Procedural mesh resolution.")
@click.option("--epochs", type=click.IntRange(min=1), default=DEMO_DEFAULTS.epochs, show_default=True, help="Training epochs.")
@click.option("--modes", "-r", type=click.IntRange(min=1), default=DEMO_DEFAULTS.modes, show_default=True, help="Learned modes r.")
@click.option("--frame", type=click.Choice(["body", "world"]), default=DEMO_DEFAULTS.frame, show_default=True,
              help="Frame of the learned modes (world: LiCROM's model, for comparison).")
@click.option("--steps", type=click.IntRange(min=1), default=None, show_default="the scene's", help="Time steps per run.")
@click.option("--quiet", "-q", is_flag=True, help="No progress display.")
def demo_command(scene_source, out, resolution, epochs, modes, frame, steps, quiet) -> None:
    """The whole pipeline at small scale on a scene file (default: the built-in scene 'demo', a cheese on inclines).

    Full-space runs of the scene's sweep, training, and the reduced model on the scene's
    held-out scenes next to the full simulation; report.html, the summary, filmstrips,
    animations, error plot, the runs (runs/*.npz) and VTU series go to the output folder.
    """
    from dataclasses import replace

    from ..learn.model import ModelConfig
    from .demo import run_demo

    ModelConfig(latent_dim=modes, frame=frame)  # -r's memory, checked before the runs are simulated
    run_demo(replace(DEMO_DEFAULTS, scene=scene_source, out_dir=out, resolution=resolution, epochs=epochs, modes=modes, frame=frame,
                     steps=steps), progress=not quiet)


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``licrom`` script."""
    try:
        cli.main(args=argv, prog_name="licrom", standalone_mode=False)
    except LicromError as exc:
        click.echo(f"licrom: error: {exc}", err=True)
        return 2
    except OSError as exc:  # an I/O failure outside licrom's own checks: still one line
        click.echo(f"licrom: error: {exc}", err=True)
        return 2
    except click.exceptions.Abort:
        click.echo("licrom: aborted", err=True)
        return 130
    except click.ClickException as exc:  # Click's own errors in licrom's one style
        ctx = getattr(exc, "ctx", None)
        hint = f" (see '{ctx.command_path} --help')" if isinstance(exc, click.UsageError) and ctx is not None else ""
        click.echo(f"licrom: error: {exc.format_message()}{hint}", err=True)
        return exc.exit_code
    return 0


if __name__ == "__main__":
    sys.exit(main())
