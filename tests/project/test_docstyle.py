"""Docstrings follow numpydoc: section headings spelled as numpydoc spells them."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
FILES = sorted([*(ROOT / "arsurf").rglob("*.py"), *(ROOT / "viewer").rglob("*.py")])
# numpydoc's section names; a heading is a line followed by a line of dashes of its length
SECTIONS = {"Parameters", "Returns", "Yields", "Receives", "Other Parameters", "Raises", "Warns", "Warnings",
            "See Also", "Notes", "References", "Examples", "Attributes", "Methods"}


@pytest.mark.parametrize("path", FILES, ids=lambda p: str(p.relative_to(ROOT)))
def test_section_headings_are_numpydoc(path):
    lines = path.read_text().splitlines()
    bad = []
    for k in range(len(lines) - 1):
        title, rule = lines[k].strip(), lines[k + 1].strip()
        if not (title and re.fullmatch(r"-{3,}", rule) and len(rule) == len(title)) or title in SECTIONS:
            continue
        # free-form headings are fine in module docstrings; a near-miss of a section name is not
        near = [s for s in SECTIONS if title.lower().rstrip("s:") == s.lower().rstrip("s")]
        if near:
            bad.append(f"line {k + 1}: {title!r} (numpydoc: {near[0]!r})")
    assert not bad, f"{path.name}: non-numpydoc section headings {bad}"
