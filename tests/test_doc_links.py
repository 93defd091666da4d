"""Every relative link in the project's Markdown resolves: to a file that exists and, with
a #fragment into a Markdown page, to one of its headings (GitHub's anchors). The pages
link to each other's sections by their titles, and a section renamed (a notebook entry
that says "not kept" once its run is done) would otherwise leave a dead link behind."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from rigtest import ROOT

SKIPPED_DIRS = {".venv", "out", ".git", "node_modules"}
LINK = re.compile(r"\]\(([^)\s]+)\)")
HEADING = re.compile(r"^#{1,6}\s+(.*?)\s*#*\s*$")
FENCE = re.compile(r"```.*?```", flags=re.DOTALL)


def markdown_files(root: Path) -> list[Path]:
    return sorted(p for p in root.rglob("*.md") if not SKIPPED_DIRS & set(p.relative_to(root).parts))


def slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces as hyphens."""
    kept = "".join(c for c in heading.strip().lower() if c.isalnum() or c in "-_ ")
    return kept.replace(" ", "-")


def anchors(text: str) -> set[str]:
    """The anchors of a page's headings; a repeated one gets -1, -2, ... as on GitHub."""
    seen: dict[str, int] = {}
    out = set()
    for line in FENCE.sub("", text).splitlines():
        match = HEADING.match(line)
        if match:
            base = slug(match.group(1))
            count = seen.get(base, 0)
            seen[base] = count + 1
            out.add(base if count == 0 else f"{base}-{count}")
    return out


def dead_links(page: Path) -> list[str]:
    dead = []
    for target in LINK.findall(FENCE.sub("", page.read_text())):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target):          # http:, https:, mailto:
            continue
        path, _, fragment = target.partition("#")
        destination = (page.parent / path) if path else page
        if not destination.exists():
            dead.append(f"{target}: no such file")
        elif fragment and destination.suffix == ".md" and fragment not in anchors(destination.read_text()):
            dead.append(f"{target}: no such heading")
    return dead


def test_a_dead_link_and_a_dead_heading_are_found(tmp_path: Path) -> None:
    (tmp_path / "other.md").write_text("# Other\n\n## A section (session 1: not kept)\n\n## Twice\n\n## Twice\n")
    page = tmp_path / "page.md"
    page.write_text("[ok](other.md#a-section-session-1-not-kept) [ok](other.md#twice-1) [ok](#here)\n"
                    "[gone](missing.md) [renamed](other.md#a-section-session-1-registered) "
                    "[web](https://example.com/x#y)\n\n# Here\n\n```\n[in code](nowhere.md)\n```\n")
    assert dead_links(page) == ["missing.md: no such file",
                                "other.md#a-section-session-1-registered: no such heading"]


@pytest.mark.parametrize("page", markdown_files(ROOT), ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_resolves(page: Path) -> None:
    assert dead_links(page) == []
