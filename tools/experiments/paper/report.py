"""Markdown rendering of a paper-reproduction run (:mod:`capstan.tools.experiments.paper.experiment`).

``render_report(doc)`` turns the results document (the content of ``results.json``) into
``report.md``: the settings, a summary with each figure's wall time, the recommendation, and
per figure the PNGs and a table *quantity | paper | ours | ratio | note*.
"""

from __future__ import annotations

import math
import statistics
from typing import Any

#: figure key -> section heading prefix, in report order
ORDER = ("fig6", "fig7", "fig8", "fig9_10", "fig11", "fig13")


def fmt(x: Any) -> str:
    """A table number: 4 significant digits; ``–`` for a missing or non-finite value."""
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "–"
    if isinstance(x, (int, float)):
        return f"{x:.4g}"
    return str(x)


def _cell(text: Any) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def _ratios(rows: list[dict[str, Any]]) -> list[float]:
    return [r["ratio"] for r in rows if isinstance(r.get("ratio"), (int, float)) and math.isfinite(r["ratio"])]


def table(rows: list[dict[str, Any]]) -> list[str]:
    """Markdown table lines of report rows (``quantity``, ``unit``, ``paper``, ``ours``, ``ratio``, ``note``)."""
    out = ["| quantity | paper | ours | ratio | note |", "|---|---:|---:|---:|---|"]
    for r in rows:
        q = f"{r['quantity']} [{r['unit']}]" if r.get("unit") and r["unit"] != "-" else r["quantity"]
        out.append(f"| {_cell(q)} | {fmt(r['paper'])} | {fmt(r['ours'])} | {fmt(r['ratio'])} | {_cell(r['note'])} |")
    return out


def _settings_text(s: dict[str, Any]) -> list[str]:
    mode = "quick (CI) settings" if s.get("quick") else "full settings"
    return [
        f"Run with {mode}: ground-truth plant = the distributed model with {s['n_true']} nodes per cable on each "
        f"routing group's curvature profile and the eq 23 pretension field ({s['pretension_N']:g} N nominal), "
        f"sampled at {s['sample_rate_hz']:g} Hz, with sensor noise; prediction runs of {s['duration_s']:g} s; "
        f"routing groups θ{', θ'.join(str(j + 1) for j in s['groups'])}; N ∈ {{{', '.join(str(n) for n in s['n_list'])}}}; "
        f"interaction runs of {s['interaction_s']:g} s simulated at 1 kHz; seed {s['seed']}.",
        "",
        "The \"measured\" runs of Figs. 6, 9-11 also carry effects none of the predicting models contain: node "
        f"friction varying ±20 % along the sheath and a ±{100 * s['asym']:g} % pretension asymmetry between the "
        "cables (same mean, so the load-cell average the models use is unchanged). Every model is driven by the "
        "measured input torque. Ratios are ours / paper; the note says why they differ.",
    ]


def render_report(doc: dict[str, Any]) -> str:
    """The Markdown report of a results document (see :func:`capstan.tools.experiments.paper.experiment.run_paper`)."""
    figs: dict[str, Any] = doc["figures"]
    lines = ["# The paper's results on the simulated rig", ""]
    lines += _settings_text(doc["settings"]) + [""]
    lines += ["## Summary", "", "| figure | wall time [s] | rows | rows with a paper value | median ratio ours/paper |",
              "|---|---:|---:|---:|---:|"]
    for key in ORDER:
        if key in figs:
            f = figs[key]
            rs = _ratios(f["rows"])
            lines.append(f"| [{_cell(f['title'])}](#{key}) | {f['wall_s']:.1f} | {len(f['rows'])} | {len(rs)} | "
                         f"{fmt(statistics.median(rs)) if rs else '–'} |")
        elif key in doc.get("failed", {}):
            lines.append(f"| {key}: **failed**: {_cell(doc['failed'][key])} | – | – | – | – |")
    lines.append(f"| start-up (loading the compiled kernels) | {doc.get('startup_s', math.nan):.1f} | | | |")
    lines.append(f"| total | {doc['total_wall_s']:.1f} | | | |")
    lines += ["", "Figs. 9-10 and 11 share their measured runs; the first of the two to run carries their "
              "simulation time.", ""]
    lines += ["## Recommendation for a rig engineer", "",
              "Derived from this run's Figs. 9-10, 11 and 13 (rules in `tools/experiments/paper/recommend.py`).", ""]
    lines += [f"- {t}" for t in doc["recommendation"]["text"]] + [""]
    for key in ORDER:
        if key not in figs:
            continue
        f = figs[key]
        lines += [f'<a id="{key}"></a>', "", f"## {f['title']}", "", f"Wall time: {f['wall_s']:.1f} s.", ""]
        lines += [f"![{png}]({png})" for png in f["figures"]] + [""]
        lines += table(f["rows"]) + [""]
    return "\n".join(lines)
