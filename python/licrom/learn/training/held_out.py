"""The trained model checked as a user runs it, on the runs the training held out.

At the end of :func:`~licrom.learn.training.train`, every held-out (validation) run's scene is
simulated with ``ReducedSim(model, scene=scene)`` and nothing else (the model's own r,
fitted cubature and contact points), over the run's steps, and compared with the run
(:func:`licrom.analysis.compare.compare`): the non-rigid deformation error, the final centre of
mass, stick/slip, and the reduced run's own online error estimate beside them. The
training report says how wrong the model is on motion it has not seen, and whether its
estimate knows: an :class:`~licrom.errors.AccuracyWarning` names every held-out run that misses
a target (non-rigid error at or above :data:`~licrom.analysis.compare.NONRIGID_TARGET`, final
centre of mass at or above :data:`~licrom.analysis.compare.COM_TARGET` of the size, stick/slip wrong).
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Sequence
from typing import Any

import numpy as np

from ...analysis.compare import COM_TARGET, METRICS, NONRIGID_TARGET, compare, verdict
from ...errors import AccuracyWarning, LicromError, LicromWarning
from ...records.trajectory import Trajectory
from ...reduced.base import ReducedSim
from ...reduced.error_estimate import ERROR_THRESHOLD
from ..model import Model

__all__ = ["CHAOS_HINT", "HELD_OUT_RUNS", "REMEDY", "check_held_out", "held_out_lines", "replay_held_out", "target_ratio", "warn_misses"]

HELD_OUT_RUNS = 8
"""Held-out runs checked at most (the first ones of the split): each costs a reduced run and a comparison."""


REMEDY = "train with more runs like them, or allow more modes (--max-rank, --rank-tolerance, --dynamics-max-rank)"
"""What the held-out warning advises by default; training passes another where the dynamics check did not run
(:func:`licrom.learn.training.dynamics.large_mesh_remedy`)."""

CHAOS_HINT = ("a run can miss because its scene is chaotic, not the model: `licrom compare MODEL --sensitivity` measures how "
              "far its own full run moves when an input moves a little (docs/results.md section 68)")
"""Said before the remedy in every held-out warning: a tumble whose own full run moves 15-49 % when dropped 1 mm higher or
turned by a degree misses by as much with any model (:mod:`licrom.analysis.sensitivity`)."""


def run_cadence(run: Trajectory) -> tuple[int, int] | None:
    """``(steps, record_every)`` of a recorded run, to replay it step for step; None where its frames are not evenly
    spaced steps."""
    steps = len(run.iterations)
    frames = run.n_frames - 1
    if steps < 1 or frames < 1 or steps % frames:
        return None
    return steps, steps // frames


def check_held_out(model: Model, runs: Sequence[tuple[str, Trajectory]], max_runs: int = HELD_OUT_RUNS, remedy: str = REMEDY) -> dict[str, Any]:
    """:func:`replay_held_out`, then :func:`warn_misses` with ``remedy``: the check as training runs it."""
    report = replay_held_out(model, runs, max_runs)
    warn_misses(report, remedy, stacklevel=4)
    return report


def replay_held_out(model: Model, runs: Sequence[tuple[str, Trajectory]], max_runs: int = HELD_OUT_RUNS) -> dict[str, Any]:
    """Run ``ReducedSim(model, scene=run.scene)`` on each held-out run and compare it with the run.

    Args:
        model: the trained model (with its fitted cubature).
        runs: ``(name, full run)`` of the held-out runs.
        max_runs: runs checked at most.

    Returns:
        ``{"runs": [per run: name, nonrigid_error, com_error, stick_slip_right, estimate, estimate_terms (the
        estimate's two terms, ``Trajectory.info["error_estimate_terms"]``), flagged, step_ms, seconds],
        "worst_nonrigid_error", "threshold"}``; a run the check cannot replay
        (frames not evenly spaced, or the reduced run fails) has ``"skipped"`` with the reason.
    """
    rows: list[dict[str, Any]] = []
    for name, run in list(runs)[:max_runs]:
        cadence = run_cadence(run)
        if cadence is None:
            rows.append({"run": name, "skipped": f"{run.n_frames} frames over {len(run.iterations)} steps are not evenly spaced"})
            continue
        start = time.perf_counter()
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", LicromWarning)  # reported below, per run
                reduced = ReducedSim(model, scene=run.scene).run(cadence[0], record_every=cadence[1])
            c = compare(run, reduced)
        except LicromError as exc:
            rows.append({"run": name, "skipped": f"{type(exc).__name__}: {exc}"})
            continue
        rows.append({
            "run": name,
            "nonrigid_error": float(c.nonrigid_error),
            "com_error": float(c.final_com_error),
            "stick_slip_right": bool(c.stick_slip_agree),
            "estimate": float(c.error_estimate),
            "estimate_terms": reduced.info["error_estimate_terms"],
            "flagged": bool(c.error_estimate > ERROR_THRESHOLD),
            "step_ms": float(1e3 * np.median(reduced.step_seconds)),
            "seconds": time.perf_counter() - start,
        })
    worst = max((r["nonrigid_error"] for r in rows if "skipped" not in r), default=float("nan"))
    return {"runs": rows, "worst_nonrigid_error": worst, "threshold": ERROR_THRESHOLD}


def warn_misses(report: dict[str, Any], remedy: str = REMEDY, stacklevel: int = 2) -> None:
    """An :class:`~licrom.errors.AccuracyWarning` naming every run of ``report`` (:func:`replay_held_out`) that misses a
    target, ending with ``remedy``; none where every run meets."""
    done = [r for r in report["runs"] if "skipped" not in r]
    misses = [(r, what) for r in done if (what := _missed(r))]
    if misses:
        shown = "; ".join(f"{r['run']} ({', '.join(what)}; estimated non-rigid {100 * r['estimate']:.1f} %)" for r, what in misses)
        warnings.warn(
            f"the trained model misses {len(misses)} of its {len(done)} held-out runs with its defaults: {shown}; {CHAOS_HINT}; {remedy}",
            AccuracyWarning, stacklevel=stacklevel)


def target_ratio(report: dict[str, Any]) -> float:
    """How far the worst checked run of ``report`` (:func:`replay_held_out`) is from its targets: the largest of its
    non-rigid error over :data:`~licrom.analysis.compare.NONRIGID_TARGET` and its final centre of mass over
    :data:`~licrom.analysis.compare.COM_TARGET` (below 1: every run meets; infinite where a run's stick/slip is wrong);
    NaN where no run was checked."""
    done = [r for r in report["runs"] if "skipped" not in r]
    ratios = [max(_over(r["nonrigid_error"], NONRIGID_TARGET), _over(r["com_error"], COM_TARGET)) if r["stick_slip_right"] else float("inf")
              for r in done]
    return max(ratios, default=float("nan"))


def _over(value: float, target: float) -> float:
    """``value / target``; a target of 0 is missed by any error (infinite ratio) and met by none."""
    return value / target if target > 0 else (float("inf") if value > 0 else 0.0)


def _missed(row: dict[str, Any]) -> list[str]:
    """The targets a checked run misses, each with its value: non-rigid error at or above ``NONRIGID_TARGET``, centre of
    mass at or above ``COM_TARGET``, stick/slip wrong."""
    what = []
    if row["nonrigid_error"] >= NONRIGID_TARGET:
        what.append(f"non-rigid error {100 * row['nonrigid_error']:.1f} % >= {100 * NONRIGID_TARGET:.0f} %")
    if row["com_error"] >= COM_TARGET:
        what.append(f"final centre of mass {100 * row['com_error']:.2f} % of the size >= {100 * COM_TARGET:.0f} %")
    if not row["stick_slip_right"]:
        what.append("stick/slip wrong")
    return what


def held_out_lines(report: dict[str, Any]) -> list[str]:
    """The check as lines of text for the training report (one per run)."""
    lines = []
    for r in report.get("runs", []):
        if "skipped" in r:
            lines.append(f"  {r['run']}: not checked ({r['skipped']})")
            continue
        ok, missed = verdict({"nonrigid_error": r["nonrigid_error"], "final_com_error": r["com_error"],
                              "stick_slip_agree": r["stick_slip_right"]})
        lines.append(
            f"  {r['run']}: non-rigid error {100 * r['nonrigid_error']:.1f} % (estimate {100 * r['estimate']:.1f} %"
            # reports of models trained before the estimate had its cubature term hold the estimate alone
            + (f": outside the subspace {100 * r['estimate_terms']['residual']:.1f} %, the cubature's {100 * r['estimate_terms']['cubature']:.1f} %"
               if "estimate_terms" in r else "")
            + f"{', flagged' if r['flagged'] else ''}), final centre of mass {100 * r['com_error']:.2f} % of the size, "
            f"stick/slip {'right' if r['stick_slip_right'] else 'WRONG'}, {r['step_ms']:.2f} ms a step: "
            + ("meets every target" if ok else "misses " + ", ".join(missed)))
    if lines:
        lines += [f"  {m.name} (target {m.target}): {m.definition}" for m in METRICS if m.key in ("nonrigid_error", "final_com_error")]
    return lines
