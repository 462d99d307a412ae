"""Exports of runs for other tools: VTU series for ParaView and time-sampled USD stages.

Both carry what the pictures show: the surface (VTU: the whole tet mesh) at every frame, the
non-rigid deformation (each frame's best rigid fit removed, :mod:`licrom.rigid`), the contact
forces at every boundary vertex, and the planes as finite quads that cover the region the run
sweeps. The contact forces are recomputed from the recorded positions and velocities with the
contact laws of ``docs/design.md`` (the same formulas as ``licrom.full.contact``), so
they exist for full and reduced runs alike.
"""

from __future__ import annotations

import errno
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from .._io import atomic_path, make_dir, output_error
from ..errors import ConfigError, OutputError, ShapeError, require_optional
from ..rigid import nonrigid_displacements
from ..scene.scene import Plane
from .trajectory import Trajectory

__all__ = [
    "EXPORT_FORMATS",
    "USD_SUFFIXES",
    "ContactForces",
    "contact_forces",
    "downhill_direction",
    "nonrigid_deformation",
    "plane_patch",
    "write_usd",
    "write_vtu_series",
]

EXPORT_FORMATS = ("vtu", "usd")
"""Formats of :func:`write_vtu_series` and :func:`write_usd` (the pictures are in :mod:`licrom.viz.render`)."""

USD_SUFFIXES = (".usd", ".usda", ".usdc")
"""File names a USD stage may have: ``.usda`` is text, ``.usd`` and ``.usdc`` binary (crate)."""


@dataclass(frozen=True)
class ContactForces:
    """Contact forces of every frame of a run, at every vertex (zero away from the boundary).

    Attributes:
        normal: (f, n, 3) penalty force along the plane normals plus the normal damping, N.
        friction: (f, n, 3) Coulomb friction force in the planes, N.
    """

    normal: np.ndarray
    friction: np.ndarray

    @property
    def total(self) -> np.ndarray:
        """(f, n, 3) normal plus friction force, N."""
        return self.normal + self.friction


def contact_forces(traj: Trajectory) -> ContactForces:
    """The contact forces the planes put on each boundary vertex at the end of every recorded step.

    Each boundary vertex carries its share ``a`` of the boundary area. For each plane
    ``n . x + d >= 0`` of the trajectory's scene, with ``x`` the vertex position at the frame,
    ``x0 = x - h v`` its position at the start of the step (backward Euler: ``v = (x - x0)/h``):

    - normal: ``a k_n max(-(n . x + d), 0) n``, plus the damping ``-a k_d (n . dx)/h n`` while the
      point approaches a plane it touched at the step's start (``dx = x - x0``);
    - friction, with the normal force lagged from the step's start ``f_n = a k_n max(-(n . x0 + d), 0)``
      and the slip ``s = dx - (n . dx) n``: ``-(a k_f / h) s`` while that is within ``mu f_n``
      (sticking), ``-mu f_n s/|s|`` otherwise (sliding).

    These are the forces :meth:`licrom.FullSim.contact_forces` reports for the full simulation;
    here they follow from a recorded run, full or reduced, at every boundary vertex (a reduced
    model that samples fewer contact points gives its forces at all of them). Frame 0 is
    treated like the others, as a state that arrived with its recorded velocity.
    """
    scene = traj.scene
    mesh = traj.mesh
    h = scene.dt
    c = scene.contact
    idx = np.asarray(mesh.boundary_vertices)
    area = np.asarray(mesh.boundary_vertex_areas)[None, :, None]
    x = traj.rest_positions[idx][None] + traj.displacements[:, idx]
    dx = h * traj.velocities[:, idx]
    x0 = x - dx
    normal = np.zeros_like(x)
    friction = np.zeros_like(x)
    for plane in scene.planes:
        n = np.asarray(plane.normal)
        gap = x @ n + plane.offset
        normal += area * c.normal_stiffness * np.maximum(-gap, 0.0)[..., None] * n
        fn_lag = area[..., 0] * c.normal_stiffness * np.maximum(-(x0 @ n + plane.offset), 0.0)
        dn = dx @ n
        damped = (fn_lag > 0.0) & (dn < 0.0)
        normal -= np.where(damped, area[..., 0] * c.normal_damping * dn / h, 0.0)[..., None] * n
        slip = dx - dn[..., None] * n
        length = np.linalg.norm(slip, axis=-1)
        stick = area[..., 0] * c.friction_stiffness / h
        cap = plane.friction * fn_lag
        # Sticking: the viscous law; sliding: the Coulomb cap along the slip (length > 0 there).
        scale = np.where(stick * length <= cap, stick, cap / np.where(length > 0.0, length, 1.0))
        friction -= np.where(cap > 0.0, scale, 0.0)[..., None] * slip
    full = (traj.n_frames, len(traj.rest_positions), 3)
    out_n, out_f = np.zeros(full), np.zeros(full)
    out_n[:, idx] = normal
    out_f[:, idx] = friction
    return ContactForces(out_n, out_f)


def nonrigid_deformation(traj: Trajectory) -> np.ndarray:
    """(f, n, 3) world-frame non-rigid deformation of every frame, m: each frame's position minus
    its best rigid placement of the rest shape (:func:`licrom.rigid.nonrigid_displacements`)."""
    masses = traj.mesh.vertex_masses(traj.scene.material.density)
    return nonrigid_displacements(traj.rest_positions[None] + traj.displacements, traj.rest_positions, masses)


def downhill_direction(plane: Plane, gravity: Sequence[float]) -> np.ndarray:
    """A unit vector in the plane: the downhill direction of gravity, or any for a level plane."""
    n = np.asarray(plane.normal)
    g = np.asarray(gravity, dtype=np.float64)
    a = g - (g @ n) * n
    if np.linalg.norm(a) < 1e-9 * max(float(np.linalg.norm(g)), 1.0):
        a = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    return a / np.linalg.norm(a)


def plane_patch(plane: Plane, points: np.ndarray, margin: float, gravity: Sequence[float] = (0.0, 0.0, -1.0)) -> np.ndarray:
    """(4, 3) corners of the part of ``plane`` under ``points`` (their projections' bounding
    rectangle grown by ``margin`` m on every side), counter-clockwise seen from the normal's side.

    The rectangle's first edge runs downhill (along gravity projected onto the plane), so
    patches of inclines line up with the slide.
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(p) == 0 or not np.all(np.isfinite(p)):
        raise ShapeError(f"plane_patch needs finite points of shape (k, 3), got {np.shape(points)}")
    n = np.asarray(plane.normal)
    a = downhill_direction(plane, gravity)
    b = np.cross(n, a)
    origin = -plane.offset * n
    s, t = (p - origin) @ a, (p - origin) @ b
    s0, s1, t0, t1 = s.min() - margin, s.max() + margin, t.min() - margin, t.max() + margin
    return np.array([origin + u * a + w * b for u, w in ((s0, t0), (s1, t0), (s1, t1), (s0, t1))])


def _patches(traj: Trajectory) -> list[np.ndarray]:
    """The quads of the scene's planes under the whole run, with half the object's size around."""
    every = traj.rest_positions[None] + traj.displacements
    return [plane_patch(p, every, 0.5 * traj.mesh.size, traj.scene.gravity) for p in traj.scene.planes]


def write_vtu_series(traj: Trajectory, folder: str | os.PathLike, name: str = "frame") -> Path:
    """Write a run as a ParaView time series; return the path of its ``name.pvd`` collection.

    Every frame becomes ``name_XXXX.vtu``: the tet mesh at its positions, with the point fields
    ``displacement`` (m), ``velocity`` (m/s), ``nonrigid_deformation`` (m, the frame's best rigid
    fit removed), ``contact_normal_force``, ``contact_friction_force`` and ``contact_force`` (N,
    see :func:`contact_forces`). Each plane becomes one static quad ``name_plane_P.vtu`` (cell
    data ``friction``) listed at every time step as its own part, so ParaView shows the run and
    the planes as blocks of one time series.
    """
    import meshio

    if not re.fullmatch(r"[A-Za-z0-9_.-]+", name):
        raise ConfigError(f"write_vtu_series name must be letters, digits, '_', '-' or '.', got {name!r}")
    out = make_dir(folder)
    forces = contact_forces(traj)
    deformation = nonrigid_deformation(traj)
    planes = []
    for p, (plane, quad) in enumerate(zip(traj.scene.planes, _patches(traj))):
        fname = f"{name}_plane_{p}.vtu"
        mesh = meshio.Mesh(quad, [("quad", np.array([[0, 1, 2, 3]]))], cell_data={"friction": [np.array([plane.friction])]})
        with atomic_path(out / fname) as tmp:
            meshio.write(tmp, mesh, file_format="vtu")
        planes.append(fname)
    entries = []
    for f in range(traj.n_frames):
        fname = f"{name}_{f:04d}.vtu"
        mesh = meshio.Mesh(
            traj.positions(f),
            [("tetra", traj.tets)],
            point_data={
                "displacement": traj.displacements[f],
                "velocity": traj.velocities[f],
                "nonrigid_deformation": deformation[f],
                "contact_normal_force": forces.normal[f],
                "contact_friction_force": forces.friction[f],
                "contact_force": forces.normal[f] + forces.friction[f],
            },
        )
        with atomic_path(out / fname, sync=False) as tmp:  # one fsync a frame took longer than the writing
            meshio.write(tmp, mesh, file_format="vtu")
        entries.append(f'    <DataSet timestep="{traj.times[f]:.9g}" part="0" file={quoteattr(fname)}/>')
        entries += [f'    <DataSet timestep="{traj.times[f]:.9g}" part="{1 + p}" file={quoteattr(q)}/>' for p, q in enumerate(planes)]
    pvd = out / f"{name}.pvd"
    text = '<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1">\n  <Collection>\n'
    text += "\n".join(entries) + "\n  </Collection>\n</VTKFile>\n"
    with atomic_path(pvd) as tmp:
        tmp.write_text(text)
    return pvd


def _prim_name(label: str) -> str:
    """A valid USD prim name from a label: letters, digits and '_' only, not starting with a digit."""
    name = re.sub(r"[^A-Za-z0-9_]", "_", label) or "run"
    return f"_{name}" if name[0].isdigit() else name


def write_usd(trajectories: Trajectory | Sequence[Trajectory], path: str | os.PathLike, labels: Sequence[str] | None = None) -> Path:
    """Write runs as one USD stage with time-sampled meshes; return the path.

    Each run becomes ``/World/<label>``: a ``Mesh`` of the boundary surface whose ``points`` and
    ``velocities`` are sampled at every frame, with the per-vertex primvar ``deformation`` (m,
    the length of the non-rigid deformation) sampled likewise. The first run's planes become
    ``/World/plane_P`` quads. Time codes are frame indices and ``timeCodesPerSecond`` makes them
    play in real time; the stage is Z-up in metres. Opens in usdview, Blender and Omniverse.

    Args:
        trajectories: one run, or runs of one scene (e.g. full and reduced) shown together.
        path: ``.usda`` (text), ``.usd`` or ``.usdc`` (binary).
        labels: prim names of the runs (default ``run_0``, ``run_1``, ...).

    Raises:
        MissingDependencyError: usd-core is not installed (``pip install 'licrom[usd]'``).
        ConfigError: another file suffix, or labels that do not match the runs.
        ShapeError: runs of different frame counts.
        OutputError: the stage cannot be written (a full disk, a read-only folder); ``path`` keeps its previous contents.
    """
    runs = [trajectories] if isinstance(trajectories, Trajectory) else list(trajectories)
    out = Path(path)
    if out.suffix not in USD_SUFFIXES:
        raise ConfigError(f"write_usd path must end in {', '.join(USD_SUFFIXES)}, got '{out.name}'")
    names = [_prim_name(s) for s in (labels if labels is not None else [f"run_{i}" for i in range(len(runs))])]
    if not runs or len(names) != len(runs) or len(set(names)) != len(names):
        raise ConfigError(f"write_usd needs one distinct label per run, got {len(runs)} runs and labels {list(labels or [])}")
    if len({t.n_frames for t in runs}) != 1:
        raise ShapeError(f"write_usd needs runs of one frame count, got {[t.n_frames for t in runs]}")
    Usd = require_optional("pxr.Usd", "usd", "USD export")
    from pxr import Gf, Sdf, Tf, UsdGeom, Vt

    first = runs[0]
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    stage.SetStartTimeCode(0)
    stage.SetEndTimeCode(first.n_frames - 1)
    spacing = np.diff(first.times)
    if len(spacing) and spacing.min() > 0:
        rate = float(f"{1.0 / spacing.mean():.9g}")  # 100, not 99.99999999999994
        stage.SetTimeCodesPerSecond(rate)
        stage.SetFramesPerSecond(rate)
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    for traj, name in zip(runs, names):
        faces = np.asarray(traj.mesh.boundary_faces)
        used = np.unique(faces)
        remap = np.full(len(traj.rest_positions), -1)
        remap[used] = np.arange(len(used))
        mesh = UsdGeom.Mesh.Define(stage, f"/World/{name}")
        mesh.CreateFaceVertexCountsAttr(Vt.IntArray([3] * len(faces)))
        mesh.CreateFaceVertexIndicesAttr(Vt.IntArray(remap[faces].ravel().tolist()))
        mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        mesh.CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set(Vt.Vec3fArray([Gf.Vec3f(0.98, 0.82, 0.35)]))
        deformation = np.linalg.norm(nonrigid_deformation(traj)[:, used], axis=-1)
        primvar = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("deformation", Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.vertex)
        points, velocities, extent = mesh.CreatePointsAttr(), mesh.CreateVelocitiesAttr(), mesh.CreateExtentAttr()
        for f in range(traj.n_frames):
            x = traj.positions(f)[used]
            points.Set(Vt.Vec3fArray.FromNumpy(x.astype(np.float32)), f)
            velocities.Set(Vt.Vec3fArray.FromNumpy(traj.velocities[f, used].astype(np.float32)), f)
            extent.Set(Vt.Vec3fArray.FromNumpy(np.array([x.min(axis=0), x.max(axis=0)], dtype=np.float32)), f)
            primvar.Set(Vt.FloatArray.FromNumpy(deformation[f].astype(np.float32)), f)
    for p, quad in enumerate(_patches(first)):
        plane = UsdGeom.Mesh.Define(stage, f"/World/plane_{p}")
        plane.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(quad.astype(np.float32)))
        plane.CreateFaceVertexCountsAttr(Vt.IntArray([4]))
        plane.CreateFaceVertexIndicesAttr(Vt.IntArray([0, 1, 2, 3]))
        plane.CreateExtentAttr(Vt.Vec3fArray.FromNumpy(np.array([quad.min(axis=0), quad.max(axis=0)], dtype=np.float32)))
        plane.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        plane.CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set(Vt.Vec3fArray([Gf.Vec3f(0.6, 0.6, 0.6)]))
        plane.GetPrim().SetCustomDataByKey("friction", float(first.scene.planes[p].friction))
    with atomic_path(out) as tmp:
        try:
            written = stage.GetRootLayer().Export(str(tmp))
        except Tf.ErrorException as exc:  # a full disk, a file size limit, an unwritable folder
            raise _usd_write_error(out, exc) from None
        if not written:
            raise OutputError(f"cannot write '{out}': USD could not export the stage there")
    return out


def _usd_write_error(out: Path, exc: Exception) -> OutputError:
    """The OutputError for USD's ``Tf.ErrorException`` on writing ``out``: the system's reason and its errno when the message names one."""
    # USD's message: "Error in 'function' at line N in file F : 'what happened'", once per failing layer.
    said = [m for m in re.findall(r" : '([^']*)'", str(exc)) if m] or [" ".join(str(exc).split())]
    for code in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EACCES, errno.EROFS, errno.EISDIR):
        if os.strerror(code) in said[0]:
            return output_error(out, OSError(code, os.strerror(code)))
    return OutputError(f"cannot write '{out}': USD could not write it ({said[0]})")

