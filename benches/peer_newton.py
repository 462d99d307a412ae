"""Peer comparison: the dropped-cheese scene in licrom's FullSim and in the ``newton`` physics package.

The same cheese mesh, material, gravity, inclined plane and initial drop are simulated by
both for one second of simulated time, on a slope where the cheese slides (30 degrees,
mu 0.3) and one where Coulomb friction holds it (15 degrees, mu 0.6). One table is printed:
wall time per 10 ms of simulated time (one licrom step), the centre-of-mass path, the slide
along the slope beside a rigid-block Coulomb estimate, the deepest penetration, and how far
each licrom centre of mass is from newton's as a fraction of the object's size. licrom runs
twice: at its own 10 ms step, and at newton's substep, which tells what the two models do
differently from what the time step does (the cheese lands on an edge and tips flat; a
10 ms backward-Euler step absorbs much of that impact, a 0.5 ms one does not). A PNG of the
centre-of-mass travel along the slope against time is written to ``--out``.

    python benches/peer_newton.py --resolution 8 --device cpu --out licrom-out/peer

``newton`` is an optional extra: ``pip install 'licrom[peer]'`` (or ``pip install newton``).

How newton is set up, and why
-----------------------------
* Solver: ``SolverVBD`` (Vertex Block Descent). It is newton's implicit solver for volumetric
  tet meshes with penalty contact and IPC-style Coulomb friction against collision shapes.
  ``SolverSemiImplicit`` also steps tets, but explicitly: it needs ~100 substeps per 10 ms
  and uses a different contact model; ``SolverXPBD`` and ``SolverStyle3D`` target
  constraints and cloth. VBD is a block Gauss-Seidel on the same backward-Euler incremental
  potential that licrom minimises with Newton's method, so the two are comparable.
* Time step: VBD needs substeps for accuracy. Each 10 ms licrom step is ``substeps`` VBD
  steps (default 20, i.e. 0.5 ms) of ``iterations`` sweeps (default 10), with collision
  detection every substep (as newton's examples do). Fewer substeps dissipate the landing
  impact (backward Euler's numerical damping grows with the step), which changes how far the
  cheese travels after it tips onto the slope; 20 substeps is where that converges here.
  One 10 ms VBD step is no option: its sweeps do not converge the friction, and the block
  slides with 40% more than the Coulomb acceleration at 10 iterations (17% at 50).
* Material: newton's ``k_mu``/``k_lambda`` are the *Lame* parameters; its VBD kernel maps
  them to stable Neo-Hookean constants itself (``mu, lambda + mu``, the energy without the
  log term), as licrom maps them to ``4/3 mu, lambda + 5/6 mu`` (the energy with it). Both
  match linear elasticity at small strain, so ``Material.lame`` goes in unchanged. No
  material damping (``k_damp = 0``): licrom has none either.
* Contact: licrom's penalty is per unit area (``k_n`` in N/m^3, each boundary vertex
  carrying its share ``a_v`` of the surface), newton's is one stiffness per particle (N/m).
  We pass ``k_n * mean(a_v)`` over the boundary vertices. Newton averages the particle and
  shape stiffnesses (arithmetic mean) and frictions (geometric mean), so both sides get the
  same value. Particle radius 0: the contact surface is the plane itself, as in licrom.
  Normal damping maps the same way (``k_d * mean(a_v)``, N s/m).
* Friction: licrom's law is ``|f_t| = min(k_f a |v_t|, mu f_n)`` (saturating at the slip
  speed ``mu p / k_f`` for contact pressure ``p``); newton's is IPC's smoothed Coulomb, which
  saturates at the slip speed ``friction_epsilon`` (m/s). We set ``friction_epsilon =
  mu p / k_f`` with ``p`` the weight's normal component over the block's footprint, so both
  reach full Coulomb friction at the same slip speed. licrom lags ``f_n`` by a step; newton
  uses the current one.
"""

from __future__ import annotations

import argparse
import math
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import licrom
import numpy as np
from licrom.analysis.compare import penetration_depths

__all__ = [
    "CASES",
    "Case",
    "NewtonSettings",
    "coulomb_slide",
    "format_table",
    "main",
    "make_scene",
    "motion_metrics",
    "newton_contact_parameters",
    "plot_travel",
    "run_case",
    "run_licrom",
    "run_newton",
]

FRAME_DT = 0.01  # s: licrom's time step, and the unit per-step times are reported in
WARMUP_FRAMES = 5  # frames left out of the timing median (kernel compile, allocation)


@dataclass(frozen=True)
class Case:
    """One scene of the comparison: a slope and its friction coefficient."""

    name: str
    angle_deg: float
    friction: float


CASES = (Case("slide", 30.0, 0.3), Case("stick", 15.0, 0.6))


@dataclass(frozen=True)
class NewtonSettings:
    """How newton steps one 10 ms frame.

    Attributes:
        substeps: VBD steps per 10 ms frame.
        iterations: VBD sweeps per substep.
        contact_gap: collision detection distance beyond contact, m (detection only).
        friction_epsilon: IPC friction regularisation speed, m/s; ``None`` derives it from
            licrom's friction stiffness (see :func:`newton_contact_parameters`).
    """

    substeps: int = 20
    iterations: int = 10
    contact_gap: float = 0.01
    friction_epsilon: float | None = None


def make_scene(mesh: licrom.Mesh, case: Case, drop: float = 0.01, dt: float = FRAME_DT) -> licrom.Scene:
    """The dropped-cheese scene: default material and contact, one incline, the lowest point ``drop`` above it."""
    plane = licrom.Plane.incline(case.angle_deg, case.friction)
    n = np.asarray(plane.normal)
    lowest = float((mesh.vertices @ n).min()) + plane.offset
    # A vertical lift of h raises every gap by h * n_z.
    lift = (drop - lowest) / n[2]
    return licrom.Scene(planes=(plane,), dt=dt, initial=licrom.InitialState(translation=(0.0, 0.0, lift)))


def newton_contact_parameters(mesh: licrom.Mesh, scene: licrom.Scene) -> dict[str, float]:
    """Map licrom's per-area contact and friction parameters to newton's per-particle ones.

    Returns ``ke`` (N/m), ``kd`` (N s/m) and ``friction_epsilon`` (m/s).
    """
    c = scene.contact
    plane = scene.planes[0]
    area = float(np.mean(mesh.boundary_vertex_areas))  # mean share of the surface per boundary vertex
    mass = float(mesh.vertex_masses(scene.material.density).sum())
    g = float(np.linalg.norm(scene.gravity))
    lo, hi = mesh.bounds
    footprint = float((hi[0] - lo[0]) * (hi[1] - lo[1]))
    pressure = mass * g * abs(plane.normal[2]) / footprint  # mean contact pressure at rest, Pa
    return {
        "ke": c.normal_stiffness * area,
        "kd": c.normal_damping * area,
        # licrom's friction saturates at slip speed mu p / k_f; IPC friction saturates at epsilon.
        "friction_epsilon": max(plane.friction * pressure / c.friction_stiffness, 1e-6),
    }


def _sync(wp: Any, device: str) -> None:
    if device != "cpu":
        wp.synchronize_device(device)


def run_newton(
    mesh: licrom.Mesh,
    scene: licrom.Scene,
    frames: int,
    device: str = "cpu",
    settings: NewtonSettings = NewtonSettings(),
) -> licrom.Trajectory:
    """Simulate ``scene`` in newton for ``frames`` frames of ``scene.dt``; return a licrom Trajectory.

    ``step_seconds`` holds the wall time of each frame (all its substeps, collision detection
    included; reading positions back is not). On CUDA the frame is captured once as a graph.
    """
    try:
        import newton
        import warp as wp
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise SystemExit("newton is not installed: pip install 'licrom[peer]'  (or: pip install newton)") from exc
    wp.config.quiet = True

    if len(scene.planes) != 1:
        raise ValueError("the peer comparison expects exactly one plane")
    plane = scene.planes[0]
    mat = scene.material
    k_mu, k_lambda = mat.lame  # newton converts Lame parameters to its Neo-Hookean constants itself
    contact = newton_contact_parameters(mesh, scene)
    eps = contact["friction_epsilon"] if settings.friction_epsilon is None else settings.friction_epsilon

    masses = mesh.vertex_masses(mat.density)
    x0, v0 = scene.initial.apply(mesh.vertices, masses)

    builder = newton.ModelBuilder(gravity=scene.gravity)
    shape_cfg = newton.ModelBuilder.ShapeConfig(ke=contact["ke"], kd=contact["kd"], mu=plane.friction)
    # newton's plane (a, b, c, d) is a x + b y + c z + d = 0 with the solid on the +normal side;
    # licrom's is n . x + offset >= 0. width = length = 0 makes it infinite.
    builder.add_shape_plane(plane=(*plane.normal, plane.offset), width=0.0, length=0.0, cfg=shape_cfg)
    with warnings.catch_warnings():
        # The procedural cheese has surface edges shared by more than two boundary
        # triangles where cells touch along an edge; newton's surface check warns about
        # them. They matter only for self-contact, which is off.
        warnings.filterwarnings("ignore", message=".*non-manifold.*")
        builder.add_soft_mesh(
            pos=wp.vec3(0.0, 0.0, 0.0),  # vertices are already placed by scene.initial
            rot=wp.quat_identity(),
            scale=1.0,
            vel=wp.vec3(0.0, 0.0, 0.0),  # set per particle below
            vertices=x0.astype(np.float32),
            indices=mesh.tets.reshape(-1).astype(np.int32),
            density=mat.density,
            k_mu=k_mu,
            k_lambda=k_lambda,
            k_damp=0.0,
            particle_radius=0.0,
        )
    builder.color()  # VBD's Gauss-Seidel needs a vertex colouring
    model = builder.finalize(device=device)
    # Particle-side contact material; newton averages it with the shape's (set equal above).
    model.soft_contact_ke = contact["ke"]
    model.soft_contact_kd = contact["kd"]
    model.soft_contact_mu = plane.friction

    pipeline = newton.CollisionPipeline(model, soft_contact_gap=settings.contact_gap)
    contacts = pipeline.contacts()
    solver = newton.solvers.SolverVBD(
        model,
        iterations=settings.iterations,
        friction_epsilon=eps,
        particle_enable_self_contact=False,
    )
    state_0, state_1 = model.state(), model.state()
    control = model.control()
    state_0.particle_qd.assign(v0.astype(np.float32))
    sub_dt = scene.dt / settings.substeps

    def frame() -> None:
        nonlocal state_0, state_1
        for _ in range(settings.substeps):
            state_0.clear_forces()
            pipeline.collide(state_0, contacts)
            solver.step(state_0, state_1, control, contacts, sub_dt)
            state_0, state_1 = state_1, state_0

    rest = mesh.vertices
    disp, vels, seconds = [x0 - rest], [v0], []
    graph = None
    for f in range(frames):
        # On CUDA, after one plain frame (compile, allocation), record a frame as a graph and
        # replay it. An even substep count ends every frame with the newest state in
        # state_0, so each replay reads and writes the same buffers.
        if f == 1 and device != "cpu" and settings.substeps % 2 == 0:
            try:
                with wp.ScopedCapture(device=device) as capture:
                    frame()
                graph = capture.graph
            except Exception as exc:  # pragma: no cover - capture unsupported: step uncaptured
                warnings.warn(f"CUDA graph capture failed, stepping newton without it: {exc}", stacklevel=2)
        start = time.perf_counter()
        if graph is not None:
            wp.capture_launch(graph)
        else:
            frame()
        _sync(wp, device)
        seconds.append(time.perf_counter() - start)
        disp.append(state_0.particle_q.numpy().astype(np.float64) - rest)
        vels.append(state_0.particle_qd.numpy().astype(np.float64))
    return licrom.Trajectory(
        rest_positions=rest,
        tets=mesh.tets,
        displacements=np.stack(disp),
        velocities=np.stack(vels),
        times=scene.dt * np.arange(len(disp)),
        scene=scene,
        step_seconds=np.asarray(seconds),
        info={
            "source": f"newton {newton.__version__} SolverVBD",
            "substeps": settings.substeps,
            "iterations": settings.iterations,
            "contact_ke": contact["ke"],
            "contact_kd": contact["kd"],
            "friction_epsilon": eps,
            "cuda_graph": graph is not None,
        },
    )


def run_licrom(mesh: licrom.Mesh, scene: licrom.Scene, frames: int, device: str = "cpu") -> licrom.Trajectory:
    """Simulate ``scene`` with licrom's full-space solver for ``frames`` steps of ``scene.dt``."""
    return licrom.FullSim(mesh, scene, device=device).run(frames)


def coulomb_slide(scene: licrom.Scene, drop: float, duration: float) -> float:
    """Centre-of-mass travel down the slope after ``duration`` for a rigid block (analytic).

    The block falls ``drop`` (measured along the normal) and lands flat, with downhill speed
    ``g sin(theta) t_land`` and normal speed ``g cos(theta) t_land``; a perfectly inelastic
    impact lets friction take up to ``mu`` times the normal impulse off the downhill speed;
    then it slides with ``a = g (sin(theta) - mu cos(theta))``, or decelerates to rest when
    ``a < 0``. The cheese lands on an edge and tips flat instead, which gains it speed, so
    the simulations travel further; ``late_accel`` in :func:`motion_metrics` checks the
    Coulomb law itself.
    """
    plane = scene.planes[0]
    g = float(np.linalg.norm(scene.gravity))
    sin_t, cos_t = math.sqrt(max(0.0, 1.0 - plane.normal[2] ** 2)), abs(plane.normal[2])
    t_land = math.sqrt(2.0 * drop / (g * cos_t))
    fall = 0.5 * g * sin_t * t_land**2
    v_t, v_n = g * sin_t * t_land, g * cos_t * t_land
    v0 = max(0.0, v_t - plane.friction * v_n)
    a = g * (sin_t - plane.friction * cos_t)
    tau = max(0.0, duration - t_land)
    if a < 0.0 and v0 > 0.0:
        tau = min(tau, v0 / -a)
    elif a < 0.0:
        tau = 0.0
    return fall + v0 * tau + 0.5 * a * tau**2


def _downhill(scene: licrom.Scene) -> np.ndarray:
    n = np.asarray(scene.planes[0].normal)
    d = np.array([n[2], 0.0, -n[0]])  # in the plane, pointing down the slope (x-z plane)
    return d / np.linalg.norm(d)


def motion_metrics(traj: licrom.Trajectory, drop: float = 0.01) -> dict[str, Any]:
    """Centre-of-mass path, slide along the slope, its late acceleration, penetration, step time.

    ``frame_ms`` is the median wall time per 10 ms of simulated time (a trajectory stepped
    with a smaller ``dt`` counts ``10 ms / dt`` steps per frame), warm-up steps left out.
    """
    scene = traj.scene
    com = traj.centers_of_mass()
    travel = (com - com[0]) @ _downhill(scene)
    t = traj.times
    late = t >= 0.5 * t[-1]  # after landing and tipping: the steady slide (or rest)
    accel = 2.0 * np.polyfit(t[late], travel[late], 2)[0] if late.sum() >= 3 else float("nan")
    plane = scene.planes[0]
    g = float(np.linalg.norm(scene.gravity))
    sin_t, cos_t = math.sqrt(max(0.0, 1.0 - plane.normal[2] ** 2)), abs(plane.normal[2])
    per_frame = FRAME_DT / scene.dt
    steps = traj.step_seconds[round(WARMUP_FRAMES * per_frame) :]
    return {
        "times": t,
        "com": com,
        "travel": travel,
        "final_com": com[-1],
        "slide": float(travel[-1]),
        "coulomb_slide": coulomb_slide(scene, drop, float(t[-1])),
        "late_accel": float(accel),
        "coulomb_accel": max(0.0, g * (sin_t - plane.friction * cos_t)),
        "max_penetration": float(penetration_depths(traj).max()),
        "frame_ms": 1e3 * float(np.median(steps)) * per_frame if len(steps) else float("nan"),
        "size": traj.mesh.size,
        "dt": scene.dt,
        "info": traj.info,
    }


def _com_on_frames(m: dict[str, Any]) -> np.ndarray:
    """Centre of mass at the 10 ms frames (a finer trajectory is subsampled)."""
    stride = round(FRAME_DT / m["dt"])
    return m["com"][::stride]


def run_case(
    mesh: licrom.Mesh,
    case: Case,
    duration: float = 1.0,
    device: str = "cpu",
    settings: NewtonSettings = NewtonSettings(),
    drop: float = 0.01,
    matched_dt: bool = True,
) -> dict[str, dict[str, Any]]:
    """Run one case in both simulators; metrics per run.

    Runs licrom at its 10 ms step, newton (10 ms frames of ``settings.substeps`` substeps)
    and, with ``matched_dt``, licrom again at newton's substep, which separates what the
    models do differently from what the time step does. Each licrom run gets
    ``com_gap_final`` / ``com_gap_max``: its centre-of-mass distance from newton's at the
    10 ms frames, as a fraction of the object's size.
    """
    scene = make_scene(mesh, case, drop)
    frames = round(duration / scene.dt)
    runs = {"licrom": motion_metrics(run_licrom(mesh, scene, frames, device), drop)}
    if matched_dt:
        fine = make_scene(mesh, case, drop, dt=scene.dt / settings.substeps)
        runs["licrom_fine"] = motion_metrics(run_licrom(mesh, fine, frames * settings.substeps, device), drop)
    runs["newton"] = motion_metrics(run_newton(mesh, scene, frames, device, settings), drop)
    peer_com = runs["newton"]["com"]
    for name, m in runs.items():
        if name == "newton":
            continue
        gap = np.linalg.norm(_com_on_frames(m) - peer_com, axis=1) / m["size"]
        m["com_gap_final"], m["com_gap_max"] = float(gap[-1]), float(gap.max())
    return runs


def _label(name: str, m: dict[str, Any]) -> str:
    return name if name == "newton" else f"licrom {1e3 * m['dt']:g}ms"


def format_table(results: dict[str, dict[str, dict[str, Any]]], cases: tuple[Case, ...]) -> str:
    """The comparison as a fixed-width text table (one row per case and run)."""
    head = (
        f"{'case':<18} {'run':<13} {'ms/10ms':>8} {'s/sim-s':>8} {'final COM x,y,z [m]':>24} "
        f"{'slide [m]':>9} {'Coulomb':>8} {'late a':>7} {'a_C':>5} {'max pen':>8} {'COM vs newton':>15}"
    )
    sub = (
        f"{'':<18} {'':<13} {'(median)':>8} {'':>8} {'':>24} {'':>9} {'rigid':>8} {'[m/s2]':>7} "
        f"{'':>5} {'[mm]':>8} {'final/max %size':>15}"
    )
    lines = [head, sub, "-" * len(head)]
    for case in cases:
        label = f"{case.name} {case.angle_deg:g}deg mu {case.friction:g}"
        for name, m in results[case.name].items():
            c = m["final_com"]
            gap = "-" if name == "newton" else f"{100 * m['com_gap_final']:.1f} / {100 * m['com_gap_max']:.1f}"
            lines.append(
                f"{label:<18} {_label(name, m):<13} {m['frame_ms']:8.1f} {m['frame_ms'] / 10:8.2f} "
                f"{c[0]:8.3f},{c[1]:7.3f},{c[2]:7.3f} {m['slide']:9.3f} {m['coulomb_slide']:8.3f} "
                f"{m['late_accel']:7.2f} {m['coulomb_accel']:5.2f} {1e3 * m['max_penetration']:8.2f} {gap:>15}"
            )
            label = ""
    return "\n".join(lines)


def plot_travel(results: dict[str, dict[str, dict[str, Any]]], cases: tuple[Case, ...], path: Path, duration: float) -> Path:
    """PNG of the centre-of-mass travel down the slope against time, one panel per case."""
    from licrom.viz._plot import pyplot, save_png

    plt = pyplot()
    styles = {"licrom": ("C0", "-"), "licrom_fine": ("C0", ":"), "newton": ("C1", "--")}
    fig, axes = plt.subplots(1, len(cases), figsize=(5.5 * len(cases), 4.0), squeeze=False)
    for ax, case in zip(axes[0], cases):
        for name, m in results[case.name].items():
            color, style = styles[name]
            ax.plot(m["times"], m["travel"], style, color=color, label=_label(name, m))
        ax.axhline(results[case.name]["licrom"]["coulomb_slide"], color="0.6", lw=0.8, ls="-.", label="rigid Coulomb, at end")
        ax.set_title(f"{case.name}: {case.angle_deg:g} deg, mu {case.friction:g}")
        ax.set_xlabel("time [s]")
        ax.set_ylabel("COM travel down the slope [m]")
        ax.set_xlim(0.0, duration)
        ax.grid(alpha=0.3)
        ax.legend()
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    return save_png(fig, path)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--resolution", type=int, default=8, help="cheese cells along its longest side (default 8)")
    parser.add_argument("--device", default="cpu", help="cpu, cuda or cuda:N (both simulators)")
    parser.add_argument("--out", type=Path, default=Path("licrom-out/peer"), help="output folder for the plot")
    parser.add_argument("--duration", type=float, default=1.0, help="simulated seconds per case (default 1)")
    parser.add_argument("--substeps", type=int, default=NewtonSettings.substeps, help="newton VBD substeps per 10 ms")
    parser.add_argument("--iterations", type=int, default=NewtonSettings.iterations, help="newton VBD iterations per substep")
    parser.add_argument("--cases", nargs="+", choices=[c.name for c in CASES], default=[c.name for c in CASES])
    parser.add_argument(
        "--no-matched-dt",
        dest="matched_dt",
        action="store_false",
        help="skip the extra licrom run at newton's substep",
    )
    args = parser.parse_args(argv)
    if not args.device.startswith(("cpu", "cuda")):
        parser.error("--device must be cpu, cuda or cuda:N")
    if args.substeps < 1 or args.iterations < 1:
        parser.error("--substeps and --iterations must be >= 1")

    cases = tuple(c for c in CASES if c.name in args.cases)
    settings = NewtonSettings(substeps=args.substeps, iterations=args.iterations)
    mesh = licrom.meshes.cheese(resolution=args.resolution)
    results = {c.name: run_case(mesh, c, args.duration, args.device, settings, matched_dt=args.matched_dt) for c in cases}

    info = results[cases[0].name]["newton"]["info"]
    eps = ", ".join(f"{results[c.name]['newton']['info']['friction_epsilon']:.2g}" for c in cases)
    print(
        f"cheese resolution {args.resolution}: {mesh.n_vertices} vertices, {mesh.n_tets} tets, "
        f"size {mesh.size:.3f} m; device {args.device}; {args.duration:g} s simulated per case"
    )
    print("licrom: FullSim, backward Euler, Newton iterations to tolerance every step")
    print(
        f"newton: {info['source']}, {settings.substeps} substeps x {settings.iterations} iterations per 10 ms "
        f"(dt {1e3 * FRAME_DT / settings.substeps:g} ms), contact ke {info['contact_ke']:.0f} N/m and "
        f"kd {info['contact_kd']:g} N s/m per particle, friction epsilon {eps} m/s"
        + (", CUDA graph" if info["cuda_graph"] else "")
    )
    print(f"times: median wall time per 10 ms of simulated time, first {WARMUP_FRAMES} frames (compile, warm-up) left out")
    print(format_table(results, cases))
    png = plot_travel(results, cases, args.out / "peer_newton_travel.png", args.duration)
    print(f"plot: {png}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
