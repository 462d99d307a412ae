import math
import sys
import xml.etree.ElementTree as ET

import meshio
import numpy as np
import pytest
from licrom import ContactParams, FullSim, Plane, meshes
from licrom.data.presets import report_dataset_spec
from licrom.errors import ConfigError, MissingDependencyError, ShapeError
from licrom.learn.training_data import make_synthetic_trajectories
from licrom.records.export import contact_forces, nonrigid_deformation, plane_patch, write_usd, write_vtu_series
from licrom.rigid import nonrigid_displacements
from licrom.scene.placement import drop_state, initial_state_on_plane

SLOPE = 20.0  # tan = 0.364: mu 0.1 slides, mu 0.9 sticks


def _incline_sim(mu, damping=0.0):
    mesh = meshes.cheese(resolution=4)
    base = report_dataset_spec("cheese", resolution=4).base_scene
    c = base.contact
    base = base.replace(contact=ContactParams(c.normal_stiffness, damping, c.friction_stiffness))
    plane = Plane.incline(SLOPE, mu)
    rest = drop_state(mesh, base.material.density, 0.0)
    return FullSim(mesh, base.replace(planes=(plane,), initial=initial_state_on_plane(rest, plane, mesh, base.material.density)))


@pytest.fixture(scope="module")
def incline_runs():
    """``{mu: (simulation after the run, trajectory)}``: 0.4 s on a 20 deg incline, every 4th step recorded."""
    out = {}
    for mu in (0.1, 0.9):
        sim = _incline_sim(mu, damping=1e4)
        out[mu] = (sim, sim.run(40, record_every=4))
    return out


@pytest.fixture(scope="module")
def traj():
    return make_synthetic_trajectories(meshes.box(0.1, 2), count=1, frames=5, seed=1)[0]


def test_contact_forces_are_the_full_simulations(incline_runs):
    for sim, traj in incline_runs.values():
        forces = contact_forces(traj)
        reference = sim.contact_forces()  # normal + damping + friction at the last step's end
        np.testing.assert_allclose(forces.total[-1][sim.contact_indices], reference, atol=1e-9 * np.abs(reference).max())
        inside = np.setdiff1d(np.arange(traj.rest_positions.shape[0]), sim.contact_indices)
        assert not forces.total[:, inside].any()


def test_contact_forces_hold_the_sticker_and_cap_the_slider(incline_runs):
    for mu, (sim, traj) in incline_runs.items():
        forces = contact_forces(traj)
        weight = sim.masses.sum() * 9.81
        normal, friction = forces.normal[-1].sum(axis=0), forces.friction[-1].sum(axis=0)
        n = np.asarray(traj.scene.planes[0].normal)
        assert np.allclose(normal / np.linalg.norm(normal), n, atol=1e-3)
        assert abs(friction @ n) < 1e-9 * weight
        ratio = np.linalg.norm(friction) / np.linalg.norm(normal)
        if mu == 0.1:  # sliding: Coulomb's cap, friction up the slope
            assert ratio == pytest.approx(0.1, rel=1e-3) and friction[0] < 0
        else:  # sticking at rest: the contact carries the weight, friction tan(slope) of the normal force
            np.testing.assert_allclose(normal + friction, [0.0, 0.0, weight], atol=0.01 * weight)
            assert ratio == pytest.approx(math.tan(math.radians(SLOPE)), rel=0.01)


def test_nonrigid_deformation_is_zero_for_a_rigid_motion(traj):
    d = nonrigid_deformation(traj)
    masses = traj.mesh.vertex_masses(traj.scene.material.density)
    np.testing.assert_allclose(d, nonrigid_displacements(traj.rest_positions + traj.displacements, traj.rest_positions, masses))
    angle = 0.3
    rot = np.array([[math.cos(angle), -math.sin(angle), 0], [math.sin(angle), math.cos(angle), 0], [0, 0, 1]])
    rigid = type(traj)(traj.rest_positions, traj.tets, (traj.rest_positions @ rot.T + [1.0, 2.0, 3.0] - traj.rest_positions)[None],
                       np.zeros((1, *traj.rest_positions.shape)), [0.0], traj.scene)
    assert np.abs(nonrigid_deformation(rigid)).max() < 1e-12


def test_plane_patch_lies_in_the_plane_under_the_points():
    plane = Plane.incline(30.0, 0.5, offset=0.2)
    points = np.array([[0.0, 0.0, 1.0], [1.0, 0.5, 0.0], [-0.5, -0.2, 0.3]])
    quad = plane_patch(plane, points, margin=0.1)
    n = np.asarray(plane.normal)
    np.testing.assert_allclose(quad @ n + plane.offset, 0.0, atol=1e-12)
    assert np.cross(quad[1] - quad[0], quad[3] - quad[0]) @ n > 0  # counter-clockwise from above
    downhill = quad[1] - quad[0]
    assert downhill[2] < 0 and abs(downhill[1]) < 1e-12
    under = points - np.outer(points @ n + plane.offset, n)
    lo, hi = quad.min(axis=0), quad.max(axis=0)
    assert np.all(under >= lo - 1e-12) and np.all(under <= hi + 1e-12)
    with pytest.raises(ShapeError, match="finite points"):
        plane_patch(plane, np.zeros((0, 3)), 0.1)


def test_vtu_series_holds_forces_deformation_and_planes(incline_runs, tmp_path):
    _, traj = incline_runs[0.1]
    pvd = write_vtu_series(traj, tmp_path / "series", name="run")
    entries = ET.parse(pvd).getroot().find("Collection")
    assert len(entries) == 2 * traj.n_frames  # the run and its plane at every time step
    forces = contact_forces(traj)
    deformation = nonrigid_deformation(traj)
    runs = [e for e in entries if e.get("part") == "0"]
    for f, entry in enumerate(runs):
        assert float(entry.get("timestep")) == pytest.approx(traj.times[f])
        m = meshio.read(pvd.parent / entry.get("file"))
        np.testing.assert_allclose(m.points, traj.positions(f))
        np.testing.assert_array_equal(m.cells_dict["tetra"], traj.tets)
        np.testing.assert_allclose(m.point_data["displacement"], traj.displacements[f])
        np.testing.assert_allclose(m.point_data["velocity"], traj.velocities[f])
        np.testing.assert_allclose(m.point_data["nonrigid_deformation"], deformation[f])
        np.testing.assert_allclose(m.point_data["contact_normal_force"], forces.normal[f])
        np.testing.assert_allclose(m.point_data["contact_friction_force"], forces.friction[f])
    assert np.abs(forces.friction[-1]).max() > 0  # the slider's friction is in the file
    planes = {e.get("file") for e in entries if e.get("part") == "1"}
    assert planes == {"run_plane_0.vtu"}
    quad = meshio.read(pvd.parent / "run_plane_0.vtu")
    plane = traj.scene.planes[0]
    np.testing.assert_allclose(quad.points @ np.asarray(plane.normal) + plane.offset, 0.0, atol=1e-12)
    assert quad.cell_data["friction"][0][0] == pytest.approx(0.1)
    assert {p.name for p in pvd.parent.iterdir()} == {"run.pvd", "run_plane_0.vtu", *(f"run_{f:04d}.vtu" for f in range(traj.n_frames))}
    with pytest.raises(ConfigError, match="name"):
        write_vtu_series(traj, tmp_path / "bad", name="a/b")


@pytest.mark.parametrize("suffix", [".usda", ".usd"])
def test_usd_stage_has_time_sampled_points_and_the_plane(incline_runs, tmp_path, suffix):
    from pxr import Usd, UsdGeom

    _, traj = incline_runs[0.1]
    path = write_usd([traj, traj], tmp_path / f"run{suffix}", labels=["full", "reduced run"])
    stage = Usd.Stage.Open(str(path))
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z and UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert stage.GetEndTimeCode() == traj.n_frames - 1
    assert stage.GetTimeCodesPerSecond() == pytest.approx(1.0 / (traj.times[1] - traj.times[0]))
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/World/full"))
    assert stage.GetPrimAtPath("/World/reduced_run").IsValid()
    used = np.unique(traj.mesh.boundary_faces)
    for f in (0, traj.n_frames // 2, traj.n_frames - 1):
        np.testing.assert_allclose(np.array(mesh.GetPointsAttr().Get(f)), traj.positions(f)[used], atol=1e-6)
    # Between samples USD interpolates linearly.
    mid = 0.5 * (traj.positions(1) + traj.positions(2))[used]
    np.testing.assert_allclose(np.array(mesh.GetPointsAttr().Get(1.5)), mid, atol=1e-6)
    indices = np.array(mesh.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3)
    np.testing.assert_array_equal(used[indices], traj.mesh.boundary_faces)
    plane = UsdGeom.Mesh(stage.GetPrimAtPath("/World/plane_0"))
    corners = np.array(plane.GetPointsAttr().Get())
    p = traj.scene.planes[0]
    np.testing.assert_allclose(corners @ np.asarray(p.normal) + p.offset, 0.0, atol=1e-6)
    assert plane.GetPrim().GetCustomDataByKey("friction") == pytest.approx(0.1)


def test_usd_refuses_bad_input(traj, tmp_path, monkeypatch):
    with pytest.raises(ConfigError, match=r"\.usda"):
        write_usd(traj, tmp_path / "run.obj")
    with pytest.raises(ConfigError, match="one distinct label per run"):
        write_usd([traj, traj], tmp_path / "run.usda", labels=["a", "a"])
    monkeypatch.setitem(sys.modules, "pxr", None)
    monkeypatch.setitem(sys.modules, "pxr.Usd", None)
    with pytest.raises(MissingDependencyError, match=r"pip install 'licrom\[usd\]'"):
        write_usd(traj, tmp_path / "run.usda")
    assert not list(tmp_path.iterdir())


# Runs a write in a child process whose file size limit is 1 kB (SIGXFSZ ignored, so writes
# past it fail with EFBIG): the disk is full for it, and for it alone.
FULL_DISK = """
import resource, signal, sys
import numpy as np
from licrom import meshes, render
from licrom.records.export import write_usd
from licrom.learn.training_data import make_synthetic_trajectories

traj = make_synthetic_trajectories(meshes.box(0.1, 2), count=1, frames=5, seed=1)[0]


class Views:  # pictures without PyVista: the GIF's bytes are what matters
    def __init__(self, *args):
        pass

    def panel(self, i, f):
        return None

    def compose(self, rows):
        return np.random.default_rng(0).integers(0, 255, (64, 64, 3), dtype=np.uint8)

    def close(self):
        pass


render._Views = Views
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
resource.setrlimit(resource.RLIMIT_FSIZE, (1000, resource.RLIM_INFINITY))
try:
    if sys.argv[1].endswith(".gif"):
        render.animation([traj], ["run"], sys.argv[1])
    else:
        write_usd(traj, sys.argv[1])
except Exception as exc:
    print(f"{type(exc).__module__}.{type(exc).__name__} errno={getattr(exc, 'errno', None)}: {exc}")
"""


@pytest.mark.parametrize("name", ["run.usda", "run.usdc", "run.gif"])
def test_a_full_disk_is_one_output_error(tmp_path, name):
    import errno
    import subprocess

    done = subprocess.run([sys.executable, "-c", FULL_DISK, str(tmp_path / name)], capture_output=True, text=True, timeout=300)
    assert done.stdout.strip() == f"licrom.errors.OutputError errno={errno.EFBIG}: cannot write '{tmp_path / name}': File too large"
    assert "Exception ignored" not in done.stderr and "Traceback" not in done.stderr
    assert list(tmp_path.iterdir()) == []  # nothing half-written
