"""Markdown rendering of a paper-reproduction run (:mod:`capstan.tools.experiments.paper.experiment`).

``render_report(doc)`` turns the results document (the content of ``results.json``) into
``report.md``: the source fingerprint, the settings, a summary with each figure's wall time, the
paper's statements checked against our rows (agrees / disagrees / mixed over the seeds, each
naming the rows it reads), the recommendation, and per figure the PNGs and a table
*id | quantity | paper | ours | spread | ours/paper | note*. A row whose paper number is not the
same quantity and case as ours shows "not like-for-like" instead of a ratio.
"""

from __future__ import annotations

import math
import re
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


def spread_text(spread: Any) -> str:
    """``min–max (n)`` of a row's spread; ``–`` when it has none."""
    if not spread or spread[2] in (0, None):
        return "–"
    return f"{fmt(spread[0])}–{fmt(spread[1])} ({int(spread[2])})"


def ratio_text(r: dict[str, Any]) -> str:
    """The ratio cell: the ratio, ``not like-for-like`` for a paper number of another quantity, ``–`` without one."""
    if r.get("paper") is not None and r.get("like_for_like") is False:
        return "not like-for-like"
    return fmt(r.get("ratio"))


def table(rows: list[dict[str, Any]]) -> list[str]:
    """Markdown table lines of report rows (``id``, ``quantity``, ``unit``, ``paper``, ``ours``, ``spread``,
    ``ratio``, ``note``)."""
    out = ["| id | quantity | paper | ours | spread min–max (n) | ours/paper | note |",
           "|---|---|---:|---:|---:|---:|---|"]
    for r in rows:
        q = f"{r['quantity']} [{r['unit']}]" if r.get("unit") and r["unit"] != "-" else r["quantity"]
        out.append(f"| {_cell(r.get('id') or '')} | {_cell(q)} | {fmt(r['paper'])} | {fmt(r['ours'])} | "
                   f"{spread_text(r.get('spread'))} | {ratio_text(r)} | {_cell(r['note'])} |")
    return out


#: (field-minimum, friction-preserving) fragments of the row ids and quantities of the two eq 25 readings
_EQ25_ID = (("-fiel", "-fric"), ("reduced_fi", "reduced_fr"))
_EQ25_TEXT = (", averaged, eq 25 friction-preserving", ", eq 25 friction-preserving", ", eq 25 friction preserving",
              " eq 25 friction preserving")


def _with_spread(r: dict[str, Any]) -> str:
    sp = spread_text(r.get("spread"))
    return fmt(r["ours"]) + (f" ({sp})" if sp != "–" else "")


def eq25_lines(figs: dict[str, Any]) -> list[str]:
    """Both readings of eq 25 side by side: every row pair that differs only in the reading."""
    rows = {r["id"]: r for key in ORDER if key in figs for r in figs[key]["rows"] if r.get("id")}
    out = []
    for rid, r in rows.items():
        for a, b in _EQ25_ID:
            if a in rid and rid.replace(a, b) in rows:
                f = rows[rid.replace(a, b)]
                label = re.sub(r" \(range [^)]*\)", "", f["quantity"])     # a range of one reading only
                for t in _EQ25_TEXT:
                    label = label.replace(t, "")
                unit = f" [{r['unit']}]" if r.get("unit") and r["unit"] != "-" else ""
                out.append(f"| {_cell(label)}{unit} | {fmt(r['paper'])} | {_with_spread(r)} | {_with_spread(f)} | "
                           f"{rid}, {f['id']} |")
    if not out:
        return []
    return ["## Eq 25: both readings side by side", "",
            "Eq 25 as printed (every spring at the field minimum, 2 T(s_min)) against the averaged pretension that "
            "preserves the field's total friction (twice its bending-weighted mean), from the rows below; ours = "
            "mean over the seeds (spread min–max (n)). Which one the data support, and the feedforward's default: "
            "see the recommendation.", "",
            "| quantity | paper | field minimum | friction-preserving | rows |", "|---|---:|---:|---:|---|"] + out + [""]


def claims_lines(figs: dict[str, Any]) -> list[str]:
    """The paper's statements checked on our rows, one table line each, grouped by verdict."""
    claims = [c for key in ORDER if key in figs for c in figs[key].get("claims", [])]
    if not claims:
        return []
    out = ["## What agrees with the paper and what does not", "",
           "Each line is one statement of the paper checked on our numbers for every noise seed; *agrees* = it "
           "holds on every seed, *disagrees* = on none, *mixed* = on some. The ids are the table rows it reads. "
           "A statement whose verdict differs between the two plants is marked **changes with the plant**.", "",
           "| verdict | plant | paper says | checked as | seeds held | rows |", "|---|---|---|---|---:|---|"]
    by_text: dict[str, set[str]] = {}
    for c in claims:
        by_text.setdefault(c["paper"], set()).add(c["verdict"])
    for c in claims:
        changes = len(by_text[c["paper"]]) > 1
        verdict = c["verdict"] + (" — **changes with the plant**" if changes else "")
        out.append(f"| {verdict} | {_cell(c['plant'])} | {_cell(c['paper'])} | {_cell(c['ours'])} | "
                   f"{c['held']}/{c['seeds']} | {', '.join(c['rows'])} |")
    return out + [""]


def _settings_text(s: dict[str, Any]) -> list[str]:
    mode = "quick (CI) settings" if s.get("quick") else "full settings"
    seeds = s.get("n_seeds", 1)
    head = []
    if s.get("quick"):
        head = ["**This is the quick run** (`capstan experiment paper --quick`): coarser grids and shorter runs than "
                "the full settings; every number below comes from it. The full run is `capstan experiment paper "
                "--out DIR`.", ""]
    return head + [
        f"Run with {mode}: ground-truth plant = the distributed model with {s['n_true']} nodes per cable on each "
        f"routing group's curvature profile and the eq 23 pretension field ({s['pretension_N']:g} N nominal), "
        f"sampled at {s['sample_rate_hz']:g} Hz, with sensor noise; prediction runs of {s['duration_s']:g} s; "
        f"routing groups θ{', θ'.join(str(j + 1) for j in s['groups'])}; N ∈ {{{', '.join(str(n) for n in s['n_list'])}}}; "
        f"interaction runs of {s['interaction_s']:g} s simulated at 1 kHz; noise / plant-effect seeds "
        f"{s['seed']}..{s['seed'] + seeds - 1} ({seeds} realisations: 'ours' is their mean, 'spread' their range); "
        f"{s.get('n_starts', 1)} starts per identification.",
        "",
        "The \"measured\" runs of Figs. 6, 9-11 also carry effects none of the predicting models contain: node "
        f"friction varying ±20 % along the sheath and a ±{100 * s['asym']:g} % pretension asymmetry between the "
        "cables (same mean, so the load-cell average the models use is unchanged). Every model is driven by the "
        "measured input torque. Ratios are ours / paper; the note says why they differ.",
        "",
        "Rows tagged **[imbalanced plant]** come from a plant of another structure: besides those effects each "
        "cable's pretension is skewed along the sheath, the upper cable tighter at its input fixture and the lower "
        f"at its output fixture (ends T(1 ± tanh({s.get('imbalance', 0):g} μθ/2)), a static capstan field), which "
        "no symmetric-pretension model can represent; the models still see only the load-cell mean.",
    ]


def render_report(doc: dict[str, Any]) -> str:
    """The Markdown report of a results document (see :func:`capstan.tools.experiments.paper.experiment.run_paper`)."""
    figs: dict[str, Any] = doc["figures"]
    lines = ["# The paper's results on the simulated rig", ""]
    fp = doc.get("source_fingerprint")
    if fp:
        lines += [f"Source fingerprint: `sha256:{fp['sha256']}` over {fp['files']} files (figure code and the models "
                  "it runs, `tools/experiments/paper/fingerprint.py`); `tests/test_paper_report_fresh.py` fails when "
                  "they change without this report being regenerated.", ""]
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
    lines += eq25_lines(figs)
    lines += claims_lines(figs)
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
