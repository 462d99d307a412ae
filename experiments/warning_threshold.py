"""The `AccuracyWarning` threshold against issue 23's flag rule, from runs already measured.

    python experiments/warning_threshold.py --cubature-rows out/cubest/rows.json --defaults out/body_frame_c10/defaults.json

A threshold does not change a run, so this reads the rows that ``experiments/cubature_estimate.py`` (``--out``'s
``rows.json``: one row per run, ``true`` and ``estimate``) and ``experiments/defaults_experiments.py`` (its
``defaults.json``: per held-out scene, each cubature's run with ``nonrigid_error`` and ``estimate``) wrote, and prints,
per set and per threshold, "flagged / above 15 %, false alarms / flags" (the rule: flag every run above 15 % true
error, at most one false alarm in five flags) and Spearman's rho of the estimate against the true error.
docs/results.md section 50 is its output.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from cubature_estimate import flag_rule
from licrom.reduced.error_estimate import ERROR_THRESHOLD
from scipy.stats import spearmanr

THRESHOLDS = (0.15, 0.12, 0.10, 0.08, 0.07)
"""Estimates above which a run is flagged; the current :data:`licrom.reduced.error_estimate.ERROR_THRESHOLD` is marked."""


def cubature_rows(path: Path) -> dict[str, list[tuple[float, float]]]:
    """``experiments/cubature_estimate.py``'s runs, as one set of (true, estimate)."""
    rows = json.loads(path.read_text())
    return {f"{path.parent.name}: {len(rows)} runs": [(r["true"], r["estimate"]) for r in rows]}


def defaults_rows(path: Path) -> dict[str, list[tuple[float, float]]]:
    """``experiments/defaults_experiments.py``'s runs: all of them, and those of the default cubature alone."""
    every, default = [], []
    for row in json.loads(path.read_text())["rows"]:
        for cubature, run in row["runs"].items():
            if run.get("estimate") is None:
                continue
            every.append((run["nonrigid_error"], run["estimate"]))
            if cubature == "default":
                default.append((run["nonrigid_error"], run["estimate"]))
    name = path.parent.name
    return {f"{name}: {len(every)} runs": every, f"{name}: its {len(default)} default-cubature runs": default}


def table(sets: dict[str, list[tuple[float, float]]]) -> str:
    """Markdown: a row per threshold, a column per set, then each set's rho."""
    lines = ["| threshold | " + " | ".join(sets) + " |", "|---|" + "---|" * len(sets)]
    for t in THRESHOLDS:
        mark = " (now)" if t == ERROR_THRESHOLD else ""
        cells = [flag_rule(np.array([a for a, _ in v]), np.array([b for _, b in v]), t) for v in sets.values()]
        lines.append(f"| {100 * t:g} %{mark} | " + " | ".join(cells) + " |")
    rhos = "; ".join(f"{k}: {spearmanr([a for a, _ in v], [b for _, b in v])[0]:.2f}" for k, v in sets.items() if len(v) > 2)
    return "\n".join(lines + ["", f"Spearman's rho, estimate against true error: {rhos}."])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cubature-rows", type=Path, action="append", default=[], help="rows.json of cubature_estimate.py")
    ap.add_argument("--defaults", type=Path, action="append", default=[], help="defaults.json of defaults_experiments.py")
    args = ap.parse_args()
    sets: dict[str, list[tuple[float, float]]] = {}
    for path in args.cubature_rows:
        sets.update(cubature_rows(path))
    for path in args.defaults:
        sets.update(defaults_rows(path))
    if not sets:
        ap.error("give at least one --cubature-rows or --defaults file")
    print(table(sets))


if __name__ == "__main__":
    main()
