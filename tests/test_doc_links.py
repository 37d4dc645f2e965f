"""Every relative link in README.md and docs/ resolves to a file inside the repository (a link
to ../shared or to a page nobody wrote fails here, not in a reader's browser)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
PAGES = [REPO / "README.md", *sorted((REPO / "docs").rglob("*.md"))]
LINK = re.compile(r"\]\(([^)\s]+)\)")
FENCE = re.compile(r"```.*?```", re.S)


def relative_links(page: Path) -> list[str]:
    """Markdown link targets of ``page`` that are neither URLs nor in-page anchors (code blocks skipped)."""
    text = FENCE.sub("", page.read_text())
    return [t for t in LINK.findall(text) if not re.match(r"^[a-z]+:", t) and not t.startswith("#")]


@pytest.mark.parametrize("page", PAGES, ids=[str(p.relative_to(REPO)) for p in PAGES])
def test_relative_links_resolve_inside_the_repository(page: Path) -> None:
    bad = []
    for target in relative_links(page):
        path = (page.parent / target.split("#", 1)[0]).resolve()
        if not path.exists() or REPO not in path.parents:
            bad.append(target)
    assert not bad, f"{page.relative_to(REPO)}: links that do not resolve inside the repository: {bad}"


def test_the_link_finder_sees_links() -> None:
    links = relative_links(REPO / "README.md")
    assert "docs/configuration.md" in links and not any(t.startswith("http") for t in links)
