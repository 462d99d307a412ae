"""Trajectory datasets: sweep, manifest, resume, repair of damaged files, the report's presets, the CLI."""

import json
import math
import zipfile

import numpy as np
import pytest
from licrom import ConfigError, ContactParams, Material, Mesh, Scene, Trajectory, meshes
from licrom.data.dataset import (
    MANIFEST_NAME,
    MESH_NAME,
    generate_dataset,
    load_manifest,
)
from licrom.data.presets import report_dataset_spec
from licrom.scene.placement import drop_state

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


def test_impact_frames_are_kept_and_another_window_is_not_mistaken_for_a_finished_run(tmp_path):
    _, _, manifest_path = _tiny(tmp_path, steps=8, impact_window=0.02)
    out = manifest_path.parent
    assert load_manifest(out)["impact_window"] == 0.02
    for e in load_manifest(out)["trajectories"]:
        traj = Trajectory.load(out / e["file"])
        steps = np.round(traj.impact_times / 0.01).astype(int)
        assert len(steps) == 1 and steps[0] % 2 == 1  # the landing's step between two frames (a window of 2 steps)
        assert traj.penetration[(steps[0] + 1) // 2] > 0 and traj.penetration[(steps[0] - 1) // 2] == 0  # first in contact there
    _, _, manifest_path = _tiny(tmp_path, steps=8, impact_window=0.0)
    entries = load_manifest(out)["trajectories"]
    assert [e["skipped"] for e in entries] == [False, False]
    assert all(len(Trajectory.load(out / e["file"]).impact_times) == 0 for e in entries)
    _, _, manifest_path = _tiny(tmp_path, steps=8, record_every=1)  # every step a frame: no impact frames asked
    assert load_manifest(out)["impact_window"] == 0.0
    for every in (1, 2):  # refused also where it would not be used
        with pytest.raises(ConfigError, match="impact_window must be a finite time >= 0"):
            _tiny(tmp_path, impact_window=-1.0, record_every=every)


def test_another_mesh_in_the_same_directory_is_refused(tmp_path):
    _tiny(tmp_path)
    with pytest.raises(ConfigError, match="another mesh"):
        generate_dataset(tmp_path / "ds", meshes.box(0.1, resolution=2), Scene(), steps=1, progress=False)


def test_a_directory_in_use_is_refused_and_a_killed_writers_lock_blocks_nothing(tmp_path):
    import re
    import subprocess
    import sys

    from licrom import ConcurrencyError
    from licrom.data.dataset import LOCK_NAME

    out = tmp_path / "ds"
    out.mkdir()
    lock = out / LOCK_NAME
    # Another process holds the directory's lock, as a running sweep does.
    code = ("import fcntl, os, sys, time; fd = os.open(sys.argv[1], os.O_RDWR | os.O_CREAT); fcntl.flock(fd, fcntl.LOCK_EX); "
            "os.write(fd, str(os.getpid()).encode()); print('locked', flush=True); time.sleep(120)")
    holder = subprocess.Popen([sys.executable, "-c", code, str(lock)], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(ConcurrencyError, match=re.escape(f"dataset directory '{out}' is being written by another licrom generate "
                                                             f"(process {holder.pid} holds its lock '{lock}'); wait for it to finish")):
            _tiny(tmp_path)  # used to write beside it, the last one winning
        assert sorted(f.name for f in out.iterdir()) == [LOCK_NAME]  # nothing written
    finally:
        holder.kill()  # SIGKILL: it leaves its lock file behind
        holder.wait()
    assert lock.exists()
    _tiny(tmp_path)  # the lock died with its process
    assert load_manifest(out)["complete"] and not lock.exists()


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
    slopes = sorted({scene.planes[0].slope_deg for scene in cheese.scenes()})
    assert cheese.frictions == (0.1, 0.3, 0.5, 0.7, 0.9) and slopes == pytest.approx([10.0, 20.0, 30.0])
    tans = [math.tan(math.radians(s)) for s in slopes]
    slides = [(mu, s) for mu in cheese.frictions for s, t in zip(slopes, tans) if mu < t]
    sticks = [(mu, s) for mu in cheese.frictions for s, t in zip(slopes, tans) if mu > t]
    assert len(slides) >= 3 and len(sticks) >= 3  # both outcomes in the set
    sphere = report_dataset_spec("sphere", resolution=4)
    assert sphere.n_trajectories == 1 and sphere.frictions == (0.5,)
    assert np.linalg.norm(sphere.initial_states[0].velocity) > 0  # thrown, so that it bounces


def test_cli_generate(tmp_path):
    from licrom.cli.commands import main

    out = tmp_path / "cli"
    assert main(["generate", str(out), "--scene", "cheese", "--resolution", "4", "--steps", "2", "-q", "--jobs", "2"]) == 0
    m = json.loads((out / MANIFEST_NAME).read_text())
    assert len(m["trajectories"]) == 15 and m["complete"] and m["jobs"] == 2 and m["device"] == "cpu"
    assert (out / MESH_NAME).is_file()
    assert main(["generate", str(out), "--scene", "cheese", "--resolution", "4", "--steps", "2", "-q"]) == 0
    assert all(t["skipped"] for t in json.loads((out / MANIFEST_NAME).read_text())["trajectories"])
    assert main(["generate", str(out), "--device", "gpu"]) == 2


def test_a_full_disk_stops_the_run_at_the_first_trajectory(tmp_path, monkeypatch, capsys):
    import errno
    import os

    from licrom.cli.commands import main

    calls = []

    def full_disk(fh, **arrays):
        calls.append(1)
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(np, "savez_compressed", full_disk)
    out = tmp_path / "cli"
    assert main(["generate", str(out), "--scene", "cheese", "--resolution", "4", "--steps", "2", "-q"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("licrom: error: cannot write") and "traj_000" in err and "no space left on the device" in err
    # not recorded as one failed trajectory after another: stopped at the first write, nothing half-written
    assert len(calls) == 1 and not list(out.glob("*.npz")) and not [p for p in out.iterdir() if p.name.startswith(".")]


def _presets_as_they_were_built_in_code(preset: str, resolution: int):
    """The presets as report_dataset_spec built them before they became scene files."""
    from licrom.data.dataset import DatasetSpec

    contact = ContactParams(normal_stiffness=1.0e7, normal_damping=0.0, friction_stiffness=1.0e7)
    material = Material(youngs_modulus=1.0e5, poisson_ratio=0.3, density=1000.0)
    if preset == "cheese":
        mesh = meshes.cheese(resolution=resolution)
        state = drop_state(mesh, material.density, height=0.02, rotation=(0.15, 0.1, 0.0))
        return DatasetSpec("cheese", mesh, Scene(material=material, contact=contact, dt=0.01), (0.1, 0.3, 0.5, 0.7, 0.9),
                           (10.0, 20.0, 30.0), (state,), 200, 1, "plane")
    mesh = meshes.sphere(radius=0.05, resolution=resolution)
    state = drop_state(mesh, material.density, height=0.2, velocity=(0.5, 0.0, -1.0))
    return DatasetSpec("sphere", mesh, Scene(material=material, contact=contact, dt=0.002), (0.5,), (20.0,), (state,), 750, 5, "plane")


@pytest.mark.parametrize("preset", ["cheese", "sphere"])
def test_presets_as_scene_files_are_the_old_presets(preset):
    old = _presets_as_they_were_built_in_code(preset, resolution=5)
    new = report_dataset_spec(preset, resolution=5)
    assert new.mesh.same_as(old.mesh)
    assert new.base_scene == old.base_scene
    assert (new.name, new.frictions, new.steps, new.record_every, new.initial_frame) == (
        old.name, old.frictions, old.steps, old.record_every, old.initial_frame)
    assert new.initial_states == old.initial_states
    assert new.scenes() == old.scenes()  # every run: planes, friction, placement on the plane
