"""Every notebook page made from a template (docs/notebook/*.md.in, filled by a benchmark)
says what its template says: prose added to the page alone would be lost the next time
the benchmark writes it, and prose added to the template alone would not be read."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from rigtest import ROOT

TEMPLATES = sorted((ROOT / "docs" / "notebook").glob("*.md.in"))
PLACEHOLDER = re.compile(r"\{\{[A-Z0-9_]+\}\}")


def is_filled_in(template: str, page: str) -> bool:
    """Whether the page is the template with something in place of each placeholder."""
    pieces = PLACEHOLDER.split(template)
    return re.fullmatch("(.*?)".join(map(re.escape, pieces)), page, flags=re.DOTALL) is not None


def test_a_page_is_its_template_filled_in() -> None:
    template = "# Title\n\n{{TABLE}}\n\nProse after.\n"
    assert is_filled_in(template, "# Title\n\n| a |\n|---|\n\nProse after.\n")
    assert not is_filled_in(template, "# Title\n\n| a |\n\nProse changed.\n")
    assert not is_filled_in(template, "# Title\n\n| a |\n\nProse after.\n\nA section of the page alone.\n")


@pytest.mark.parametrize("template", TEMPLATES, ids=lambda path: path.name)
def test_the_notebook_page_is_its_template_filled_in(template: Path) -> None:
    page = template.with_suffix("")
    assert is_filled_in(template.read_text(), page.read_text()), (
        f"{page.name} and {template.name} differ outside the template's placeholders: edit both, "
        f"or rewrite the page with its benchmark")


def test_there_are_templates() -> None:
    assert len(TEMPLATES) >= 3
