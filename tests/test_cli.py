import errno
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from licrom.cli.commands import main
from licrom.learn.model import Model


def test_mesh_command_generates_and_converts(tmp_path, capsys):
    out = tmp_path / "c.vtu"
    assert main(["mesh", "cheese", "--resolution", "6", "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "tets" in text and "dihedral" in text and out.exists()
    assert main(["mesh", str(out)]) == 0
    assert "mesh file" in capsys.readouterr().out


def test_errors_are_one_line(tmp_path, capsys):
    assert main(["mesh", str(tmp_path / "missing.vtu")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("licrom: error: mesh file not found") and err.count("\n") == 1
    assert main(["mesh", "cheese", "--resolution", "0"]) == 2
    assert "resolution must be an integer >= 4" in capsys.readouterr().err


def test_installed_entry_point_runs():
    r = subprocess.run([sys.executable, "-m", "licrom.cli", "--help"], capture_output=True, text=True)
    assert r.returncode == 0 and "mesh" in r.stdout


def test_compare_command_reports_and_writes_pictures(tiny_demo, tmp_path, capsys):
    import json

    out = tmp_path / "new" / "folder"
    model = tiny_demo[0] / "model.lcm"
    args = ["compare", str(model), "--slope", "25", "--friction", "0.1", "--friction", "0.9", "--steps", "40",
            "--cubature", "40", "--out", str(out)]
    assert main(args) == 0
    text = capsys.readouterr().out
    assert "slope 25.0 deg, mu 0.1" in text and "slope 25.0 deg, mu 0.9" in text and "stick/slip" in text
    summary = json.loads((out / "summary.json").read_text())
    slides, sticks = summary["cases"]
    assert (slides["scene"], sticks["scene"]) == ("slope 25.0 deg, mu 0.1", "slope 25.0 deg, mu 0.9")
    assert slides["slid_full"] and not sticks["slid_full"]
    # The demo's layout (licrom.viz.report): same names, a summary.md and report.html.
    assert {p.name for p in out.iterdir()} == {"summary.json", "summary.md", "report.html", "errors.png", "runs",
                                               "filmstrip_slope25_mu0.1.png", "filmstrip_slope25_mu0.9.png",
                                               "animation_slope25_mu0.1.gif", "animation_slope25_mu0.9.gif"}
    assert {p.name for p in (out / "runs").iterdir()} == {f"{k}_slope25_mu{m}.npz" for k in ("full", "reduced") for m in ("0.1", "0.9")}
    assert "| slope 25.0 deg, mu 0.1 |" in (out / "summary.md").read_text()


def test_compare_command_sets_the_error_beside_the_scenes_sensitivity(tiny_demo, tmp_path, capsys):
    import json

    model = tiny_demo[0] / "model.lcm"
    args = ["compare", str(model), "--slope", "25", "--friction", "0.9", "--steps", "30", "--cubature", "40", "--sensitivity", "-q",
            "--out", str(tmp_path)]
    assert main(args) == 0
    text = capsys.readouterr().out
    assert "scene sensitivity" in text and "1 mm higher" in text and "E +2 %" in text and "h / 2" in text
    spread = re.search(r"spread ([0-9.]+) % / ([0-9.]+) % \((chaotic at a model's scale|well conditioned)\); the reduced run's non-rigid error is ([0-9.]+|inf)x it", text)
    assert spread is not None
    rows = [float(m) for m in re.findall(r"^  (?:1 mm higher|gravity turned .*|mu \+.*|E \+2 %) +([0-9.]+) %", text, re.M)]
    assert len(rows) == 5 and float(spread[1]) == pytest.approx(max(rows), abs=0.051)
    saved = json.loads((tmp_path / "summary.json").read_text())["sensitivity"]["slope 25.0 deg, mu 0.9"]
    assert 100 * saved["nonrigid_spread"] == pytest.approx(float(spread[1]), abs=0.051) and saved["chaotic"] == (spread[3] != "well conditioned")
    assert "Scene sensitivity" in (tmp_path / "summary.md").read_text()


def test_compare_command_refuses_bad_input(tiny_demo, tmp_path, capsys):
    bad = tmp_path / "model.lcm"
    bad.write_bytes(b"not a model")
    assert main(["compare", str(bad)]) == 2
    assert capsys.readouterr().err.startswith("licrom: error:")
    assert main(["compare", str(tiny_demo[0] / "model.lcm"), "--mesh", "sphere:abc"]) == 2
    assert "needs an integer resolution" in capsys.readouterr().err
    for value in ("optimal", "0", "-3"):
        assert main(["compare", str(tiny_demo[0] / "model.lcm"), "--cubature", value]) == 2
        assert "--cubature" in capsys.readouterr().err


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    from licrom import meshes
    from licrom.learn.training_data import make_synthetic_trajectories

    d = tmp_path_factory.mktemp("data")
    for k, t in enumerate(make_synthetic_trajectories(meshes.box((0.2, 0.1, 0.1), resolution=3), count=2, frames=4, seed=0)):
        t.save(d / f"traj_{k}.npz")
    return d


def _full_disk(monkeypatch):
    import licrom._io as lio

    def fsync(fd):  # where a delayed-allocation file system reports a full disk
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(lio.os, "fsync", fsync)
    return "no space left on the device"


def _read_only(monkeypatch):
    # simulated: as root, a chmod'ed folder stays writable
    import licrom._io as lio

    def mkstemp(*args, **kwargs):
        raise PermissionError(errno.EACCES, os.strerror(errno.EACCES))

    monkeypatch.setattr(lio.tempfile, "mkstemp", mkstemp)
    return "permission denied: the folder is read-only"


@pytest.mark.parametrize("failure", [_full_disk, _read_only], ids=["full", "read-only"])
def test_unwritable_outputs_are_one_line_errors(data, tmp_path, capsys, monkeypatch, failure):
    out = tmp_path / "out"
    commands = [
        ["mesh", "box", "--resolution", "4", "-o", str(out / "box.vtu")],
        ["generate", str(out / "gen"), "--resolution", "4", "--steps", "2", "-q"],
        ["train", str(data), "-o", str(out / "m.lcm"), "-r", "2", "--epochs", "1", "--points", "128", "--batch-frames", "4",
         "--width", "16", "--fourier", "0", "--val-fraction", "0", "--device", "cpu", "-q"],
    ]
    expected = failure(monkeypatch)
    for args in commands:
        assert main(args) == 2, args
        err = capsys.readouterr().err
        assert err.startswith("licrom: error: cannot write") and expected in err and err.count("\n") == 1, err
    assert [p for p in out.rglob("*") if p.is_file()] == []


def test_train_cubature_points_caps_the_fitted_cubature(data, tmp_path):
    model_path = tmp_path / "m.lcm"
    assert main(["train", str(data), "-o", str(model_path), "-r", "2", "--epochs", "1", "--points", "128", "--batch-frames", "4",
                 "--width", "16", "--fourier", "0", "--val-fraction", "0", "--device", "cpu", "--cubature-points", "3",
                 "--cubature-candidates", "40", "-q"]) == 0
    model = Model.load(model_path)
    assert 1 <= model.cubature.count <= 3
    assert model.metadata["cubature"]["max_count"] == 3 and model.metadata["cubature"]["candidates"] == 40


def test_train_reports_the_cubature_fits_it_chose_between(data, tmp_path, capsys, monkeypatch):
    from licrom.learn.training import run

    monkeypatch.setattr(run, "cubature_counts", lambda n_tets: (2, 30))  # the large-mesh choice, on the small data
    model_path = tmp_path / "m.lcm"
    assert main(["train", str(data), "-o", str(model_path), "-r", "2", "--epochs", "1", "--points", "128", "--batch-frames", "4",
                 "--width", "16", "--fourier", "0", "--val-fraction", "0.5", "--device", "cpu", "--cubature-candidates", "40"]) == 0
    printed = capsys.readouterr().out
    stored = Model.load(model_path).metadata["cubature"]
    for row in stored["choice"]:
        kept = "kept" if row["max_count"] == stored["max_count"] else "not kept"
        assert (f"fit of at most {row['max_count']} tets: {row['count']} tets, force residual {100 * row['fit_error']:.2f} %, worst held-out "
                f"run {row['target_ratio']:.2f}x its targets ({kept})") in printed, printed
    assert printed.count("(kept)") == 1


def test_out_of_range_flags_are_refused_with_the_flag_and_the_range(tmp_path, capsys):
    assert main(["generate", str(tmp_path / "d"), "--slope", "95"]) == 2  # used to run at 85 deg
    assert "Invalid value for '--slope': 95.0 is not in the range 0<=x<90." in capsys.readouterr().err
    assert main(["compare", str(tmp_path / "m.lcm"), "--slope", "95"]) == 2
    assert "'--slope': 95.0 is not in the range 0<=x<90" in capsys.readouterr().err
    assert main(["train", str(tmp_path), "-o", str(tmp_path / "m.lcm"), "-r", "0"]) == 2  # used to name ModelConfig.latent_dim
    assert "Invalid value for '--modes' / '-r': 0 is not in the range x>=1." in capsys.readouterr().err
    assert main(["demo", "--modes", "0"]) == 2
    assert "'--modes' / '-r': 0 is not in the range x>=1" in capsys.readouterr().err
    assert main(["generate", str(tmp_path / "d"), "--poisson-ratio", "0.5"]) == 2
    assert "'--poisson-ratio': 0.5 is not in the range -1<x<0.5" in capsys.readouterr().err
    assert not (tmp_path / "d").exists()


def test_generate_refuses_a_directory_in_use_and_a_ray_cluster_that_never_answers(tmp_path, capsys, monkeypatch):
    import fcntl
    import socket
    import types

    from licrom.data.dataset import LOCK_NAME

    small = ["--mesh", "box:1", "--friction", "0.5", "--slope", "10", "--steps", "2", "-q"]
    out = tmp_path / "d"
    out.mkdir()
    fd = os.open(out / LOCK_NAME, os.O_RDWR | os.O_CREAT)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)  # a licrom generate of another mesh writing the same directory
        assert main(["generate", str(out), *small]) == 2  # was 0, both runs writing mesh.vtu and the manifest
        err = capsys.readouterr().err
        assert err.startswith(f"licrom: error: dataset directory '{out}' is being written by another licrom generate") and err.count("\n") == 1
        assert f"holds its lock '{out / LOCK_NAME}'" in err and not (out / "mesh.vtu").exists()
    finally:
        os.close(fd)  # the lock goes with the descriptor

    monkeypatch.setitem(sys.modules, "ray", types.SimpleNamespace(is_initialized=lambda: False, init=lambda **kw: pytest.fail("ray.init")))
    with socket.socket() as s:  # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        monkeypatch.setenv("RAY_ADDRESS", f"127.0.0.1:{s.getsockname()[1]}")
    assert main(["generate", str(out), *small, "--executor", "ray", "--ray-timeout", "0.5"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("licrom: error: no Ray cluster at RAY_ADDRESS=") and "now 0.5 s" in err
    assert main(["generate", str(out), *small, "--executor", "ray", "--ray-timeout", "0"]) == 2
    assert "'--ray-timeout': 0.0 is not in the range x>0" in capsys.readouterr().err


def test_export_command_writes_every_format(tiny_demo, tmp_path, capsys):
    import meshio
    from PIL import Image
    from pxr import Usd

    runs = [str(tiny_demo[0] / "runs" / f"{kind}_slope20_mu0.1.npz") for kind in ("full", "reduced")]
    assert main(["export", *runs, "--format", "gif", "-o", str(tmp_path / "run.gif"), "--max-frames", "5", "--title", "t"]) == 0
    assert "wrote" in capsys.readouterr().out and Image.open(tmp_path / "run.gif").n_frames == 5
    assert main(["export", *runs, "--format", "png", "-o", str(tmp_path / "run.png"), "--color-by", "error", "--frames", "3"]) == 0
    assert main(["export", runs[0], "--format", "gif", "-o", str(tmp_path / "mpl.gif"), "--renderer", "matplotlib", "--max-frames", "3"]) == 0
    assert Image.open(tmp_path / "mpl.gif").n_frames == 3
    width, height = Image.open(tmp_path / "run.png").size
    assert width > height
    assert main(["export", *runs, "--format", "vtu", "-o", str(tmp_path / "vtu"), "--label", "full", "--label", "reduced"]) == 0
    assert {"full.pvd", "reduced.pvd", "full_plane_0.vtu"} <= {p.name for p in (tmp_path / "vtu").iterdir()}
    assert "contact_friction_force" in meshio.read(tmp_path / "vtu" / "reduced_0010.vtu").point_data
    assert main(["export", *runs, "--format", "usd", "-o", str(tmp_path / "run.usda")]) == 0
    stage = Usd.Stage.Open(str(tmp_path / "run.usda"))
    assert stage.GetPrimAtPath("/World/full_slope20_mu0_1").IsValid() and stage.GetPrimAtPath("/World/plane_0").IsValid()


def test_export_command_refuses_bad_input(tiny_demo, tmp_path, capsys):
    run = str(tiny_demo[0] / "runs" / "full_slope20_mu0.1.npz")
    assert main(["export", run, "--format", "vtu", "-o", str(tmp_path), "--label", "a", "--label", "b"]) == 2
    assert "--label must be given once per run" in capsys.readouterr().err
    assert main(["export", run, "--format", "usd", "-o", str(tmp_path / "run.obj")]) == 2
    assert ".usda" in capsys.readouterr().err
    assert main(["export", str(tmp_path / "missing.npz"), "--format", "gif", "-o", str(tmp_path / "x.gif")]) == 2
    assert "not found" in capsys.readouterr().err


def test_help_shows_every_default_one_way_and_as_the_configs_have_them():
    """Defaults in Click's '[default: X]' only (no hand-written '[X]'), and train's equal to its config classes'."""
    import re

    from click.testing import CliRunner
    from licrom.cli.commands import cli
    from licrom.learn.model import ModelConfig
    from licrom.learn.training import TrainConfig

    runner = CliRunner()
    shown = {}
    # Click's own notes: defaults, required, ranges, and choices as metavars
    clicks = re.compile(r"default: .*|required|[-\d.e]*<=?x(<=?[-\d.e]+)?|x[<>]=?[-\d.e]+|[\w-]+(\|[\w-]+)+")
    for name in cli.commands:
        text = runner.invoke(cli, [name, "--help"], terminal_width=1000, max_content_width=1000).output
        options = text.split("Options:", 1)[1]
        for note in re.findall(r"\[([^\]\[]*)\]\s*$", options, re.MULTILINE):
            assert clicks.fullmatch(note), f"licrom {name} --help: '[{note}]' is not Click's '[default: X]'"
        if name == "train":
            joined = re.sub(r"\n {8,}", " ", text)  # an option whose name fills its column has its help on the next line
            shown = {k: v.strip("()") for k, v in re.findall(r"^\s+(--[\w-]+)[^\n]*\[default: \(?([^\];]+)", joined, re.MULTILINE)}
    t, m = TrainConfig(), ModelConfig()
    expected = {"--rank-tolerance": t.rank_tolerance, "--max-rank": t.max_rank, "--objective": t.objective, "--pod-weighting": t.pod_weighting,
                "--epochs": t.epochs, "--lr": t.lr, "--nodes": t.nodes, "--join-timeout": t.join_timeout_s, "--batch-frames": t.batch_frames,
                "--points": t.points_per_frame, "--val-fraction": t.val_fraction, "--width": m.field_width, "--layers": m.field_layers,
                "--projection-weight": t.projection_weight, "--fourier": m.fourier_features, "--dynamics-max-rank": t.dynamics_max_rank,
                "--cubature-points": t.cubature_points}
    for option, value in expected.items():
        first = shown[option].strip("()")
        assert float(first) == float(value) if not isinstance(value, str) else first == value, (option, shown[option], value)


def test_the_readme_own_object_section_runs_as_written(tmp_path, monkeypatch, capsys):
    """The README's 'Your own object' commands, word for word, on a small closed surface; only the run
    lengths are cut (options appended: --steps, --epochs), so that the sequence's wiring is what is tested."""
    import re
    import shlex

    import meshio
    from test_surface import icosphere

    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    block = re.search(r"## Your own object.*?```bash\n(.*?)```", readme, re.DOTALL).group(1)
    commands = [shlex.split(line.split("#")[0]) for line in block.splitlines() if line.startswith("licrom ")]
    assert [c[1] for c in commands] == ["mesh", "scene", "generate", "train", "compare"]
    v, f = icosphere(radius=0.04, subdivisions=2)
    meshio.write(tmp_path / "potato.obj", meshio.Mesh(v * [1.5, 1.0, 0.8], [("triangle", f)]))
    monkeypatch.chdir(tmp_path)
    shorter = {"generate": ["--steps", "20", "-q"], "train": ["--epochs", "1", "-q"], "compare": ["--steps", "20", "-q"]}
    for command in commands:
        assert main(command[1:] + shorter.get(command[1], [])) == 0, (command, capsys.readouterr().err)
    scene_object = (tmp_path / "potato.toml").read_text().split("[object]")[1].split("[material]")[0]
    assert 'mesh = "potato.msh"' in scene_object and "resolution" not in scene_object
    assert {"report.html", "summary.md"} <= {p.name for p in (tmp_path / "potato-compare").iterdir()}
