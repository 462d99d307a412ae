"""Trajectory datasets: sweep, manifest, resume, repair of damaged files, the report's presets, the CLI."""

import json
import math
import zipfile

import numpy as np
import pytest
from licrom import ConfigError, ContactParams, Material, Mesh, Scene, Trajectory, meshes
from licrom.dataset import (
    MANIFEST_NAME,
    MESH_NAME,
    generate_dataset,
    load_manifest,
    report_dataset_spec,
)
from licrom.placement import drop_state

STIFF = Material(youngs_modulus=1e6, poisson_ratio=0.3)
CONTACT = ContactParams(normal_stiffness=1e7, friction_stiffness=1e7)


def _tiny(tmp_path, **kw):
    mesh = meshes.box(0.1, resolution=1)
    scene = Scene(material=STIFF, contact=CONTACT)
    state = drop_state(mesh, STIFF.density, height=0.005)
    args = dict(frictions=[0.2, 0.6], planes=[25.0], initial_states=[state], steps=4, record_every=2,
                initial_frame="plane", progress=False, name="tiny")
    args.update(kw)
    return mesh, scene, generate_dataset(tmp_path / "ds", mesh, scene, **args)


def test_generate_writes_trajectories_mesh_and_manifest(tmp_path):
    mesh, _scene, manifest_path = _tiny(tmp_path)
    out = manifest_path.parent
    assert manifest_path.name == MANIFEST_NAME
    m = load_manifest(out)
    assert m["complete"] and m["name"] == "tiny" and m["frames"] == 3 and m["steps"] == 4
    assert Mesh.load(out / m["mesh"]).same_as(mesh)
    entries = m["trajectories"]
    assert [e["file"] for e in entries] == ["traj_000_mu0.20_slope25_ic0.npz", "traj_001_mu0.60_slope25_ic0.npz"]
    for e, mu in zip(entries, (0.2, 0.6)):
        assert e["status"] == "done" and not e["skipped"] and e["friction"] == mu
        assert e["slope_deg"] == [pytest.approx(25.0)]
        assert e["seconds"] > 0 and e["bytes"] == (out / e["file"]).stat().st_size
        traj = Trajectory.load(out / e["file"])
        assert traj.n_frames == 3 and traj.times[-1] == pytest.approx(0.04)
        assert traj.scene.planes[0].friction == mu and traj.scene.planes[0].slope_deg == pytest.approx(25.0)
        assert traj.info["source"] == "full" and traj.info["friction"] == mu
        # Dropped from 5 mm above the incline, measured along its normal.
        p = traj.scene.planes[0]
        assert (traj.positions(0) @ np.array(p.normal) + p.offset).min() == pytest.approx(0.005, abs=1e-7)  # frames stored as float32
    assert not [f for f in out.iterdir() if f.name.startswith(".")]  # no temporary files left


def test_rerun_skips_finished_files_and_regenerates_damaged_ones(tmp_path):
    _, _, manifest_path = _tiny(tmp_path)
    out = manifest_path.parent
    first = load_manifest(out)["trajectories"]
    stamps = {e["file"]: (out / e["file"]).stat().st_mtime_ns for e in first}

    _tiny(tmp_path)
    again = load_manifest(out)["trajectories"]
    assert [e["skipped"] for e in again] == [True, True]
    assert {e["file"]: (out / e["file"]).stat().st_mtime_ns for e in again} == stamps
    assert again[0]["seconds"] == first[0]["seconds"]  # timing of the original run kept

    damaged = out / first[1]["file"]
    data = bytearray(damaged.read_bytes())
    with zipfile.ZipFile(damaged) as zf:
        info = zf.getinfo("displacements.npy")
    start = info.header_offset + 30 + len(info.filename.encode()) + int.from_bytes(data[info.header_offset + 28:info.header_offset + 30], "little")
    data[start + info.compress_size // 2] ^= 0xFF  # one flipped byte inside the compressed frames
    damaged.write_bytes(bytes(data))
    (out / first[0]["file"]).write_bytes(b"not a trajectory")
    _tiny(tmp_path)
    repaired = load_manifest(out)["trajectories"]
    assert [e["skipped"] for e in repaired] == [False, False]
    for e in repaired:
        assert Trajectory.load(out / e["file"]).n_frames == 3


def test_changed_parameters_are_not_mistaken_for_finished_runs(tmp_path):
    _tiny(tmp_path)
    _, _, manifest_path = _tiny(tmp_path, steps=6)  # same file names, more frames
    entries = load_manifest(manifest_path.parent)["trajectories"]
    assert [e["skipped"] for e in entries] == [False, False]
    assert Trajectory.load(manifest_path.parent / entries[0]["file"]).n_frames == 4


def test_another_mesh_in_the_same_directory_is_refused(tmp_path):
    _tiny(tmp_path)
    with pytest.raises(ConfigError, match="another mesh"):
        generate_dataset(tmp_path / "ds", meshes.box(0.1, resolution=2), Scene(), steps=1, progress=False)


def test_bad_arguments(tmp_path):
    mesh = meshes.box(0.1, resolution=1)
    with pytest.raises(ConfigError, match="steps"):
        generate_dataset(tmp_path, mesh, Scene(), steps=0, progress=False)
    with pytest.raises(ConfigError, match="friction"):
        generate_dataset(tmp_path, mesh, Scene(), frictions=[-0.1], progress=False)
    with pytest.raises(ConfigError, match="planes"):
        generate_dataset(tmp_path, mesh, Scene(), planes=["steep"], progress=False)
    with pytest.raises(ConfigError, match="initial_frame"):
        generate_dataset(tmp_path, mesh, Scene(), initial_frame="body", progress=False)
    with pytest.raises(ConfigError, match="auto, cpu, cuda"):
        generate_dataset(tmp_path, mesh, Scene(), device="tpu", progress=False)
    with pytest.raises(ConfigError, match="executor"):
        generate_dataset(tmp_path, mesh, Scene(), executor="threads", progress=False)
    with pytest.raises(ConfigError, match="preset"):
        report_dataset_spec("teapot")


def test_report_presets():
    cheese = report_dataset_spec("cheese", resolution=6)
    assert cheese.n_trajectories == 15
    assert cheese.frictions == (0.1, 0.3, 0.5, 0.7, 0.9) and cheese.planes == (10.0, 20.0, 30.0)
    tans = [math.tan(math.radians(s)) for s in cheese.planes]
    slides = [(mu, s) for mu in cheese.frictions for s, t in zip(cheese.planes, tans) if mu < t]
    sticks = [(mu, s) for mu in cheese.frictions for s, t in zip(cheese.planes, tans) if mu > t]
    assert len(slides) >= 3 and len(sticks) >= 3  # both outcomes in the set
    sphere = report_dataset_spec("sphere", resolution=4)
    assert sphere.n_trajectories == 1 and sphere.frictions == (0.5,)
    assert np.linalg.norm(sphere.initial_states[0].velocity) > 0  # thrown, so that it bounces


def test_cli_generate(tmp_path):
    from licrom.cli import main

    out = tmp_path / "cli"
    assert main(["generate", str(out), "--preset", "cheese", "--resolution", "4", "--steps", "2", "-q", "--jobs", "2"]) == 0
    m = json.loads((out / MANIFEST_NAME).read_text())
    assert len(m["trajectories"]) == 15 and m["complete"] and m["jobs"] == 2 and m["device"] == "cpu"
    assert (out / MESH_NAME).is_file()
    assert main(["generate", str(out), "--preset", "cheese", "--resolution", "4", "--steps", "2", "-q"]) == 0
    assert all(t["skipped"] for t in json.loads((out / MANIFEST_NAME).read_text())["trajectories"])
    assert main(["generate", str(out), "--device", "gpu"]) == 2
    assert main(["generate", str(out), "--jobs", "0"]) == 2
    assert main(["generate", str(out), "--executor", "ray", "--jobs", "2"]) == 2
