"""The README's quick start runs as printed (copy-paste on a fresh install must work)."""
from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _quick_start() -> str:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    section = text.split("## Quick start (Python)", 1)[1]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


def test_the_quick_start_runs_on_the_bundled_scan(capsys):
    code = _quick_start()
    assert "bundled_scan()" in code  # a file that ships with the package, not one the reader lacks
    namespace: dict = {}
    exec(compile(code, "README.md quick start", "exec"), namespace)
    contact, est = namespace["contact"], namespace["est"]
    assert contact.depth > 0 and abs(sum(n * n for n in contact.normal) - 1.0) < 1e-9
    assert len(est.force) == 3
    assert capsys.readouterr().out.count("\n") == 2  # the two print() lines
