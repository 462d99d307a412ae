"""Trajectory datasets: sweeps of full-space simulations over friction, planes and initial states.

:func:`generate_dataset` runs the cartesian product of friction coefficients, plane
configurations and initial states for one mesh, writes one trajectory file per run
(``traj_XXX_*.npz``), the mesh once (``mesh.vtu``) and a manifest (``manifest.json``)
listing every run with its parameters, status and timing. It is resumable: a run whose
file exists and is valid (readable archive, licrom trajectory header, the same scene and
frame count) is skipped, so an interrupted sweep continues where it stopped. One sweep at a
time writes a directory: it holds a lock (``.licrom.lock``, :data:`LOCK_NAME`) while it runs, and a
second one is refused with a ConcurrencyError; the lock dies with its process, so a killed run
leaves nothing that blocks the next.

Each run is one task (:func:`simulate_run`, the same code for every executor) that writes
its own file atomically; the runs go one after the other in this process, to a pool of
local processes (``jobs``) or to a Ray cluster (``executor="ray"``), see
:mod:`licrom.executors`. The manifest is written here as runs finish.

:func:`report_dataset_spec` gives the built-in scene files (``licrom/scenes/*.toml``) as
dataset specs: the report's sets ("cheese": 5 friction coefficients x 3 inclines with a
cheese dropped from a short height; "sphere": a sphere bouncing down a 20 degree slope with
mu 0.5) and the demo's training set ("demo").
"""

from __future__ import annotations

import contextlib
import json
import os
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from .._io import atomic_path, load_npz, make_dir, output_error
from ..errors import ConcurrencyError, ConfigError, FileFormatError, LicromError, OutputError
from ..geometry.mesh import Mesh
from ..records.trajectory import READABLE_VERSIONS
from ..scene.placement import initial_state_on_plane
from ..scene.scene import InitialState, Plane, Scene
from ..scene.sweep import DEFAULT_FRICTION, check_friction, sweep, sweep_axis, sweep_count, with_friction
from ..stepping import check_impact_window

__all__ = [
    "DATASET_FORMAT_VERSION",
    "IMPACT_WINDOW",
    "LOCK_NAME",
    "MANIFEST_NAME",
    "MESH_NAME",
    "DatasetSpec",
    "generate_dataset",
    "load_manifest",
    "local_devices",
    "simulate_run",
    "sweep_runs",
]

DATASET_FORMAT_VERSION = 1
MANIFEST_NAME = "manifest.json"
MESH_NAME = "mesh.vtu"
LOCK_NAME = ".licrom.lock"
"""The file a running :func:`generate_dataset` holds locked in its directory (removed when it ends)."""
INITIAL_FRAMES = ("world", "plane")
IMPACT_WINDOW = 0.05
"""s: how long after each impact a run of the data set keeps every step's displacement as an impact frame, where it
records only every ``record_every``-th step (:meth:`licrom.FullSim.run`, ``impact_window``).

A landing's fast transient (the first contact, the bounce, the second contact) lasts a few tens of ms and falls
between frames 10 ms apart; a subspace learned from those frames misses the momentum the landing exchanges and
leaves a speed offset that grows over the slide. Measured (results section 26: the soft cheese at the converged
truth, POD(120) of its 20 training runs as training weighs them, every tet as cubature, 4 held-out scenes): final
centre of mass 0.1-2.4 % of the size with the 10 ms frames alone, 0.1-1.5 % with 50 ms of impact frames (+50 % frames),
0.1-1.6 % with 100 ms (+94 %), non-rigid error the same (1.2-4.1 %).
"""


# --- sweep ---------------------------------------------------------------------------------
def _as_planes(item: Any, friction: float | None) -> tuple[Plane, ...]:
    """A sweep entry -> planes: a slope in degrees (incline about y), a Plane, or several Planes."""
    if isinstance(item, Plane):
        planes: tuple[Plane, ...] = (item,)
    elif isinstance(item, (int, float, np.integer, np.floating)) and not isinstance(item, bool):
        planes = (Plane.incline(float(item), DEFAULT_FRICTION if friction is None else friction),)
    elif isinstance(item, (tuple, list)) and all(isinstance(p, Plane) for p in item):
        planes = tuple(item)
    else:
        raise ConfigError(f"planes entries must be slopes in degrees, Plane objects or tuples of Planes, got {item!r}")
    return with_friction(planes, friction)


def _describe_planes(planes: tuple[Plane, ...]) -> str:
    if not planes:
        return "noplane"
    if len(planes) == 1:
        return f"slope{planes[0].slope_deg:g}"
    return f"{len(planes)}planes"


def _file_name(index: int, friction: float | None, planes: tuple[Plane, ...], initial_index: int) -> str:
    mu = f"_mu{friction:.2f}" if friction is not None else ""
    return f"traj_{index:03d}{mu}_{_describe_planes(planes)}_ic{initial_index}.npz"


def _valid_trajectory_file(path: Path, scene: Scene, frames: int, impact_window: float) -> bool:
    """True when ``path`` is an intact trajectory archive of ``scene`` with ``frames`` frames, recorded with
    ``impact_window``."""
    if not path.is_file():
        return False
    try:
        header, arrays = load_npz(path, "trajectory")  # reads every member: their CRCs are checked
        return (header.get("version") in READABLE_VERSIONS and "displacements" in arrays
                and Scene.from_dict(header["scene"]) == scene and len(arrays.get("times", ())) == frames
                and header.get("info", {}).get("impact_window", 0.0) == impact_window)
    except (LicromError, KeyError, TypeError, ValueError):
        return False


def load_manifest(out_dir: str | Path) -> dict[str, Any]:
    """Read the manifest of a dataset directory.

    Raises:
        FileFormatError: missing, unreadable or not a licrom dataset manifest.
    """
    p = Path(out_dir) / MANIFEST_NAME
    if not p.is_file():
        raise FileFormatError(f"dataset manifest not found: '{p}'")
    try:
        d = json.loads(p.read_text())
    except (OSError, ValueError) as exc:
        raise FileFormatError(f"dataset manifest '{p}' is not readable JSON: {exc}") from exc
    except RecursionError:
        raise FileFormatError(f"dataset manifest '{p}' is nested too deeply to be a licrom manifest") from None
    if not isinstance(d, dict) or d.get("format") != "licrom.dataset":
        raise FileFormatError(f"'{p}' is not a licrom dataset manifest")
    if isinstance(d.get("version"), bool) or d.get("version") != DATASET_FORMAT_VERSION:
        raise FileFormatError(f"dataset manifest '{p}' has format version {d.get('version')!r}; this licrom reads version {DATASET_FORMAT_VERSION} only")
    entries = d.get("trajectories")
    if not isinstance(entries, list) or not all(isinstance(t, dict) and isinstance(t.get("file"), str) for t in entries):
        raise FileFormatError(f"dataset manifest '{p}' is corrupt: 'trajectories' must be a list of objects with a 'file' name")
    return d


def _try_lock(fd: int) -> bool:
    """Lock the open file ``fd`` for this process without waiting; False when another holds it.

    The operating system releases the lock when its holder exits, however it ends (killed included).
    """
    try:
        import fcntl
    except ImportError:  # Windows
        import msvcrt

        try:
            msvcrt.locking(fd, msvcrt.LK_NBLCK, 1)
        except OSError:
            return False
        return True
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return False
    return True


@contextlib.contextmanager
def _directory_lock(out: Path) -> Iterator[None]:
    """Hold ``out/LOCK_NAME`` locked while the body runs; remove it after.

    Raises:
        ConcurrencyError: another sweep (in this or another process) holds the lock.
        OutputError: the lock file cannot be created (read-only folder, ...).
    """
    path = out / LOCK_NAME
    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as exc:
            raise output_error(path, exc) from exc
        if not _try_lock(fd):
            try:
                holder = os.read(fd, 32).decode(errors="replace").strip()
            except OSError:
                holder = ""
            os.close(fd)
            raise ConcurrencyError(f"dataset directory '{out}' is being written by another licrom generate "
                                   f"({'process ' + holder if holder.isdigit() else 'another process'} holds its lock "
                                   f"'{path}'); wait for it to finish or write to another directory")
        # The holder before us removes the file as it ends: hold the one that is at the path now.
        try:
            current = os.stat(path)
            opened = os.fstat(fd)
            if (current.st_dev, current.st_ino) == (opened.st_dev, opened.st_ino):
                break
        except FileNotFoundError:
            pass
        os.close(fd)
    try:
        with contextlib.suppress(OSError):  # the holder's pid is for the message only
            os.ftruncate(fd, 0)
            os.write(fd, f"{os.getpid()}\n".encode())
        yield
    finally:
        with contextlib.suppress(OSError):
            os.unlink(path)  # while still locked, so no one holds a file that is no longer there
        os.close(fd)


def _write_manifest(path: Path, manifest: dict[str, Any]) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(manifest, indent=2))


def sweep_runs(
    mesh: Mesh,
    base_scene: Scene,
    frictions: Sequence[float] | None = None,
    planes: Sequence[Any] | None = None,
    initial_states: Sequence[InitialState] | None = None,
    initial_frame: str = "world",
) -> list[tuple[float | None, tuple[Plane, ...], int, InitialState, Scene]]:
    """The runs of a sweep, in file order: ``(friction, planes, initial index, initial state, scene)`` each.

    Frictions outermost, then planes, then initial states (:func:`licrom.scene.sweep.sweep`).
    Arguments as in :func:`generate_dataset`; ``scene`` is what the run simulates.

    Raises:
        ConfigError: bad arguments.
    """
    mus, plane_items, states = _sweep_axes(base_scene, frictions, planes, initial_states)
    if initial_frame not in INITIAL_FRAMES:
        raise ConfigError(f"initial_frame must be one of {INITIAL_FRAMES}, got {initial_frame!r}")
    runs = []
    for mu, p_item, (k, state) in sweep(mus, plane_items, tuple(enumerate(states))):
        run_planes = _as_planes(p_item, mu)
        initial = state
        if initial_frame == "plane":
            if not run_planes:
                raise ConfigError("initial_frame='plane' needs at least one plane in every run")
            initial = initial_state_on_plane(state, run_planes[0], mesh, base_scene.material.density)
        runs.append((mu, run_planes, k, state, base_scene.replace(planes=run_planes, initial=initial)))
    return runs


def _sweep_axes(base_scene: Scene, frictions: Sequence[float] | None, planes: Sequence[Any] | None,
                initial_states: Sequence[InitialState] | None) -> tuple[tuple[float | None, ...], tuple[Any, ...], tuple[InitialState, ...]]:
    """The checked axes of a sweep: friction coefficients (``(None,)``: the planes keep their own), plane
    entries and initial states, the base scene's where None.

    Raises:
        ConfigError: a bad friction or initial state, or an empty axis.
    """
    mus = None if frictions is None else tuple(check_friction(m, f"frictions[{i}]") for i, m in enumerate(frictions))
    plane_items = (tuple(base_scene.planes),) if planes is None else tuple(planes)
    states = (base_scene.initial,) if initial_states is None else tuple(initial_states)
    for s in states:
        if not isinstance(s, InitialState):
            raise ConfigError(f"initial_states must hold InitialState objects, got {type(s).__name__}")
    if mus == () or not plane_items or not states:
        raise ConfigError("frictions, planes and initial_states must not be empty (use None for the base scene's)")
    return sweep_axis(mus), plane_items, states


def local_devices(device: str, jobs: int) -> list[str]:
    """The devices the local executor's runs take in turn: every CUDA device of the machine when
    ``device`` is ``"cuda"`` (as ``"auto"`` resolves on a GPU machine) and several processes run,
    else ``device`` alone."""
    if device != "cuda" or jobs < 2:
        return [device]
    from ..full.device import warp_ready

    count = warp_ready().get_cuda_device_count()
    return [f"cuda:{i}" for i in range(count)] if count > 1 else [device]


def simulate_run(
    out_dir: str,
    mesh: Mesh,
    scene: Scene,
    file: str,
    steps: int,
    record_every: int,
    device: str | None,
    precision: str,
    info: dict[str, Any],
    progress: bool = False,
    impact_window: float = 0.0,
) -> dict[str, Any]:
    """One run of a sweep, wherever it runs: simulate, write ``out_dir/file`` atomically, report.

    The same code for every executor of :func:`generate_dataset`. The dataset's mesh file
    must be visible in ``out_dir`` (written by the caller), which on a cluster means a
    shared file system.

    Returns:
        The manifest entry's fields: ``status`` ("done" or "failed"), ``seconds``,
        ``device``, and ``bytes``, ``newton_mean``, ``unconverged_steps`` or ``error``.
    """
    from ..full import FullSim

    t0 = time.perf_counter()
    out = Path(out_dir)
    try:
        if not (out / MESH_NAME).is_file():
            import socket

            raise ConfigError(f"dataset directory '{out}' (with its {MESH_NAME}) is not visible on host {socket.gethostname()}; "
                              "the tasks of a cluster need a file system shared with the caller")
        sim = FullSim(mesh, scene, device=device)
        traj = sim.run(int(steps), record_every=int(record_every), progress=progress, impact_window=impact_window)
        traj.info.update(info)
        path = traj.save(out / file, precision=precision)
        return {
            "status": "done",
            "seconds": round(time.perf_counter() - t0, 3),
            "device": sim.device,
            "bytes": path.stat().st_size,
            "newton_mean": round(float(np.mean(traj.iterations)), 3) if len(traj.iterations) else 0.0,
            "unconverged_steps": int((~traj.converged).sum()),
        }
    except OutputError:
        raise  # a full or read-only disk fails every later run too
    except LicromError as exc:
        return {"status": "failed", "seconds": round(time.perf_counter() - t0, 3), "device": device, "error": f"{type(exc).__name__}: {exc}"}


def generate_dataset(
    out_dir: str | Path,
    mesh: Mesh,
    base_scene: Scene,
    frictions: Sequence[float] | None = None,
    planes: Sequence[Any] | None = None,
    initial_states: Sequence[InitialState] | None = None,
    steps: int = 200,
    record_every: int = 1,
    device: str | None = None,
    progress: bool = True,
    initial_frame: str = "world",
    precision: str = "float32",
    name: str | None = None,
    executor: str = "local",
    jobs: int | None = None,
    ray_timeout: float | None = None,
    impact_window: float = IMPACT_WINDOW,
) -> Path:
    """Simulate the cartesian product of frictions x planes x initial states; return the manifest path.

    Args:
        out_dir: dataset directory (created if missing).
        mesh: the mesh every run simulates (saved once as ``mesh.vtu``).
        base_scene: material, contact, solver, time step and gravity of every run, and the
            defaults for what is not swept.
        frictions: Coulomb coefficients; each replaces the friction of every plane of a run.
            ``None``: the planes keep their own.
        planes: plane configurations: a slope in degrees (``Plane.incline(slope, mu)``), a
            :class:`Plane`, or a tuple of planes. ``None``: the base scene's planes.
        initial_states: initial placements and velocities. ``None``: the base scene's.
        steps: time steps per run.
        record_every: record every n-th step (frame 0 is the initial state).
        device: warp device of the simulations: ``None``/``"auto"`` (CUDA where a task sees
            a GPU, else the CPU), ``"cpu"``, ``"cuda"`` or ``"cuda:N"``. Several local
            processes on a machine of several GPUs take the GPUs in turn (see
            :func:`local_devices`); Ray gives each task its own. Each manifest entry records
            the device its run used.
        progress: show progress bars (runs as they finish; with the serial local executor
            also the steps of the current run).
        initial_frame: ``"world"``: initial states as given; ``"plane"``: initial states
            are given over a horizontal ground ``z = 0`` and carried onto the first plane
            of each run (see :func:`initial_state_on_plane`), so a drop height means the
            same on every slope.
        precision: storage precision of the frames (``"float32"`` or ``"float64"``).
        name: a name recorded in the manifest.
        executor: ``"local"`` (this machine) or ``"ray"`` (one Ray task per run, a GPU per
            task where the cluster has GPUs; ``out_dir`` must then be on a file system the
            tasks share). See :mod:`licrom.executors`.
        jobs: processes of the local executor (default 1: the runs in this process, one
            after the other); not for Ray.
        ray_timeout: seconds to wait for the Ray cluster at ``RAY_ADDRESS`` to answer (default
            ``LICROM_RAY_TIMEOUT``, else :data:`licrom.executors.RAY_TIMEOUT`, 30 s).
        impact_window: s, where ``record_every > 1``: every step's displacement is kept this long after each
            impact (:data:`IMPACT_WINDOW`; 0 keeps none).

    Every run is :func:`simulate_run`, which writes its file atomically; this process
    writes the manifest as runs finish. The files do not depend on the executor. Existing
    valid files are skipped, whatever executor wrote them; runs that fail (SolverError
    with ``on_failure="raise"``) are recorded as failed and retried on the next call.

    Raises:
        ConfigError: bad arguments, Ray missing for ``executor="ray"``, no Ray cluster answering
            at ``RAY_ADDRESS`` within ``ray_timeout``, or ``out_dir`` holds a dataset of another mesh.
        ConcurrencyError: another sweep is writing ``out_dir`` (it holds :data:`LOCK_NAME` there).
    """
    from ..executors import check_executor, check_ray_timeout, run_tasks
    from ..full import check_device_name, resolve_device

    if not isinstance(mesh, Mesh):
        raise ConfigError(f"mesh must be a licrom.Mesh, got {type(mesh).__name__}")
    if not isinstance(base_scene, Scene):
        raise ConfigError(f"base_scene must be a licrom.Scene, got {type(base_scene).__name__}")
    if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) or steps < 1:
        raise ConfigError(f"steps must be an integer >= 1, got {steps!r}")
    if isinstance(record_every, bool) or not isinstance(record_every, (int, np.integer)) or record_every < 1:
        raise ConfigError(f"record_every must be an integer >= 1, got {record_every!r}")
    if precision not in ("float32", "float64"):
        raise ConfigError(f"precision must be 'float32' or 'float64', got {precision!r}")
    impact_window = check_impact_window(impact_window)
    if record_every == 1:
        impact_window = 0.0  # every step is a frame already
    runs = sweep_runs(mesh, base_scene, frictions, planes, initial_states, initial_frame)
    executor, jobs = check_executor(executor, jobs)
    ray_timeout = check_ray_timeout(ray_timeout) if executor == "ray" else None
    # Local runs use this machine's devices; Ray tasks choose on the node that runs them.
    device = resolve_device(device) if executor == "local" else check_device_name(device)
    mus, plane_items, states = _sweep_axes(base_scene, frictions, planes, initial_states)

    out = make_dir(out_dir)
    # One sweep at a time per directory: two would both write mesh.vtu and the manifest, the last one winning.
    with _directory_lock(out):
        mesh_path = out / MESH_NAME
        existing = None
        if mesh_path.exists():
            try:
                existing = Mesh.load(mesh_path)
            except LicromError:
                existing = None  # unreadable: written again below
        if existing is not None and not existing.same_as(mesh):
            if (out / MANIFEST_NAME).exists():
                raise ConfigError(f"'{out}' already holds a dataset of another mesh ({existing.n_tets} tets); use a new directory")
            existing = None
        if existing is None:
            mesh.save(mesh_path)
        frames = 1 + steps // record_every
        manifest: dict[str, Any] = {
            "format": "licrom.dataset",
            "version": DATASET_FORMAT_VERSION,
            "name": name,
            "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
            "mesh": MESH_NAME,
            "n_vertices": mesh.n_vertices,
            "n_tets": mesh.n_tets,
            "base_scene": base_scene.to_dict(),
            "sweep": {
                "frictions": list(mus),
                "planes": [[{"normal": list(p.normal), "offset": p.offset, "friction": p.friction} for p in _as_planes(it, None)]
                           for it in plane_items],
                "initial_states": [s.__dict__ for s in states],
                "initial_frame": initial_frame,
            },
            "steps": int(steps),
            "record_every": int(record_every),
            "impact_window": impact_window,
            "frames": frames,
            "device": device,
            "executor": executor,
            "jobs": jobs if executor == "local" else None,
            "precision": precision,
            "trajectories": [],
        }
        manifest_path = out / MANIFEST_NAME
        previous: dict[str, dict[str, Any]] = {}
        if manifest_path.exists():
            try:
                previous = {t["file"]: t for t in load_manifest(out).get("trajectories", [])}
            except (FileFormatError, KeyError, TypeError):
                previous = {}

        # Entries in sweep order; a run still to simulate has its entry filled when its task finishes.
        entries: list[dict[str, Any]] = []
        todo: list[int] = []
        task_args: list[tuple[Any, ...]] = []
        step_bars = progress and executor == "local" and jobs == 1  # one run at a time: its steps can be shown
        run_devices = local_devices(device, jobs) if executor == "local" else [device]
        for index, (mu, run_planes, k, state, scene) in enumerate(runs):
            fname = _file_name(index, mu, run_planes, k)
            entry: dict[str, Any] = {
                "index": index,
                "file": fname,
                "friction": mu if mu is not None else [p.friction for p in run_planes],
                "slope_deg": [p.slope_deg for p in run_planes],
                "planes": [{"normal": list(p.normal), "offset": p.offset, "friction": p.friction} for p in run_planes],
                "initial_index": k,
                "initial": state.__dict__,
                "scene_initial": scene.initial.__dict__,
            }
            entries.append(entry)
            if _valid_trajectory_file(out / fname, scene, frames, impact_window):
                old = previous.get(fname, {})
                entry.update(status="done", skipped=True, seconds=old.get("seconds"), device=old.get("device"),
                             bytes=(out / fname).stat().st_size, newton_mean=old.get("newton_mean"),
                             unconverged_steps=old.get("unconverged_steps"))
            else:
                info = {"dataset": name, "index": index, "friction": mu, "slope_deg": entry["slope_deg"], "initial_index": k, "mesh": MESH_NAME}
                todo.append(index)
                run_device = run_devices[len(task_args) % len(run_devices)]
                task_args.append((str(out), mesh, scene, fname, int(steps), int(record_every), run_device, precision, info, step_bars,
                                  impact_window))

        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=len(runs), desc=f"dataset {name or out.name}", unit="traj", initial=len(runs) - len(todo))
        start_all = time.perf_counter()

        def write(complete: bool) -> None:
            manifest["trajectories"] = [e for e in entries if "status" in e]
            manifest["seconds"] = round(time.perf_counter() - start_all, 3)
            manifest["complete"] = complete
            _write_manifest(manifest_path, manifest)

        try:
            for i, result in run_tasks(simulate_run, task_args, executor, jobs if executor == "local" else None, ray_timeout):
                entry = entries[todo[i]]
                entry.update(skipped=False, **result)
                write(False)
                if bar is not None:
                    bar.update(1)
                    bar.set_postfix(last=f"{entry['file']} {entry['status']}", refresh=False)
        finally:
            if bar is not None:
                bar.close()
        write(all(e["status"] == "done" for e in entries))
        return manifest_path


# --- the report's sets --------------------------------------------------------------------
@dataclass(frozen=True)
class DatasetSpec:
    """A named dataset: the mesh, the base scene and the sweep, ready for :func:`generate_dataset`."""

    name: str
    mesh: Mesh
    base_scene: Scene
    frictions: tuple[float, ...] | None
    planes: tuple[Any, ...] | None
    initial_states: tuple[InitialState, ...]
    steps: int
    record_every: int
    initial_frame: str = "plane"
    description: str = ""
    impact_window: float = IMPACT_WINDOW
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def n_trajectories(self) -> int:
        """How many runs the sweep has: frictions x planes x initial states (:func:`licrom.scene.sweep.sweep_count`)."""
        return sweep_count(self.frictions, self.planes, self.initial_states)

    def scenes(self) -> list[Scene]:
        """The scene of every run, in file order."""
        return [run[-1] for run in sweep_runs(self.mesh, self.base_scene, self.frictions, self.planes, self.initial_states, self.initial_frame)]

    def generate(self, out_dir: str | Path, device: str | None = None, progress: bool = True, executor: str = "local",
                 jobs: int | None = None, ray_timeout: float | None = None) -> Path:
        """Run :func:`generate_dataset` on this spec; return the manifest path."""
        return generate_dataset(
            out_dir,
            self.mesh,
            self.base_scene,
            frictions=self.frictions,
            planes=self.planes,
            initial_states=self.initial_states,
            steps=self.steps,
            record_every=self.record_every,
            device=device,
            progress=progress,
            initial_frame=self.initial_frame,
            name=self.name,
            executor=executor,
            jobs=jobs,
            ray_timeout=ray_timeout,
            impact_window=self.impact_window,
        )
