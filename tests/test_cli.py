import subprocess
import sys

import pytest

from licrom.cli import main


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
