"""Every code block of the README runs as printed (copy-paste on a fresh install must work).

A block that cannot run here says so right above its fence, in an HTML comment GitHub does not
render: ``<!-- not run by tests/project/test_readme.py: <why, and which test covers it> -->``
(``make demo`` builds a venv and installs every extra; the wheel block installs into the running
environment). Every other block runs: Python blocks in a fresh namespace, shell blocks line by line
in an empty folder that holds the source tree's ``scans/`` and ``arsurf/data/nanotubes.npz``, with
the demo shortened (``tests.support.code_blocks.FAST``) so that the test takes seconds, not minutes.
"""
from __future__ import annotations

import json
import re
import subprocess

import pytest

from tests.support.code_blocks import ROOT, arsurf_command, markdown_blocks, shell_workdir

README = ROOT / "README.md"


def test_the_readme_is_short_and_every_block_runs_or_says_why():
    assert len(README.read_text(encoding="utf-8").splitlines()) <= 250
    blocks = markdown_blocks(README)
    assert {b.lang for b in blocks} == {"sh", "python"}, "a block in a language this test cannot run"
    for b in blocks:
        if b.skip is not None:
            assert len(b.skip) > 40 and "test" in b.skip, f"a skipped block must say why and what covers it: {b.code!r}"
    assert sum(b.skip is None for b in blocks) >= 2


def test_every_docs_page_the_readme_names_exists():
    named = set(re.findall(r"`(docs/[\w./-]+)`", README.read_text(encoding="utf-8")))
    assert len(named) >= 10
    assert [p for p in sorted(named) if not p.startswith("docs/_build/") and not (ROOT / p).exists()] == []


def test_the_python_blocks_run(capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    blocks = [b for b in markdown_blocks(README) if b.lang == "python" and b.skip is None]
    assert blocks
    for k, b in enumerate(blocks):
        namespace: dict = {}
        exec(compile(b.code, f"README.md python block {k}", "exec"), namespace)
    contact = namespace["contact"]  # the quick start: a tip pressed ~2 nm into the bundled scan
    assert 0 < contact.depth < 20e-9 and abs(sum(n * n for n in contact.normal) - 1.0) < 1e-9
    printed = capsys.readouterr().out
    assert re.fullmatch(r"depth \d+\.\d\d nm, normal \[.*\]\n", printed, re.S), printed


@pytest.mark.slow
def test_the_shell_blocks_run(tmp_path):
    work = shell_workdir(tmp_path)
    lines = [ln for b in markdown_blocks(README) if b.lang == "sh" and b.skip is None
             for ln in b.code.splitlines() if ln.strip()]
    assert len(lines) >= 5
    for line in lines:
        proc = subprocess.run(arsurf_command(line), cwd=work, capture_output=True, text=True, timeout=900)
        assert proc.returncode == 0, f"{line}\n{proc.stdout[-2000:]}\n{proc.stderr[-3000:]}"
    out = work / "out"
    for name in ("sinusoid.surface.npz", "grating.gsf", "demo/session.h5", "replay/forces.csv", "sweep/results.csv"):
        assert (out / name).is_file(), name
    summary = json.loads((out / "demo" / "summary.json").read_text(encoding="utf-8"))
    assert summary["n_ticks"] > 0
    with open(out / "replay" / "forces.csv", encoding="utf-8") as fh:
        assert fh.readline().startswith("t_s,F_recorded_x_N,")


@pytest.mark.parametrize("line", ["make demo", "pip install arsurf"])
def test_a_line_the_test_cannot_run_is_refused_not_ignored(line):
    with pytest.raises(AssertionError, match="does not know how to run"):
        arsurf_command(line)
