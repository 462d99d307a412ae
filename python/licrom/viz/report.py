"""The report of full-against-reduced comparisons: one folder layout for ``licrom demo`` and ``licrom compare --out``.

For every scene compared, ``filmstrip_TAG.png`` and ``animation_TAG.gif`` (full and reduced side by
side, one colour scale shared by all scenes) and ``runs/full_TAG.npz``, ``runs/reduced_TAG.npz``;
then ``errors.png`` (error curves), ``summary.json``, ``summary.md`` and ``report.html``: a single
self-contained page (pictures embedded) with the summary table, what each number means, its target
and whether it is met. The metrics, their definitions and their targets are the table
:data:`licrom.analysis.compare.METRICS`, the one place the summaries, the report and the training's
held-out check read them from.
"""

from __future__ import annotations

import base64
import html
import json
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .._io import atomic_path, make_dir
from ..analysis.compare import METRICS, Comparison, Metric, judge, verdict
from ..records.trajectory import Trajectory

__all__ = ["Case", "case_tag", "write_report"]


@dataclass(frozen=True)
class Case:
    """One scene compared: its label, its file tag, the comparison and both runs."""

    label: str
    tag: str
    comparison: Comparison
    full: Trajectory
    reduced: Trajectory


def case_tag(label: str, scene: Any, taken: Sequence[str] = ()) -> str:
    """The file-name tag of a scene: ``slope20_mu0.25`` from its first plane (else the label), unique among ``taken``."""
    if getattr(scene, "planes", ()):
        p = scene.planes[0]
        base = f"slope{p.slope_deg:.3g}_mu{p.friction:g}"
    else:
        base = re.sub(r"[^A-Za-z0-9.]+", "_", label).strip("_") or "scene"
    tag, k = base, 2
    while tag in taken:
        tag, k = f"{base}_{k}", k + 1
    return tag


def write_report(cases: Sequence[Case], out: str | Path, title: str, description: str, renderer: str,
                 extra: dict[str, Any] | None = None, footer: str = "") -> dict[str, Any]:
    """Write the pictures, runs, summaries and ``report.html`` of ``cases`` into ``out``; return the summary.

    Args:
        cases: the scenes compared.
        out: the folder (made if missing).
        title: the report's heading.
        description: a line on the model and the mesh.
        renderer: ``"pyvista"`` or ``"matplotlib"`` (:func:`licrom.viz.render.pick_renderer`).
        extra: more JSON-ready entries of ``summary.json`` (e.g. timings).
        footer: a last line of ``summary.md`` and the report.
    """
    from .render import RenderStyle, deformation_mm, pictures, plot_errors

    folder = make_dir(out)
    top = max(float(deformation_mm(t).max()) for c in cases for t in (c.full, c.reduced)) if cases else 1.0
    style = RenderStyle(clim=(0.0, max(top, 0.01)))
    rows = []
    for c in cases:
        pictures([c.full, c.reduced], ["full", "reduced"], folder, c.tag, title=c.label, renderer=renderer, style=style)
        c.full.save(folder / "runs" / f"full_{c.tag}.npz")
        c.reduced.save(folder / "runs" / f"reduced_{c.tag}.npz")
        s = c.comparison.summary()
        ok, missed = verdict(s)
        rows.append({"scene": c.label, "tag": c.tag, **s, "meets_targets": ok, "missed": missed})
    if cases:
        plot_errors({c.label: c.comparison for c in cases}, folder / "errors.png")
    summary = {"title": title, "description": description, **(extra or {}), "cases": rows,
               "targets": {m.key: m.target for m in METRICS if m.target}}
    for name, text in (("summary.json", json.dumps(summary, indent=2)), ("summary.md", _markdown(summary, footer)),
                       ("report.html", _html(summary, folder, footer))):
        with atomic_path(folder / name) as tmp:
            tmp.write_text(text, encoding="utf-8")
    return summary


def _verdict_text(row: dict[str, Any]) -> str:
    return "meets every target" if row["meets_targets"] else "misses: " + ", ".join(row["missed"])


def _cell(m: Metric, row: dict[str, Any]) -> str:
    v = row.get(m.key)
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    return m.show(v)


def _markdown(summary: dict[str, Any], footer: str) -> str:
    head = "| scene | " + " | ".join(m.name for m in METRICS) + " | full ms/step | reduced ms/step | verdict |\n"
    head += "|---" * (len(METRICS) + 4) + "|\n"
    for r in summary["cases"]:
        head += (f"| {r['scene']} | " + " | ".join(_cell(m, r) for m in METRICS)
                 + f" | {r['full_step_ms']:.2f} | {r['reduced_step_ms']:.3f} | {_verdict_text(r)} |\n")
    defs = "\n".join(f"- **{m.name}**: {m.definition}" + (f" Target: {m.target}." if m.target else "") for m in METRICS)
    text = f"# {summary['title']}\n\n{summary['description']}\n\n{head}\n{defs}\n"
    return text + (f"\n{footer}\n" if footer else "")


def _data_uri(path: Path) -> str:
    kind = {".png": "image/png", ".gif": "image/gif"}[path.suffix]
    return f"data:{kind};base64,{base64.b64encode(path.read_bytes()).decode('ascii')}"


_STYLE = ("body{font-family:system-ui,sans-serif;margin:2em;max-width:1400px}table{border-collapse:collapse;margin:1em 0}"
          "td,th{border:1px solid #ccc;padding:4px 8px;text-align:right}th{background:#f3f3f3}td:first-child{text-align:left}"
          ".meets{background:#e3f6e3}.misses{background:#fbe0e0}img{max-width:100%;display:block;margin:.5em 0}"
          "dt{font-weight:600;margin-top:.6em}")


def _html(summary: dict[str, Any], folder: Path, footer: str) -> str:
    e = html.escape
    head = "".join(f"<th>{e(m.name)}<br><small>{e(m.target) or 'no target'}</small></th>" for m in METRICS)
    body = []
    for r in summary["cases"]:
        cells = []
        for m in METRICS:
            judged = judge(m, r)
            cls = "" if judged is None else (' class="meets"' if judged else ' class="misses"')
            cells.append(f"<td{cls}>{e(_cell(m, r))}</td>")
        cls = "meets" if r["meets_targets"] else "misses"
        body.append(f"<tr><td>{e(r['scene'])}</td>{''.join(cells)}<td>{r['full_step_ms']:.2f}</td><td>{r['reduced_step_ms']:.3f}</td>"
                    f'<td class="{cls}">{e(_verdict_text(r))}</td></tr>')
    table = (f"<table><tr><th>scene</th>{head}<th>full ms/step</th><th>reduced ms/step</th><th>verdict</th></tr>"
             + "".join(body) + "</table>")
    defs = "<dl>" + "".join(f"<dt>{e(m.name)}</dt><dd>{e(m.definition)}" + (f" <b>Target: {e(m.target)}.</b>" if m.target else "")
                            + "</dd>" for m in METRICS) + "</dl>"
    pictures = []
    errors = folder / "errors.png"
    if errors.is_file():
        pictures.append(f'<h2>Error over time</h2><img alt="error curves" src="{_data_uri(errors)}">')
    for r in summary["cases"]:
        pictures.append(f"<h2>{e(r['scene'])}</h2>")
        for name, alt in ((f"animation_{r['tag']}.gif", "animation"), (f"filmstrip_{r['tag']}.png", "filmstrip")):
            if (folder / name).is_file():
                pictures.append(f'<img alt="{e(alt)}: {e(r["scene"])}" src="{_data_uri(folder / name)}">')
    return (f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8"><title>{e(summary["title"])}</title>'
            f"<style>{_STYLE}</style></head><body><h1>{e(summary['title'])}</h1><p>{e(summary['description'])}</p>{table}"
            f"<h2>What the numbers mean</h2>{defs}{''.join(pictures)}" + (f"<p>{e(footer)}</p>" if footer else "") + "</body></html>\n")
