"""The committed paper report (docs/paper/report.md) is produced by the current sources.

The report records the fingerprint of the figure code and the models it runs
(tools/experiments/paper/fingerprint.py). When any of them changes, the numbers in the report
may no longer be what the code gives: this test fails until the report is regenerated
(``capstan experiment paper --out docs/paper``, or ``--quick`` as the report header says).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from capstan.tools.experiments.paper.fingerprint import SOURCES, fingerprint_in_report, source_fingerprint

DOCS = Path(__file__).resolve().parent.parent / "docs" / "paper"


def test_committed_report_matches_the_current_sources() -> None:
    report = (DOCS / "report.md").read_text(encoding="utf-8")
    recorded = fingerprint_in_report(report)
    assert recorded is not None, "docs/paper/report.md records no source fingerprint: regenerate it"
    digest, n_files = source_fingerprint()
    assert recorded == digest, (
        f"docs/paper/report.md was produced by other sources than the current {n_files} files of {list(SOURCES)}: "
        "regenerate it with `capstan experiment paper --out docs/paper` (the report header says which settings)")
    results = json.loads((DOCS / "results.json").read_text(encoding="utf-8"))
    assert results["source_fingerprint"] == {"sha256": digest, "files": n_files}


def test_fingerprint_changes_with_a_model_edit_and_ignores_line_endings(tmp_path: Path) -> None:
    from capstan.tools.experiments.paper.fingerprint import source_files, source_root

    root = source_root()
    files = source_files(root)
    rel = [p.relative_to(root) for p in files]
    assert any(r.as_posix() == "models/transmission/pretension.py" for r in rel)
    assert any(r.as_posix() == "tools/experiments/paper/figs_models.py" for r in rel)
    for r in rel:                                               # a copy of exactly the fingerprinted files
        (tmp_path / r).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(root / r, tmp_path / r)
    base, n = source_fingerprint(tmp_path)
    assert (base, n) == source_fingerprint(root)
    target = tmp_path / "models" / "transmission" / "pretension.py"
    text = target.read_bytes()
    target.write_bytes(text.replace(b"\n", b"\r\n"))
    assert source_fingerprint(tmp_path)[0] == base               # CRLF checkout: same sources
    target.write_bytes(text + b"\n# edited\n")
    assert source_fingerprint(tmp_path)[0] != base               # an edit of a model: stale report
    target.write_bytes(text)
    (tmp_path / "tools" / "experiments" / "paper" / "new_figure.py").write_text("X = 1\n", encoding="utf-8")
    assert source_fingerprint(tmp_path) == (source_fingerprint(tmp_path)[0], n + 1)
    assert source_fingerprint(tmp_path)[0] != base               # a new figure module counts too


@pytest.mark.parametrize("text", ["no fingerprint here", "Source fingerprint: `sha256:abc`"])
def test_report_without_a_valid_fingerprint_reads_as_none(text: str) -> None:
    assert fingerprint_in_report(text) is None
