"""Fingerprint of the sources a paper-reproduction report was produced from.

``report.md`` and ``results.json`` record :func:`source_fingerprint` of the figure code and the
models it runs (:data:`SOURCES`, globs relative to the source root that holds ``models/``,
``tools/`` and ``controller/``). ``tests/test_paper_report_fresh.py`` recomputes it and fails
when the committed report is older than those sources: regenerate it with
``capstan experiment paper --out docs/paper`` (add ``--quick`` for the CI settings).
"""

from __future__ import annotations

import hashlib
import re
from pathlib import Path

#: source globs (relative to the source root) whose content determines the report's numbers
SOURCES: tuple[str, ...] = (
    "tools/experiments/paper/*.py",
    "tools/experiments/interaction.py",
    "models/transmission/*.py",
    "models/distributed/*.py",
    "models/plant/*.py",
    "controller/law/*.py",
)

#: how the fingerprint is written in report.md (one line)
LINE_RE = re.compile(r"Source fingerprint: `sha256:([0-9a-f]{64})`")


def source_root() -> Path:
    """The directory holding ``models/``, ``tools/`` and ``controller/`` (repository or installed package)."""
    import capstan.models

    return Path(capstan.models.__file__).resolve().parent.parent


def source_files(root: Path | None = None) -> list[Path]:
    """The files of :data:`SOURCES` under ``root`` (default :func:`source_root`), sorted by relative path."""
    base = source_root() if root is None else root
    files = {p for g in SOURCES for p in base.glob(g) if p.is_file()}
    return sorted(files, key=lambda p: p.relative_to(base).as_posix())


def source_fingerprint(root: Path | None = None) -> tuple[str, int]:
    """``(sha256 hex digest, number of files)`` over each source's relative path and content.

    Line endings are normalised, so a checkout with CRLF gives the same digest.
    """
    base = source_root() if root is None else root
    h = hashlib.sha256()
    files = source_files(base)
    for p in files:
        h.update(p.relative_to(base).as_posix().encode())
        h.update(b"\0")
        h.update(hashlib.sha256(p.read_bytes().replace(b"\r\n", b"\n")).digest())
    return h.hexdigest(), len(files)


def fingerprint_in_report(text: str) -> str | None:
    """The digest a report's text records (None if it records none)."""
    m = LINE_RE.search(text)
    return m.group(1) if m else None
