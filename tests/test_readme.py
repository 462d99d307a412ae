"""The README's figures checker (``.ci/readme_figures``): its marks and the defaults, without the runs.

CI runs the checker in full (the README's snippet, its shorter training and ``licrom demo``); here the
``--static`` mode checks the README as it is, and that the checker fails on a README that is wrong.
"""

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CHECKER = ROOT / ".ci" / "readme_figures"


def check(readme: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(CHECKER), "--static", "--readme", str(readme)], capture_output=True, text=True)


def test_the_readme_marks_every_figure_and_quotes_the_defaults():
    result = check(ROOT / "README.md")
    assert result.returncode == 0, result.stdout + result.stderr
    for key in ("max_rank", "rank_tolerance", "warning_threshold", "default_epochs", "demo_target"):
        assert f"\n{key} " in result.stdout and "OUT OF TOLERANCE" not in result.stdout


@pytest.mark.parametrize("old, new, said", [
    ("<!-- figure max_rank ±0 -->120", "<!-- figure max_rank ±0 -->121", "max_rank"),          # a stale default
    ("<!-- figure rank ±2 -->", "", "figure 'rank'"),                                          # a figure left unmarked
    ("<!-- figure rank ±2 -->", "<!-- figure rnak ±2 -->", "unknown figure 'rnak'"),           # a mark of nothing known
    ("<!-- figure rank ±2 -->", "<!-- figure rank 2 -->", "malformed figure mark"),            # a mark without its tolerance
])
def test_the_checker_fails_on_a_wrong_readme(tmp_path, old, new, said):
    text = (ROOT / "README.md").read_text()
    assert old in text
    readme = tmp_path / "README.md"
    readme.write_text(text.replace(old, new, 1))
    result = check(readme)
    assert result.returncode == 1
    assert said in result.stderr
