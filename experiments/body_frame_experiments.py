"""Body-frame experiments: scenes a new user would try, with their noise floors, subspace bounds and reduced runs.

    python experiments/body_frame_experiments.py [--work out/body_frame] [--docs docs] [--r 20 40] [--small]

Families (one mesh and material each; training runs and held-out runs):

* ``cheese``: a soft cheese (E = 20 kPa) dropped onto inclines whose downhill direction is
  along x or off-axis (azimuth measured from +x), sliding and sticking; held out: other
  slopes and friction coefficients and a new azimuth;
* ``box``: a tall soft box that tips over once on a slope, or is thrown spinning to tumble
  down it like a square log; held out: a new slope / a new throw;
* ``sphere``: a soft ball bouncing and rolling down a slope (as in section 2), held out on another.

For every held-out run the script measures

* the **noise floor**: the full run against itself dropped 0.1 mm higher;
* the **subspace bounds**: the non-rigid projection error of the run onto affine + POD(r) of
  the training frames in the world frame, onto the body-frame modes (6 symmetric affine +
  POD(r)) of the training frames, of the run's own frames, and of the learned body-frame model;
* the **reduced runs**, one function per column (:data:`COLUMNS`): world-frame POD and model,
  body-frame POD and model, and the body-frame solver with the run's own modes.

Full runs are cached as ``.npz`` under ``--work/full`` and models under ``--work/models``, so
reruns skip them. Training on a CPU is slow: ``--train-only world body --device cuda`` trains the
models from the cached training runs (on a GPU machine) and stops; copy the ``.lcm`` files back
into ``--work/models``. The script writes ``--work/results.json``, section 10 of
``docs/results.md`` (keeping its hand-written ``### Reading``) and filmstrips under
``docs/figures``. ``--small`` runs tiny meshes for a few steps (a smoke test, under a minute)
and writes nothing under ``docs``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import platform
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import licrom
import numpy as np
from licrom import AffineBasis, Material, MeshBasis, ModelConfig, Plane, ReducedSim, Scene, StackedBasis, Trajectory, meshes
from licrom._io import atomic_path
from licrom.analysis.compare import COM_TARGET, NONRIGID_TARGET, compare, first_contact_frame, nonrigid_error
from licrom.learn.training import TrainConfig
from licrom.reduced.body import BodyFrameSim
from licrom.rigid import body_frame_displacements, rigid_fit
from licrom.scene.placement import drop_state, initial_state_on_plane
from licrom.scene.scene import INTEGRATORS
from licrom.subspace.affine import apply_affine, fit_affine
from licrom.subspace.basis import RUN_BALANCE, SubspaceProjector, run_balanced_weights
from licrom.subspace.body_basis import BodyFrameBasis
from licrom.subspace.cubature import Cubature
from licrom.viz.render import filmstrip, pick_renderer

SECTION_TITLE = "## 10. Body-frame reduced model"
READING = "### Reading"  # the hand-written part of the section, kept when the script rewrites its tables
NUDGE = 1e-4  # m: the noise floor's higher drop
CHAOTIC_FLOOR = 0.02  # a noise floor above this makes a scene chaotic (target: 3x the floor)
POD_SIZES = (20, 40, 60)
CUBATURE_TOLERANCE = 1e-2  # relative force error of the fitted cubature (1e-3 kept 419 of the cheese's 864 tets at r = 20)
TRAINING_AZIMUTHS = (0.0, 50.0, 160.0, 230.0, 300.0)  # deg; the held-out 120 lies between two of them
# (slope deg, mu) of the cheese's training runs at each azimuth: the full 2 x 2 grid, or with PAIRED_DESIGN two of its
# corners, alternating between azimuths ((15, 0.2), (30, 0.8) at even ones; (15, 0.8), (30, 0.2) at odd ones): twice the
# azimuths for the same number of runs, every slope, friction and their pairings still seen.
PAIRED_DESIGN = False


# --- scenes ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class Case:
    """One full-space run of a family.

    Attributes:
        name: file stem of the cached run.
        kind: what the run tests (soft slide, off-axis, tipping, ...).
        held_out: False for training runs.
        scene: the scene simulated.
        figure: draw a filmstrip of the full and reduced runs (held-out runs only).
    """

    name: str
    kind: str
    held_out: bool
    scene: Scene
    figure: bool = False


@dataclass(frozen=True)
class Family:
    """A mesh, its material and time stepping, with its training and held-out runs.

    Attributes:
        name: family name.
        mesh: the tet mesh.
        steps: time steps per run (h = ``cases[0].scene.dt``).
        cases: training and held-out runs.
        record_every: steps between recorded frames.
    """

    name: str
    mesh: licrom.Mesh
    steps: int
    cases: tuple[Case, ...]
    record_every: int = 1

    @property
    def training(self) -> list[Case]:
        return [c for c in self.cases if not c.held_out]

    @property
    def held_out(self) -> list[Case]:
        return [c for c in self.cases if c.held_out]


def with_physics(fam: Family, dt: float, integrator: str, viscosity: float, frame_dt: float = 0.01) -> Family:
    """``fam`` with every scene's time step ``dt`` (s), ``integrator`` and material viscosity (Pa s), for the same
    simulated time, recording a frame every ``frame_dt`` (s): the family at a converged truth (section 12)."""
    steps = round(fam.steps * fam.cases[0].scene.dt / dt)
    cases = tuple(dataclasses.replace(c, scene=c.scene.replace(dt=dt, integrator=integrator,
                                                               material=dataclasses.replace(c.scene.material, viscosity=viscosity)))
                  for c in fam.cases)
    return dataclasses.replace(fam, steps=steps, cases=cases, record_every=max(1, round(frame_dt / dt)))


CONVERGED_VISCOSITY = 400.0
"""Pa s: the material's damping at a converged truth (section 12)."""
CONVERGED_STEPS = {"cheese": 0.001, "box": 0.001, "sphere": 0.0005}
"""s, BDF2, per family: within 2 % of the size in centre of mass and 5 % non-rigid of h -> 0 (section 12)."""


def at_converged_truth(name: str, fam: Family) -> Family:
    """The family ``name`` (a key of :data:`FAMILIES`) at a converged truth: BDF2 at its :data:`CONVERGED_STEPS`
    with :data:`CONVERGED_VISCOSITY`, frames every 10 ms."""
    return with_physics(fam, CONVERGED_STEPS[name], "bdf2", CONVERGED_VISCOSITY)


def add_physics_arguments(ap: argparse.ArgumentParser) -> None:
    """``--time-step``, ``--integrator`` and ``--viscosity``: a family at other physics (:func:`physics_of`)."""
    ap.add_argument("--time-step", type=float, default=None, help="h of every run, s (default the family's; frames every 10 ms)")
    ap.add_argument("--integrator", choices=INTEGRATORS, default=None, help="of every run (default the family's backward Euler)")
    ap.add_argument("--viscosity", type=float, default=0.0, help="the material's Kelvin-Voigt viscosity, Pa s (section 12: 400 converges the truth)")


def physics_of(fam: Family, args: argparse.Namespace) -> Family:
    """``fam`` at the options of :func:`add_physics_arguments` where any is given (:func:`with_physics`), else as it is."""
    if not (args.time_step or args.viscosity or args.integrator):
        return fam
    base = fam.cases[0].scene
    return with_physics(fam, args.time_step or base.dt, args.integrator or base.integrator, args.viscosity)


def incline(slope_deg: float, azimuth_deg: float, friction: float) -> Plane:
    """A plane through the origin sloping by ``slope_deg``, downhill along ``(cos a, sin a, 0)``.

    Azimuth 0 is :meth:`Plane.incline`; other azimuths turn the downhill direction off the axes.
    """
    t, a = math.radians(slope_deg), math.radians(azimuth_deg)
    return Plane(normal=(math.sin(t) * math.cos(a), math.sin(t) * math.sin(a), math.cos(t)), friction=friction)


def _on_plane(mesh: licrom.Mesh, base: Scene, plane: Plane, height: float, rotation=(0.0, 0.0, 0.0),
              velocity=(0.0, 0.0, 0.0), angular_velocity=(0.0, 0.0, 0.0)) -> Scene:
    """``base`` on ``plane`` with the mesh dropped from ``height`` above it (pose and velocities given for flat ground)."""
    rho = base.material.density
    flat = drop_state(mesh, rho, height, rotation=rotation, velocity=velocity, angular_velocity=angular_velocity)
    return base.replace(planes=(plane,), initial=initial_state_on_plane(flat, plane, mesh, rho))


def _label(plane: Plane, azimuth: float) -> str:
    return f"{plane.slope_deg:.0f} deg az {azimuth:g}, mu {plane.friction:g}"


CHEESE_RESOLUTION = 8  # 864 tets (10: 1638); set by --cheese-resolution
SPHERE_RESOLUTION = 7  # 1074 tets (32: 103536)
CHEESE_DROP = 0.06  # m above the plane
CHEESE_TILT = (0.15, 0.1, 0.0)  # rad, the start pose's rotation vector


def cheese_family(small: bool) -> Family:
    """Soft cheese on inclines along x and off-axis: 2 slopes x 2 friction coefficients x 5 azimuths in training."""
    mesh = meshes.cheese(resolution=5 if small else CHEESE_RESOLUTION)
    # E = 20 kPa and a 6 cm drop: peak non-rigid deformation 5-14 % of the size where it slides or sticks (measured).
    base = Scene(material=Material(youngs_modulus=2.0e4, poisson_ratio=0.3, density=1000.0), dt=0.01)
    height, tilt = CHEESE_DROP, CHEESE_TILT
    cases = []
    # Friction loads the body from the downhill direction, which no rotation of the body frame removes: with
    # azimuths 0 and 50 alone, POD(20) of the training frames left 20 % of a run at azimuth 120 (its own POD: 0.8 %).
    grid = [(slope, mu) for slope in (15.0, 30.0) for mu in (0.2, 0.8)]
    for k, az in enumerate(TRAINING_AZIMUTHS):
        paired = (grid[0], grid[3]) if k % 2 == 0 else (grid[1], grid[2])
        for slope, mu in paired if PAIRED_DESIGN else grid:
            p = incline(slope, az, mu)
            cases.append(Case(f"cheese_train_{slope:g}_{mu:g}_az{az:g}", _label(p, az), False, _on_plane(mesh, base, p, height, tilt)))
    held = [("soft, slides", 22.0, 0.0, 0.3), ("soft, sticks", 22.0, 0.0, 0.6),
            ("off-axis, new azimuth", 25.0, 120.0, 0.3), ("off-axis, new slope and mu", 35.0, 50.0, 0.45)]
    for kind, slope, az, mu in held:
        p = incline(slope, az, mu)
        cases.append(Case(f"cheese_test_{slope:g}_{mu:g}_az{az:g}", f"{kind}: {_label(p, az)}", True,
                          _on_plane(mesh, base, p, height, tilt), figure=az == 120.0))
    if small:
        cases = cases[:2] + cases[-1:]
    return Family("cheese", mesh, 20 if small else 150, tuple(cases))


def box_family(small: bool) -> Family:
    """A tall soft box (4 x 4 x 12 cm) that tips over once on a slope, or is thrown to tumble down it."""
    mesh = meshes.box(size=(0.04, 0.04, 0.12), resolution=4 if small else 8)
    base = Scene(material=Material(youngs_modulus=2.0e4, poisson_ratio=0.3, density=1000.0), dt=0.01)
    cases = []
    # Standing on its end, it tips when tan(slope) > width / height = 1/3 (18.4 deg); high friction keeps it from sliding first.
    for slope, held in ((22.0, False), (30.0, False), (26.0, True)):
        p = incline(slope, 0.0, 0.9)
        cases.append(Case(f"box_tip_{slope:g}", f"tips over: {_label(p, 0.0)}", held, _on_plane(mesh, base, p, 0.005), figure=held))
    # Lying across the slope, thrown spinning downhill: it rolls over its edges like a square log, several turns.
    for slope, spin, speed, held in ((30.0, 15.0, 0.5, False), (35.0, 10.0, 0.3, False), (32.0, 12.0, 0.4, True)):
        p = incline(slope, 0.0, 0.6)
        cases.append(Case(f"box_tumble_{slope:g}_{spin:g}", f"tumbles: spin {spin:g} rad/s, {speed:g} m/s, {_label(p, 0.0)}", held,
                          _on_plane(mesh, base, p, 0.03, rotation=(math.pi / 2, 0.0, 0.0), velocity=(speed, 0.0, 0.0),
                                    angular_velocity=(0.0, spin, 0.0)), figure=held))
    if small:
        cases = [cases[0], cases[2]]
    return Family("box", mesh, 20 if small else 150, tuple(cases))


def sphere_family(small: bool) -> Family:
    """A soft ball (radius 5 cm) thrown down a slope so that it bounces and rolls."""
    mesh = meshes.sphere(radius=0.05, resolution=4 if small else SPHERE_RESOLUTION)
    base = Scene(material=Material(youngs_modulus=2.0e4, poisson_ratio=0.3, density=1000.0), dt=0.005)
    cases = []
    # Friction on both sides of the held-out 0.3 (as the cheese's 0.2 / 0.8): with mu 0.5 alone, POD(60) of the
    # training frames left 5.0 % of the held-out run and its reduced run ended 11 % of the size away (with 0.2 too: 3.3 %, 4.6 %).
    for slope, mu, held in ((20.0, 0.5, False), (30.0, 0.5, False), (20.0, 0.2, False), (30.0, 0.2, False), (25.0, 0.3, True)):
        p = incline(slope, 0.0, mu)
        cases.append(Case(f"sphere_{slope:g}_{mu:g}", f"rolls: {_label(p, 0.0)}", held,
                          _on_plane(mesh, base, p, 0.1, velocity=(0.5, 0.0, -1.0)), figure=held))
    if small:
        cases = cases[-2:]
    return Family("sphere", mesh, 20 if small else 200, tuple(cases))


FAMILIES: dict[str, Callable[[bool], Family]] = {"cheese": cheese_family, "box": box_family, "sphere": sphere_family}


# --- full runs ------------------------------------------------------------------------------
NUDGED = "_nudged"
"""Name suffix of a scene's noise-floor run (the same scene, :func:`nudged`)."""


def nudged(scene: Scene, offset: tuple[float, float, float] = (0.0, 0.0, NUDGE)) -> Scene:
    """The same scene with the object's start moved by ``offset`` (m; by default dropped ``NUDGE`` higher: the noise
    floor's run)."""
    init = scene.initial
    return scene.replace(initial=dataclasses.replace(init, translation=tuple(np.add(init.translation, offset))))


def _close(a, b) -> bool:
    """Equal scene descriptions up to round-off (the start pose is computed, and numpy builds differ in the last bit)."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_close(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(_close(x, y) for x, y in zip(a, b))
    if isinstance(a, float) or isinstance(b, float):
        return math.isclose(a, b, rel_tol=1e-12, abs_tol=1e-15)
    return a == b


def full_run(work: Path, name: str, mesh: licrom.Mesh, scene: Scene, steps: int, record_every: int = 1,
             impact_window: float = 0.0) -> Trajectory:
    """The full-space run (a frame every ``record_every`` steps, impact frames for ``impact_window`` s after each
    impact), from the cache when it holds this scene, step count and impact window."""
    path = work / "full" / f"{name}.npz"
    if path.exists():
        traj = Trajectory.load(path)
        if (_close(traj.scene.to_dict(), scene.to_dict()) and traj.n_frames == steps // record_every + 1
                and traj.rest_positions.shape == mesh.vertices.shape and traj.info.get("impact_window", 0.0) == impact_window):
            return traj
    t0 = time.perf_counter()
    # looked up here: warp loads only when a run is not cached
    traj = licrom.FullSim(mesh, scene).run(steps, record_every=record_every, impact_window=impact_window)
    traj.save(path, precision="float64")
    print(f"  full {name}: {mesh.n_tets} tets, {steps} steps in {time.perf_counter() - t0:.1f} s "
          f"({traj.iterations.mean():.1f} Newton its/step)", flush=True)
    return traj


# --- metrics --------------------------------------------------------------------------------
def masses_of(traj: Trajectory) -> np.ndarray:
    return traj.mesh.vertex_masses(traj.scene.material.density)


def contact_start(traj: Trajectory) -> int:
    """First frame with a vertex touching a plane (0 if none ever does): where the non-rigid metrics start."""
    return first_contact_frame(traj) or 0


def run_metrics(full: Trajectory, other: Trajectory) -> dict:
    """Non-rigid error, final COM distance / size, stick/slip, peak deformation and rotation of ``other`` against ``full``."""
    c = compare(full, other)
    return {
        "nonrigid_error": c.nonrigid_error,
        "com_error": c.final_com_error,
        "slides": bool(c.slid_reduced),
        "stick_slip_right": bool(c.stick_slip_agree),
        "peak_deformation": c.peak_deformation_reduced,
        "rotation": c.rotation_reduced,
        "step_ms": c.reduced_step_ms,
        "iterations": c.reduced_iterations,
    }


# --- subspace bounds ------------------------------------------------------------------------
def residual_pod(mesh: licrom.Mesh, runs: list[np.ndarray], masses: np.ndarray, r: int, balance: float = RUN_BALANCE) -> MeshBasis:
    """POD(r) of what the mass-weighted affine fit leaves of each run's snapshots (f_k, n, 3), as training does.

    The runs are balanced (:func:`licrom.subspace.basis.run_balanced_weights` with power ``balance``:
    the training's default ``pod_weighting="run"``), so the POD spans what the models
    learn; ``balance=0`` is plain POD. The modes are mass-orthogonal to every affine mode,
    rigid ones included.
    """
    rest = mesh.vertices
    residual = np.concatenate([u - apply_affine(rest, fit_affine(rest, u, masses)) for u in runs])
    run_index = np.concatenate([np.full(len(u), k) for k, u in enumerate(runs)])
    weights = run_balanced_weights(run_index, np.einsum("fni,fni,n->f", residual, residual, masses), power=balance)
    return MeshBasis.pod(mesh, residual, min(r, len(residual)), weights=weights)[0]


def _as_run(full: Trajectory, displacements: np.ndarray) -> Trajectory:
    """``full`` with other displacements (a projection of it), so the metrics of :func:`compare` apply."""
    return dataclasses.replace(full, displacements=displacements, velocities=np.zeros_like(displacements))


def body_displacements(traj: Trajectory) -> np.ndarray:
    return body_frame_displacements(traj.rest_positions + traj.displacements, traj.rest_positions, masses_of(traj))


def world_projection_error(test: Trajectory, values: np.ndarray) -> float:
    """Non-rigid error of the test run projected (mass-weighted) onto world-frame modes ``values`` (n, 3, k)."""
    projected = np.einsum("nik,fk->fni", values, SubspaceProjector(values, masses_of(test)).project(test.displacements))
    return nonrigid_error(test, _as_run(test, projected), start=contact_start(test))


def body_projection_error(test: Trajectory, values: np.ndarray) -> float:
    """Non-rigid error of the test run with its body-frame displacements projected onto body-frame modes ``values`` (n, 3, k).

    Each frame keeps its own rigid fit ``(c, R)`` (exact in the body-frame model); only the
    body-frame displacement is replaced by its mass-weighted projection.
    """
    rest, m = test.rest_positions, masses_of(test)
    c, rot = rigid_fit(rest + test.displacements, rest, m)
    xbar = rest - m @ rest / m.sum()
    d_proj = np.einsum("nik,fk->fni", values, SubspaceProjector(values, m).project(body_displacements(test)))
    projected = c[:, None, :] + np.einsum("fij,fnj->fni", rot, xbar + d_proj) - rest
    return nonrigid_error(test, _as_run(test, projected), start=contact_start(test))


@dataclass
class Setting:
    """A family with its training runs: what the subspaces and reduced runs are built from.

    Attributes:
        family: the family.
        train: its training runs (full space).
        models: folder of the trained models (cached).
        epochs: training epochs of models trained here.
        device: training device (``"auto"``, ``"cpu"``, ``"cuda"``).
        cubatures: the fitted cubatures of :meth:`fitted_cubature` already loaded, by r.
    """

    family: Family
    train: list[Trajectory]
    models: Path
    epochs: int
    device: str = "auto"
    cubatures: dict[int, Cubature] = dataclasses.field(default_factory=dict, init=False, repr=False)

    @property
    def mesh(self) -> licrom.Mesh:
        return self.family.mesh

    @cached_property
    def masses(self) -> np.ndarray:
        return masses_of(self.train[0])

    @cached_property
    def train_u(self) -> list[np.ndarray]:
        """World-frame displacements of each training run's frames from first contact on (the fall adds nothing)."""
        return [t.displacements[contact_start(t):] for t in self.train]

    @cached_property
    def train_d(self) -> list[np.ndarray]:
        """Body-frame displacements of the same frames."""
        return [body_displacements(t)[contact_start(t):] for t in self.train]

    def world_pod(self, r: int) -> StackedBasis:
        return StackedBasis(AffineBasis(), residual_pod(self.mesh, self.train_u, self.masses, r))

    def body_pod(self, r: int, balance: float = RUN_BALANCE) -> MeshBasis:
        return residual_pod(self.mesh, self.train_d, self.masses, r, balance)

    def fitted_cubature(self, r: int) -> Cubature:
        """Optimised cubature of the body-frame model with r learned modes (``Cubature.for_model`` on the training
        runs, to ``CUBATURE_TOLERANCE``), fitted once and cached beside the model."""
        if r in self.cubatures:
            return self.cubatures[r]
        path = self.models / f"{self.family.name}_body_r{r}_e{self.epochs}_cubature_tol{CUBATURE_TOLERANCE:g}.npz"
        if path.exists():
            with np.load(path) as f:
                tets, weights, fit_error = f["tets"], f["weights"], float(f["fit_error"])
            self.cubatures[r] = Cubature(tets, weights, self.mesh.centroids[tets], "optimized", fit_error)
            return self.cubatures[r]
        t0 = time.perf_counter()
        cub = Cubature.for_model(self.model("body", r), self.train, tolerance=CUBATURE_TOLERANCE)
        with atomic_path(path) as tmp, open(tmp, "wb") as f:
            np.savez(f, tets=cub.tets, weights=cub.weights, fit_error=cub.fit_error)
        print(f"  fitted {cub.count} cubature tets of {self.mesh.n_tets} to {cub.fit_error:.1e} for {path.name} "
              f"in {time.perf_counter() - t0:.0f} s", flush=True)
        self.cubatures[r] = cub
        return cub

    def body_basis(self, learned) -> BodyFrameBasis:
        """The 6 symmetric affine modes + ``learned`` (a basis of body-frame displacements), free of rigid motion."""
        return BodyFrameBasis(self.mesh, learned, density=self.family.cases[0].scene.material.density)

    def model(self, frame: str, r: int) -> licrom.Model:
        """The model of this family's training runs in ``frame`` with r learned modes, trained once and cached per epoch count."""
        path = self.models / f"{self.family.name}_{frame}_r{r}_e{self.epochs}.lcm"
        if not path.exists():
            t0 = time.perf_counter()
            licrom.train(self.train, path, TrainConfig(epochs=self.epochs, val_fraction=0.0, progress=False, device=self.device),
                         ModelConfig(latent_dim=r, frame=frame))
            print(f"  trained {path.name} ({self.epochs} epochs) in {time.perf_counter() - t0:.0f} s", flush=True)
        return licrom.Model.load(path)


# --- reduced runs: one function per column, each returning (reduced run, projection error of its subspace) ---
def _reduced(setting: Setting, case: Case, basis) -> Trajectory:
    return ReducedSim(basis, setting.mesh, case.scene, cubature=Cubature.full(setting.mesh)).run(setting.family.steps)


def world_pod_column(setting: Setting, case: Case, full: Trajectory, r: int) -> tuple[Trajectory, float]:
    """World frame, affine + POD(r) of the training frames: what any linear world-frame subspace of this size gives."""
    basis = setting.world_pod(r)
    return _reduced(setting, case, basis), world_projection_error(full, basis.values(setting.mesh.vertices))


def world_model_column(setting: Setting, case: Case, full: Trajectory, r: int) -> tuple[Trajectory, float]:
    """The learned world-frame model (LiCROM as published)."""
    model = setting.model("world", r)
    return _reduced(setting, case, model), world_projection_error(full, model.values(setting.mesh.vertices))


def _body_reduced(setting: Setting, case: Case, basis: BodyFrameBasis, strain: str = "mesh", cubature: Cubature | None = None) -> Trajectory:
    cubature = cubature or Cubature.full(setting.mesh)
    return BodyFrameSim(basis, setting.mesh, case.scene, cubature=cubature, strain=strain).run(setting.family.steps)


def body_model_column(setting: Setting, case: Case, full: Trajectory, r: int) -> tuple[Trajectory, float]:
    """The learned body-frame model: rigid motion exact, learned modes in the body."""
    basis = setting.body_basis(setting.model("body", r))
    return _body_reduced(setting, case, basis), body_projection_error(full, basis.values(setting.mesh.vertices))


def body_model_fitted_cubature_column(setting: Setting, case: Case, full: Trajectory, r: int) -> tuple[Trajectory, float]:
    """The learned body-frame model with optimised cubature fitted to its training runs, as a user would run it."""
    basis = setting.body_basis(setting.model("body", r))
    reduced = _body_reduced(setting, case, basis, cubature=setting.fitted_cubature(r))
    return reduced, body_projection_error(full, basis.values(setting.mesh.vertices))


def body_model_field_strain_column(setting: Setting, case: Case, full: Trajectory, r: int) -> tuple[Trajectory, float]:
    """The same learned body-frame model with the field's own gradient as its strain (``strain="field"``, as LiCROM)."""
    basis = setting.body_basis(setting.model("body", r))
    return _body_reduced(setting, case, basis, "field"), body_projection_error(full, basis.values(setting.mesh.vertices))


def body_pod_column(setting: Setting, case: Case, full: Trajectory, r: int) -> tuple[Trajectory, float]:
    """The body-frame model with POD(r) of the training frames' body-frame displacements as its modes."""
    basis = setting.body_basis(setting.body_pod(r))
    return _body_reduced(setting, case, basis), body_projection_error(full, basis.values(setting.mesh.vertices))


def own_body_pod_column(setting: Setting, case: Case, full: Trajectory, r: int) -> tuple[Trajectory, float]:
    """The body-frame model with POD(r) of the held-out run's own body-frame displacements: the dynamics alone, no training gap."""
    own = body_displacements(full)[contact_start(full):]
    basis = setting.body_basis(residual_pod(setting.mesh, [own], setting.masses, r))
    return _body_reduced(setting, case, basis), body_projection_error(full, basis.values(setting.mesh.vertices))


OWN = "own body POD"
FITTED = "body model, fitted cubature"
COLUMNS: dict[str, Callable[[Setting, Case, Trajectory, int], tuple[Trajectory, float]]] = {
    "world POD": world_pod_column,
    "world model": world_model_column,
    "body POD": body_pod_column,
    "body model": body_model_column,
    FITTED: body_model_fitted_cubature_column,
    "body model, field strain": body_model_field_strain_column,
    OWN: own_body_pod_column,
}


# --- report ---------------------------------------------------------------------------------
def _pct(x: float | None) -> str:
    return "-" if x is None else f"{100 * x:.1f} %"


def meets_defaults_targets(run: dict, floor: dict | None) -> bool:
    """Whether a reduced run (``nonrigid_error``, ``com_error``, ``stick_slip_right``) meets the defaults' targets: non-rigid
    < 10 %, centre of mass < 2 % of the size, stick/slip right; a chaotic scene (its noise ``floor`` above
    :data:`CHAOTIC_FLOOR`) within 3x its floor instead."""
    if floor is not None and max(floor["nonrigid_error"], floor["com_error"]) > CHAOTIC_FLOOR:
        return (run["nonrigid_error"] <= max(NONRIGID_TARGET, 3 * floor["nonrigid_error"])
                and run["com_error"] <= max(COM_TARGET, 3 * floor["com_error"]))
    return run["nonrigid_error"] < NONRIGID_TARGET and run["com_error"] < COM_TARGET and run["stick_slip_right"]


def targets(row: dict) -> tuple[float, float]:
    """(non-rigid error, final COM / size) targets of a held-out run: 15 % and 2 %, or 3x the noise floor when chaotic."""
    floor = row["noise_floor"]
    if not row["chaotic"]:
        return 0.15, 0.02
    return max(0.15, 3 * floor["nonrigid_error"]), max(0.02, 3 * floor["com_error"])


def verdict(row: dict, run: dict) -> str:
    """Which targets a reduced run meets, and for a miss whether the subspace or the dynamics is to blame.

    The subspace is to blame when its projection error alone is above the target, or, for a
    body-frame run, when the body-frame solver with the run's own modes (same r, no training
    gap) meets every target: then the dynamics are sound and what the training subspace lacks
    is what goes wrong.
    """
    t_nr, t_com = targets(row)
    misses = []
    if run["nonrigid_error"] > t_nr:
        misses.append(f"non-rigid > {_pct(t_nr)}")
    if run["com_error"] > t_com:
        misses.append(f"COM > {_pct(t_com)}")
    if not run["stick_slip_right"]:
        misses.append("stick/slip wrong")
    if not misses:
        return "meets"
    own = [o for o in row["reduced"] if o["column"] == OWN and o["r"] == run["r"]]
    if run["bound"] > t_nr:
        blame = f"subspace (its projection leaves {_pct(run['bound'])})"
    elif run["column"].startswith("body") and own and verdict(row, own[0]) == "meets":
        blame = f"subspace (projection {_pct(run['bound'])}; with the run's own {run['r']} modes the same solver meets the targets)"
    else:
        blame = f"dynamics (the subspace holds the run to {_pct(run['bound'])})"
    return "misses " + ", ".join(misses) + ": " + blame


def held_out_table(rows: list[dict], pod_sizes: tuple[int, ...]) -> str:
    head = ["family", "held-out run", "tets", "peak def.", "rotation", "full", "noise floor (non-rigid / COM)",
            *(f"{f}{r}" for r in pod_sizes for f in ("world POD", "body POD", "own body POD", "learned body "))]
    out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in rows:
        nf = row["noise_floor"]
        out.append("| " + " | ".join([
            row["family"], row["kind"], str(row["tets"]), _pct(row["peak_deformation"]), f"{row['rotation']:.0f} deg",
            "slides" if row["slides"] else "sticks",
            f"{_pct(nf['nonrigid_error'])} / {_pct(nf['com_error'])}" + (" chaotic" if row["chaotic"] else ""),
            *(_pct(row["bounds"].get(f"{f}{r}")) for r in pod_sizes for f in ("world", "body", "own", "learned")),
        ]) + " |")
    return "\n".join(out)


def learned_table(rows: list[dict], sizes: list[int]) -> str:
    """The learned body-frame modes' projection error against body POD of the same size and frames: balanced as they
    were trained, and plain (every frame the same), whose 1.2x is the bound a learned subspace must reach."""
    sizes = [r for r in sizes if any(f"learned{r}" in row["bounds"] for row in rows)]
    head = ["held-out run", *(f"r = {r}: learned / balanced POD / plain POD" for r in sizes),
            *(f"r = {r}: learned over balanced, over plain" for r in sizes)]
    out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in rows:
        b = row["bounds"]
        out.append("| " + " | ".join([
            f"{row['family']}: {row['kind']}",
            *(f"{_pct(b[f'learned{r}'])} / {_pct(b[f'body{r}'])} / {_pct(b[f'plain{r}'])}" for r in sizes),
            *(f"{b[f'learned{r}'] / b[f'body{r}']:.3f}x, {b[f'learned{r}'] / b[f'plain{r}']:.3f}x" for r in sizes),
        ]) + " |")
    return "\n".join(out)


def reduced_table(rows: list[dict]) -> str:
    out = ["| held-out run | subspace | r | projection | non-rigid error | final COM / size | full / reduced | "
           "peak def. full / reduced | rotation full / reduced | ms/step (Newton its) | cubature tets | verdict |", "|" + "---|" * 12]
    for row in rows:
        for run in row["reduced"]:
            out.append(
                f"| {row['family']}: {row['kind']} | {run['column']} | {run['r']} | {_pct(run['bound'])} | {_pct(run['nonrigid_error'])} | "
                f"{_pct(run['com_error'])} | {'slides' if row['slides'] else 'sticks'} / {'slides' if run['slides'] else 'sticks'} | "
                f"{_pct(row['peak_deformation'])} / {_pct(run['peak_deformation'])} | {row['rotation']:.0f} / {run['rotation']:.0f} deg | "
                f"{run['step_ms']:.2f} ({run['iterations']:.1f}) | {run.get('cubature', row['tets'])} | {verdict(row, run)} |")
    return "\n".join(out)


def summary_table(rows: list[dict]) -> str:
    """Per subspace and r: held-out runs meeting every target, and how much the reduced run adds to its projection error."""
    out = ["| subspace | r | meets every target | non-rigid error / projection error (median) | final COM / size (median) |",
           "|---|---|---|---|---|"]
    keys = dict.fromkeys((run["column"], run["r"]) for row in rows for run in row["reduced"])
    for column, r in keys:
        runs = [(row, run) for row in rows for run in row["reduced"] if (run["column"], run["r"]) == (column, r)]
        meets = [row["name"] for row, run in runs if verdict(row, run) == "meets"]
        ratio = np.median([run["nonrigid_error"] / run["bound"] for _, run in runs])
        com = np.median([run["com_error"] for _, run in runs])
        out.append(f"| {column} | {r} | {len(meets)}/{len(runs)} | {ratio:.1f}x | {_pct(com)} |")
    return "\n".join(out)


def training_table(rows: list[dict]) -> str:
    out = ["| family | training run | peak def. | rotation | full | full run s |", "|---|---|---|---|---|---|"]
    for row in rows:
        out.append(f"| {row['family']} | {row['kind']} | {_pct(row['peak_deformation'])} | {row['rotation']:.0f} deg | "
                   f"{'slides' if row['slides'] else 'sticks'} | {row['wall_s']:.1f} |")
    return "\n".join(out)


def write_section(docs: Path, text: str, title: str = SECTION_TITLE) -> None:
    """Put ``text`` in place of the section headed ``title`` (default section 10) of ``docs/results.md`` (appended if absent), atomically.

    A ``### Reading`` subsection of the old section (written by hand) is kept after the new tables.
    """
    path = docs / "results.md"
    before, found, after = (path.read_text() if path.exists() else "").partition(title)
    end = after.find("\n## ") if found else -1
    old, rest = (after, "") if end < 0 else (after[:end], after[end:])
    reading = old[old.find(READING):].rstrip("\n") + "\n" if found and READING in old else ""
    with atomic_path(path) as tmp:
        tmp.write_text(before.rstrip("\n") + "\n\n" + text.rstrip("\n") + "\n" + ("\n" + reading if reading else "") + rest)


INTRO = (
    "Scenes of our own, not tuned for the model: a soft cheese (E = 20 kPa, 864 tets, dropped from 6 cm) on inclines "
    "whose downhill direction is along x (azimuth 0) or off-axis (azimuth from +x), a tall soft box (4 x 4 x 12 cm, "
    "432 tets) that tips over once on a slope or is thrown spinning to tumble down it like a square log, and a soft ball "
    "(1074 tets, h = 5 ms) bouncing and rolling down a slope; h = 10 ms otherwise, 1.5 s (ball 1 s). Training runs, "
    "with each run's peak non-rigid deformation (largest body-frame displacement / size), total rotation and outcome "
    "(`licrom.compare`):"
)
BOUNDS_INTRO = (
    "Held-out runs. Noise floor: the full run against itself dropped 0.1 mm higher (non-rigid error / final centre-of-mass "
    "distance over the size); above 2 % the scene is chaotic and its targets are 3x the floor. Subspace bounds: the "
    "non-rigid error (compare's: each frame's own best rigid fit removed, mass-weighted, from first contact) of the run "
    "projected onto affine + POD(r) of the training frames in the world frame, onto the 6 symmetric affine modes + POD(r) "
    "of the training frames' body-frame displacements (the rigid motion kept exact), and onto the same built from the "
    "run's own frames; and onto the learned body-frame model's modes (with the same 6 affine modes), which should come "
    "within 1.2x of body POD of its size. POD of the training frames balances the training runs "
    f"(`run_balanced_weights`, power {RUN_BALANCE:g}, as the training does by default), so that it spans what the models learn."
)
LEARNED_INTRO = (
    "The learned body-frame modes against body POD of the same size and training frames (each with the 6 symmetric "
    "affine modes; body-frame projection error of each held-out run, as above): balanced as the models are trained, and "
    "plain, every frame counting the same, within 1.2x of which a learned subspace must come."
)
REDUCED_INTRO = (
    "Reduced runs, every tet a cubature point (except in one column) and every boundary vertex a contact point: `world POD` (`ReducedSim`, affine + "
    "POD(r) of the training frames), `world model` (the learned world-frame model, LiCROM's network), `body POD` "
    "(`BodyFrameSim` with `BodyFrameBasis(mesh, MeshBasis(mesh, POD(r) of the training frames' body-frame displacements))`), "
    "`body model` (the learned body-frame model), `body model, fitted cubature` (the same model with the optimised cubature "
    f"a user would run it with: `Cubature.for_model(model, training runs, tolerance={CUBATURE_TOLERANCE:g})`), "
    "`body model, field strain` (the same model with the field's own gradient "
    "as its strain, `strain=\"field\"` as LiCROM publishes, instead of the default linear-tet gradient of its vertex values) "
    "and `own body POD` (`BodyFrameSim` with POD(r) of the held-out run's own "
    "body-frame displacements: no training gap, so what it misses is the reduced dynamics). Models: 200 epochs of the "
    f"POD objective, runs balanced with power {RUN_BALANCE:g} (`--train-only world|body --r 20|40|60 --epochs 200 --device cuda`, one process per model, "
    "122-163 s each for the box and the ball, 12 at once, and 357-365 s for the cheese, 6 at once, on one H100). Each run "
    "stands beside the projection error of its own subspace. Targets: non-rigid error < 15 %, final COM within 2 % of "
    "the size, stick/slip right (chaotic: 3x the floor). A miss is put on the subspace when its projection error alone "
    "is above the target, or (body-frame runs) when `own body POD` of the same r meets every target (the solver is then sound and the "
    "training subspace is what is missing), else on the reduced dynamics. ms/step: median wall time of a reduced step here (2 shared "
"cores, other jobs running), with mean Newton iterations."
)


# --- main -----------------------------------------------------------------------------------
def held_out_row(setting: Setting, case: Case, work: Path, columns: list[str], sizes: list[int], pod_sizes: tuple[int, ...],
                 figs: Path | None) -> dict:
    """Noise floor, subspace bounds and reduced runs of one held-out run (and its filmstrip into ``figs``)."""
    fam, mesh = setting.family, setting.mesh
    full = full_run(work, case.name, mesh, case.scene, fam.steps)
    floor = run_metrics(full, full_run(work, case.name + NUDGED, mesh, nudged(case.scene), fam.steps))
    own_d = body_displacements(full)[contact_start(full):]
    bounds = {}
    for r in pod_sizes:
        bounds[f"world{r}"] = world_projection_error(full, setting.world_pod(r).values(mesh.vertices))
        for key, learned in (("body", setting.body_pod(r)), ("own", residual_pod(mesh, [own_d], setting.masses, r))):
            bounds[f"{key}{r}"] = body_projection_error(full, setting.body_basis(learned).values(mesh.vertices))
    for r in sizes if any("model" in name for name in columns) else ():  # POD columns alone need no trained model
        bounds[f"learned{r}"] = body_projection_error(full, setting.body_basis(setting.model("body", r)).values(mesh.vertices))
        for key, balance in (("body", RUN_BALANCE), ("plain", 0.0)):
            if f"{key}{r}" not in bounds:
                bounds[f"{key}{r}"] = body_projection_error(full, setting.body_basis(setting.body_pod(r, balance)).values(mesh.vertices))
    own = run_metrics(full, full)
    row = {"family": fam.name, "name": case.name, "kind": case.kind, "tets": mesh.n_tets, "peak_deformation": own["peak_deformation"],
           "rotation": own["rotation"], "slides": own["slides"], "noise_floor": floor,
           "chaotic": max(floor["nonrigid_error"], floor["com_error"]) > CHAOTIC_FLOOR, "bounds": bounds, "reduced": [],
           "figure": f"figures/body_frame_{case.name}.png" if figs is not None and case.figure else None}
    print(f"  {case.name}: peak {_pct(row['peak_deformation'])}, rotation {row['rotation']:.0f} deg, "
          f"floor {_pct(floor['nonrigid_error'])} / {_pct(floor['com_error'])}, "
          + ", ".join(f"{k} {_pct(v)}" for k, v in bounds.items()), flush=True)
    strip = {"full": full}
    for name in columns:
        for r in sizes:
            reduced, bound = COLUMNS[name](setting, case, full, r)
            if r == sizes[0]:
                strip[f"{name} r{r}"] = reduced
            run = {"column": name, "r": r, "bound": bound, **run_metrics(full, reduced)}
            if name == FITTED:
                run["cubature"] = setting.fitted_cubature(r).count
            row["reduced"].append(run)
            print(f"    {name} r {r}: non-rigid {_pct(run['nonrigid_error'])} (projection {_pct(bound)}), COM {_pct(run['com_error'])}, "
                  f"{verdict(row, run)}", flush=True)
    if figs is not None and case.figure:
        filmstrip(list(strip.values()), list(strip), figs / f"body_frame_{case.name}.png", title=f"{fam.name}: {case.kind}",
                  renderer=pick_renderer()[0])
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--work", type=Path, default=Path("out/body_frame"))
    ap.add_argument("--docs", type=Path, default=Path("docs"))
    ap.add_argument("--families", nargs="+", default=list(FAMILIES), choices=list(FAMILIES))
    ap.add_argument("--columns", nargs="*", default=list(COLUMNS), choices=list(COLUMNS), help="reduced runs to make")
    ap.add_argument("--r", type=int, nargs="+", default=[20], help="learned / POD modes of the reduced runs")
    ap.add_argument("--epochs", type=int, default=200, help="epochs of the models trained here")
    ap.add_argument("--train-only", nargs="*", choices=("world", "body"), metavar="FRAME",
                    help="only make the training runs and train the models of these frames (none: the runs alone), then stop; writes nothing under --docs")
    ap.add_argument("--device", default="auto", help="training device: auto, cpu or cuda")
    ap.add_argument("--small", action="store_true", help="tiny meshes, few steps: a smoke test that writes nothing under --docs")
    ap.add_argument("--cheese-resolution", type=int, default=CHEESE_RESOLUTION, help="cheese mesh resolution (8: 864 tets, 10: 1638)")
    args = ap.parse_args()
    globals()["CHEESE_RESOLUTION"] = args.cheese_resolution
    work = args.work / "small" if args.small else args.work
    sizes = [min(r, 4) for r in args.r] if args.small else args.r
    pod_sizes = (4,) if args.small else POD_SIZES
    epochs = 1 if args.small else args.epochs
    t_start = time.perf_counter()
    train_rows, test_rows = [], []
    for fam_name in args.families:
        fam = FAMILIES[fam_name](args.small)
        print(f"{fam.name}: {fam.mesh.n_tets} tets, {fam.mesh.n_vertices} vertices, {len(fam.cases)} runs of {fam.steps} steps", flush=True)
        train = []
        for case in fam.training:
            traj = full_run(work, case.name, fam.mesh, case.scene, fam.steps)
            train.append(traj)
            own = run_metrics(traj, traj)
            train_rows.append({"family": fam.name, "name": case.name, "kind": case.kind, "peak_deformation": own["peak_deformation"],
                               "rotation": own["rotation"], "slides": own["slides"], "wall_s": float(traj.step_seconds.sum())})
        setting = Setting(fam, train, work / "models", epochs, args.device)
        if args.train_only is not None:
            for frame in args.train_only:
                for r in sizes:
                    setting.model(frame, r)
            continue
        figs = None if args.small else args.docs / "figures"
        test_rows += [held_out_row(setting, case, work, args.columns, sizes, pod_sizes, figs) for case in fam.held_out]
    wall = time.perf_counter() - t_start
    with atomic_path(work / "results.json") as tmp:
        tmp.write_text(json.dumps({"training": train_rows, "held_out": test_rows, "wall_s": wall}, indent=1))
    print(f"wrote {work / 'results.json'} ({wall:.0f} s)")
    if args.small or args.train_only is not None:
        return
    write_section(args.docs, f"{SECTION_TITLE}\n\nMeasured by `python experiments/body_frame_experiments.py` on "
                  f"{platform.processor() or platform.machine()}, {time.strftime('%Y-%m-%d')}; wall time {wall:.0f} s "
                  "(full runs and models cached; the models trained on an H100 with `--train-only`, see below).\n\n" + INTRO + "\n\n"
                  + training_table(train_rows) + "\n\n" + BOUNDS_INTRO + "\n\n" + held_out_table(test_rows, pod_sizes) + "\n\n"
                  + (LEARNED_INTRO + "\n\n" + learned_table(test_rows, sizes) + "\n\n" if any("model" in c for c in args.columns) else "")
                  + REDUCED_INTRO + "\n\n" + summary_table(test_rows) + "\n\n" + reduced_table(test_rows) + "\n\n"
                  + f"Filmstrips: the full run, then each subspace at r = {sizes[0]}.\n\n"
                  + "\n\n".join(f"![{row['family']}: {row['kind']}]({row['figure']})" for row in test_rows if row["figure"]) + "\n")

if __name__ == "__main__":
    main()
