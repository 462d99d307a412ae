"""The file layer (licrom._io) and every loader against damaged and hostile files.

Writes: atomic, a full or read-only disk or a directory in the way is an OutputError, and a
killed writer's temporary file is removed by the next write in its folder. Reads: array
headers are checked before anything is allocated, and random truncations, bit flips and
garbage headers of every format give a FileFormatError (or load), never another exception.
"""

import errno
import io
import json
import os
import subprocess
import sys
import zipfile

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from licrom import ConfigError, FileFormatError, OutputError, Scene, Trajectory, meshes
from licrom._io import atomic_path, load_npz, save_npz

FAST = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _trajectory(frames=3):
    m = meshes.box(0.1, 2)
    u = 1e-3 * np.random.default_rng(0).standard_normal((frames, m.n_vertices, 3))
    return Trajectory(m.vertices, m.tets, u, 10 * u, np.arange(frames) * 0.01, Scene(), info={"source": "test"})


def _hidden(folder):
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


# --- writes --------------------------------------------------------------------------------
def _full_disk_writer(monkeypatch):
    """np.savez_compressed that writes part of the file and then finds the disk full."""

    def write(fh, **arrays):
        fh.write(b"PK\x03\x04" + b"\0" * 64)
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(np, "savez_compressed", write)


def test_full_disk_keeps_the_old_file_and_leaves_nothing(tmp_path, monkeypatch):
    path = _trajectory().save(tmp_path / "t.npz")
    before = path.read_bytes()
    _full_disk_writer(monkeypatch)
    with pytest.raises(OutputError, match=r"cannot write '.*t\.npz': no space left on the device") as info:
        _trajectory(4).save(path)
    assert info.value.errno == errno.ENOSPC and isinstance(info.value, OSError)
    assert path.read_bytes() == before and _hidden(tmp_path) == []


def test_read_only_folder_and_directory_targets_are_named(tmp_path, monkeypatch):
    import licrom._io as lio

    # a directory where the file should go
    with pytest.raises(OutputError, match="is a directory"):
        save_npz(tmp_path, {}, {"kind": "x"})
    (tmp_path / "file").touch()
    with pytest.raises(OutputError, match="a part of the path is a file"):
        save_npz(tmp_path / "file" / "inner.npz", {}, {"kind": "x"})

    # a read-only folder (simulated: as root, chmod does not stop writes)
    def refuse(*args, **kwargs):
        raise PermissionError(errno.EROFS, os.strerror(errno.EROFS))

    monkeypatch.setattr(lio.tempfile, "mkstemp", refuse)
    with pytest.raises(OutputError, match="permission denied: the folder is read-only") as info:
        _trajectory().save(tmp_path / "ro.npz")
    assert info.value.errno == errno.EROFS and not (tmp_path / "ro.npz").exists()


_KILLED_WRITE = """
import os, signal, sys
import numpy as np
from licrom import Scene, Trajectory, meshes

def killed(fh, **arrays):
    fh.write(b"PK half a file")
    fh.flush()
    os.kill(os.getpid(), signal.SIGKILL)

np.savez_compressed = killed
m = meshes.box(0.1, 2)
u = np.zeros((2, m.n_vertices, 3))
Trajectory(m.vertices, m.tets, u, u, [0.0, 0.01], Scene()).save(sys.argv[1])
"""


def test_a_killed_write_leaves_a_temporary_file_that_the_next_run_removes(tmp_path):
    target = tmp_path / "traj_000.npz"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    killed = subprocess.run([sys.executable, "-c", _KILLED_WRITE, str(target)], env=env, capture_output=True)
    assert killed.returncode == -9, killed.stderr
    stale = _hidden(tmp_path)
    assert len(stale) == 1 and stale[0].startswith(".traj_000.npz.licrom-tmp-") and not target.exists()
    # a temporary file of a live writer (this process's parent) is left alone
    (tmp_path / f".other.npz.licrom-tmp-{os.getppid()}-x.npz").write_bytes(b"in progress")
    # the next run writing into the folder (a new process) removes the killed writer's file
    rerun = "import sys; from licrom import Scene; from licrom._io import atomic_path\n" \
            "with atomic_path(sys.argv[1]) as tmp: tmp.write_text(Scene().to_json())"
    subprocess.run([sys.executable, "-c", rerun, str(tmp_path / "scene.json")], env=env, check=True)
    assert _hidden(tmp_path) == [f".other.npz.licrom-tmp-{os.getppid()}-x.npz"]


def test_atomic_path_passes_licrom_errors_through(tmp_path):
    with pytest.raises(ConfigError), atomic_path(tmp_path / "x.json"):
        raise ConfigError("not an output problem")
    assert list(tmp_path.iterdir()) == []


def test_a_rewritten_file_keeps_its_mode(tmp_path):
    from click.testing import CliRunner
    from licrom.cli.commands import cli

    path = _trajectory().save(tmp_path / "t.npz")
    os.chmod(path, 0o600)
    _trajectory(4).save(path)
    assert (os.stat(path).st_mode & 0o7777) == 0o600 and _hidden(tmp_path) == []
    scene = tmp_path / "scene.toml"
    scene.write_text("old")
    os.chmod(scene, 0o640)
    result = CliRunner().invoke(cli, ["scene", "cheese", "-o", str(scene)])
    assert result.exit_code == 0, result.output
    assert (os.stat(scene).st_mode & 0o7777) == 0o640 and scene.read_text() != "old"
    # a new file gets what open() would give it
    umask = os.umask(0o022)
    try:
        fresh = _trajectory().save(tmp_path / "fresh.npz")
    finally:
        os.umask(umask)
    assert (os.stat(fresh).st_mode & 0o7777) == 0o644


def test_outputs_that_are_not_regular_files_are_refused(tmp_path):
    import socket

    fifo = tmp_path / "pipe.npz"
    os.mkfifo(fifo)
    with pytest.raises(OutputError, match=r"cannot write '.*pipe\.npz': it is a FIFO \(named pipe\), not a regular file"):
        _trajectory().save(fifo)
    assert fifo.is_fifo() and _hidden(tmp_path) == []
    sock_path = tmp_path / "s.json"
    sock = socket.socket(socket.AF_UNIX)
    try:
        sock.bind(str(sock_path))
        with pytest.raises(OutputError, match="it is a socket"), atomic_path(sock_path) as tmp:
            tmp.write_text("{}")
        assert sock_path.is_socket()
    finally:
        sock.close()
    with pytest.raises(OutputError, match=r"'/dev/null': it is a character device"), atomic_path("/dev/null") as tmp:
        tmp.write_text("{}")
    assert os.path.exists("/dev/null") and not os.path.isfile("/dev/null")
    # a symlink is still replaced, not followed
    real = tmp_path / "real.json"
    real.write_text("real")
    link = tmp_path / "link.json"
    link.symlink_to(real)
    with atomic_path(link) as tmp:
        tmp.write_text("new")
    assert not link.is_symlink() and link.read_text() == "new" and real.read_text() == "real"


def test_any_legal_name_can_be_written_and_longer_names_are_named(tmp_path):
    for length in (231, 250, 255):
        name = "t" * (length - 4) + ".npz"
        path = _trajectory().save(tmp_path / name)
        assert Trajectory.load(path).n_frames == 3 and _hidden(tmp_path) == []
        path.unlink()
    long = tmp_path / ("t" * 300 + ".npz")
    with pytest.raises(OutputError, match=r"cannot write '.*tttt\.npz': its name is 304 bytes long, over the "
                                          r"file system's limit of 255 bytes") as info:
        _trajectory().save(long)
    assert info.value.errno == errno.ENAMETOOLONG and list(tmp_path.iterdir()) == []
    with pytest.raises(OutputError, match="over the file system's limit of 255 bytes"):
        _trajectory().save(tmp_path / ("d" * 300) / "t.npz")
    with pytest.raises(FileFormatError, match=r"'.*tttt\.npz': its name is 304 bytes long, over the file system's limit"):
        Trajectory.load(long)


# --- reads: sizes and types checked before allocating --------------------------------------
def _npz_with_member(path, name, header_bytes, body):
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("header_json.npy", _npy(np.array(json.dumps({"kind": "trajectory", "version": 1}))))
        zf.writestr(name, header_bytes + body)


def _npy(a):
    buf = io.BytesIO()
    np.lib.format.write_array(buf, a)
    return buf.getvalue()


def test_a_member_declaring_a_huge_shape_is_refused_before_allocating(tmp_path):
    p = tmp_path / "huge.npz"
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": "<f8", "fortran_order": False, "shape": (2**40,)})
    _npz_with_member(p, "times.npy", buf.getvalue(), np.zeros(4).tobytes())
    with pytest.raises(FileFormatError, match=r"declares an array of shape \(1099511627776,\).*holds 32 bytes"):
        Trajectory.load(p)


def test_a_member_claiming_more_bytes_than_deflate_can_hold_is_refused(tmp_path):
    p = tmp_path / "bomb.npz"
    _npz_with_member(p, "times.npy", b"", _npy(np.zeros(3)))
    raw = bytearray(p.read_bytes())
    # raise the declared uncompressed size of the last member in the central directory to 4 GB
    cd = raw.rfind(b"PK\x01\x02")
    raw[cd + 24 : cd + 28] = (0xFFFFFFF0).to_bytes(4, "little")
    p.write_bytes(bytes(raw))
    with pytest.raises(FileFormatError, match=r"declares 4294967280 bytes stored in \d+ bytes"):
        Trajectory.load(p)


@pytest.mark.parametrize(
    "header, match",
    [([1, 2], "a JSON list, expected an object"), ("text", "a JSON str"), ({"kind": "model"}, "expected a 'trajectory'")],
)
def test_header_of_the_wrong_json_type(tmp_path, header, match):
    p = tmp_path / "h.npz"
    np.savez_compressed(p, header_json=np.array(json.dumps(header)))
    with pytest.raises(FileFormatError, match=match):
        load_npz(p, "trajectory")


def test_object_arrays_are_refused(tmp_path):
    p = tmp_path / "o.npz"
    np.savez(p, header_json=np.array('{"kind": "trajectory"}'), times=np.array([{"a": 1}], dtype=object))
    with pytest.raises(FileFormatError, match="Python objects"):
        Trajectory.load(p)


# --- every loader against damaged and hostile files (property-based) ---------------------
def _damage(data: bytes, draw) -> bytes:
    how = draw(st.sampled_from(["truncate", "flip", "garbage"]))
    if how == "truncate":
        return data[: draw(st.integers(0, len(data) - 1))]
    if how == "flip":
        out = bytearray(data)
        for pos in draw(st.lists(st.integers(0, len(data) - 1), min_size=1, max_size=4)):
            out[pos] ^= 1 << draw(st.integers(0, 7))
        return bytes(out)
    head = draw(st.binary(min_size=1, max_size=64))
    return head + data[len(head) :]


json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-(2**70), 2**70) | st.floats(allow_nan=False) | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4),
    max_leaves=12,
)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """Valid files of every format (bytes), and a scratch folder."""
    from licrom.data.dataset import MANIFEST_NAME
    from licrom.learn.model import LicromNet, Model, ModelConfig

    d = tmp_path_factory.mktemp("valid")
    traj = _trajectory().save(d / "t.npz").read_bytes()
    mesh = meshes.box(0.1, 2)
    net = LicromNet(ModelConfig(latent_dim=2, field_width=8, field_layers=2, fourier_features=2,
                                encoder_point_widths=(4,), encoder_fc_widths=(), frame="world"))
    model = Model(net, mesh, [Scene()]).save(d / "m.lcm").read_bytes()
    manifest = json.dumps({"format": "licrom.dataset", "version": 1, "trajectories": [{"file": "traj_000.npz"}]}).encode()
    ckpt = io.BytesIO()
    torch.save({"state_dict": {"w": torch.ones(3)}, "epoch": 1, "licrom_run": {"data": "ab", "r": 2}}, ckpt)
    scratch = tmp_path_factory.mktemp("scratch")
    return {"trajectory": traj, "model": model, "manifest": manifest, "checkpoint": ckpt.getvalue(),
            "scene": Scene().to_json().encode(), "scratch": scratch, "manifest_name": MANIFEST_NAME}


def _load(kind, files, data):
    """Write ``data`` as a ``kind`` file and load it with licrom's loader."""
    from licrom.data.dataset import load_manifest
    from licrom.learn.model import Model
    from licrom.learn.training.checkpoints import read_checkpoint

    folder = files["scratch"]
    if kind == "scene":
        return Scene.from_json(data.decode("utf-8", errors="replace"))
    path = folder / {"trajectory": "t.npz", "model": "m.lcm", "manifest": files["manifest_name"], "checkpoint": "last.ckpt"}[kind]
    path.write_bytes(data)
    return {"trajectory": Trajectory.load, "model": Model.load, "checkpoint": read_checkpoint,
            "manifest": lambda p: load_manifest(p.parent)}[kind](path)


# Scene JSON written by hand may also hold values out of range: ConfigError names the field.
_ACCEPTED = {"scene": (FileFormatError, ConfigError)}


@pytest.mark.parametrize("kind", ["trajectory", "model", "scene", "manifest", "checkpoint"])
@FAST
@given(data=st.data())
def test_damaged_files_raise_file_format_error_or_load(files, kind, data):
    damaged = _damage(files[kind], data.draw)
    try:
        _load(kind, files, damaged)
    except _ACCEPTED.get(kind, FileFormatError):
        pass


@pytest.mark.parametrize("kind", ["trajectory", "model"])
@FAST
@given(data=st.data())
def test_garbage_in_npz_headers_raises_file_format_error_or_loads(files, kind, data):
    header, arrays = load_npz(_save_valid(files, kind), kind)
    # replace, add or drop header fields, or the whole header, with random JSON
    if data.draw(st.booleans()):
        header = data.draw(json_values)
    else:
        for key in data.draw(st.lists(st.sampled_from(sorted(header) + ["x"]), min_size=1, max_size=3)):
            if data.draw(st.booleans()):
                header[key] = data.draw(json_values)
            else:
                header.pop(key, None)
    if data.draw(st.booleans()) and arrays:  # and reshape or retype one array
        name = data.draw(st.sampled_from(sorted(arrays)))
        arrays[name] = data.draw(st.sampled_from([arrays[name].ravel(), arrays[name].astype(np.float32),
                                                  np.zeros((0,) + arrays[name].shape[1:]), np.array(np.nan)]))
    payload = {**arrays, "header_json": np.array(json.dumps(header))}
    path = files["scratch"] / f"g.{kind}.npz"
    np.savez_compressed(path, **payload)
    try:
        _load_path(kind, path)
    except FileFormatError:
        pass


@FAST
@given(value=json_values, depth=st.integers(1, 5000))
def test_garbage_and_deep_scene_json_raise_named_errors(value, depth):
    for text in (json.dumps(value), "[" * depth + "]" * depth, '{"format": "licrom.scene", "version": 1, "material": ' + "[" * depth):
        with pytest.raises((FileFormatError, ConfigError)):
            Scene.from_json(text)


def _save_valid(files, kind):
    path = files["scratch"] / f"valid.{kind}.npz"
    path.write_bytes(files[kind])
    return path


def _load_path(kind, path):
    from licrom.learn.model import Model

    return (Trajectory.load if kind == "trajectory" else Model.load)(path)



# The members whose values (not only their shapes) a loader must check: the model's weights and scalars, the
# trajectory's mesh part. Each gets the right shape and dtype but a poisoned value somewhere.
_POISONED = {"model": lambda name: True, "trajectory": lambda name: name in ("rest_positions", "tets")}


@pytest.mark.parametrize("kind", ["trajectory", "model"])
@FAST
@given(data=st.data())
def test_poisoned_values_in_weights_and_mesh_parts_raise_file_format_error(files, kind, data):
    header, arrays = load_npz(_save_valid(files, kind), kind)
    names = sorted(n for n in arrays if _POISONED[kind](n) and arrays[n].size and arrays[n].dtype.kind in "fiu")
    name = data.draw(st.sampled_from(names))
    a = arrays[name].copy()
    at = data.draw(st.integers(0, a.size - 1))
    if a.dtype.kind == "f":
        a.flat[at] = data.draw(st.sampled_from([np.nan, np.inf, -np.inf]))
    else:  # tet indices: negative or past the last vertex
        n = len(arrays["rest_positions" if kind == "trajectory" else "rest_vertices"])
        a.flat[at] = data.draw(st.sampled_from([-1, -(2**31), n, 2**31 - 1]))
    arrays[name] = a
    path = files["scratch"] / f"p.{kind}.npz"
    np.savez_compressed(path, **arrays, header_json=np.array(json.dumps(header)))
    with pytest.raises(FileFormatError):
        _load_path(kind, path)
