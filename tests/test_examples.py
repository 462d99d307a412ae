"""Every user example in ``examples/`` run as a test, with the small options CI gives it.

Each example runs as a user runs it: a fresh interpreter on the script with its command line,
everything written under ``tmp_path``. The test then checks what the example wrote and printed
(files that load, figures that parse), not only that it exited cleanly.
"""

from __future__ import annotations

import math
import re
import subprocess
import sys
from pathlib import Path

import licrom

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
PERCENT = r"(\d+(?:\.\d+)?) %"


def _run(*argv: str | Path, cwd: Path, timeout: float = 300) -> str:
    """Run ``python *argv`` in ``cwd``; its standard output (the test fails, showing stderr, on a non-zero exit)."""
    done = subprocess.run([sys.executable, *map(str, argv)], cwd=cwd, capture_output=True, text=True, timeout=timeout)
    assert done.returncode == 0, f"{argv} exited with {done.returncode}:\n{done.stdout}\n{done.stderr}"
    return done.stdout


def test_examples_are_all_tested():
    tested = {"hard_landing.py", "own_mesh.py", "train_subspace.py"}
    assert {p.name for p in EXAMPLES.glob("*.py")} == tested


def test_hard_landing(tmp_path):
    out = _run(EXAMPLES / "hard_landing.py", "--work", tmp_path / "work", "--steps", "10", "--pod", "4", cwd=tmp_path)
    truth = licrom.Trajectory.load(tmp_path / "work" / "truth.npz")
    assert truth.n_frames == 11
    rows = [line for line in out.splitlines() if line.startswith("| affine")]
    assert [row.split(" | ")[0] for row in rows] == ["| affine", "| affine + POD 4"]
    modes = [int(row.split(" | ")[1]) for row in rows]
    assert modes[1] == modes[0] + 4
    for row in rows:
        figures = [float(x) for x in re.findall(PERCENT, row)]
        assert len(figures) == 3 and all(math.isfinite(x) and x >= 0 for x in figures), row
    # POD modes of this very run hold it better than the affine modes alone.
    projection = [float(re.findall(PERCENT, row)[0]) for row in rows]
    assert projection[1] < projection[0]


def test_train_subspace(tmp_path):
    _run("-m", "licrom.cli", "generate", tmp_path / "data", "-r", "4", "--steps", "10", "-q", cwd=tmp_path)
    model_path = tmp_path / "subspace.lcm"
    out = _run(EXAMPLES / "train_subspace.py", tmp_path / "data", "--epochs", "2", "--modes", "4", "--device", "cpu", "--out", model_path, cwd=tmp_path)
    model = licrom.Model.load(model_path)
    assert model.n_modes == 4
    shapes = re.search(r"values \((\d+), 3, (\d+)\) jacobians \((\d+), 3, 3, (\d+)\)", out)
    assert shapes is not None, out
    assert [int(x) for x in shapes.groups()] == [model.mesh.n_tets, 4, model.mesh.n_tets, 4]
    for name in ("projection", "encoder"):
        found = re.search(rf"{name}: full error {PERCENT}, residual error {PERCENT}", out)
        assert found is not None, out
        assert all(math.isfinite(float(x)) for x in found.groups())


def test_own_mesh(tmp_path):
    work = tmp_path / "own-mesh"
    out = _run(EXAMPLES / "own_mesh.py", "--small", "--work", work, cwd=tmp_path)
    for name in ("potato.obj", "potato.msh", "potato.toml", "potato-data", "potato.lcm", "potato-compare"):
        assert (work / name).exists(), name
    assert licrom.Model.load(work / "potato.lcm").n_modes == 8
    times = re.findall(r"^\| `licrom (\w+) .*` \| (\d+\.\d) s \|$", out, flags=re.MULTILINE)
    assert [command for command, _ in times] == ["mesh", "scene", "generate", "train", "compare"]
    total = re.search(r"^\| total \| (\d+\.\d) s \|$", out, flags=re.MULTILINE)
    assert total is not None
    # Each time is rounded to 0.1 s, the total too.
    assert abs(float(total.group(1)) - sum(float(t) for _, t in times)) <= 0.05 * (len(times) + 1) + 1e-9
