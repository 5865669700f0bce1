"""Every code block of the docs pages runs as printed, or says above it why not and what test covers
it instead (``.. not run by tests/project/test_doc_blocks.py: ...``). Python blocks run in a fresh
namespace from the source tree (the pages name the real scans as ``../shared/scans-real/...``:
skipped, saying so, where that folder is absent); shell blocks run their ``arsurf`` lines in an empty
folder holding ``scans/`` and the bundled scan (tests.support.code_blocks)."""
from __future__ import annotations

import subprocess

import pytest

from tests.support.code_blocks import ROOT, arsurf_command, rst_blocks, shell_workdir

PAGES = sorted((ROOT / "docs").glob("*.rst"))
BLOCKS = [b for page in PAGES for b in rst_blocks(page) if b.lang in ("python", "sh")]
REAL = ROOT.parent / "shared" / "scans-real"


def test_every_runnable_language_is_run_or_says_why():
    assert len(BLOCKS) >= 8
    for b in BLOCKS:
        if b.skip is not None:
            assert len(b.skip) > 40 and "test" in b.skip, f"{b.source}: a skipped block must say why: {b.code!r}"
    assert sum(b.skip is None for b in BLOCKS) >= 5


@pytest.mark.parametrize("block", [b for b in BLOCKS if b.lang == "python" and b.skip is None],
                         ids=lambda b: f"{b.source}:{b.code.splitlines()[0][:40]}")
def test_the_python_blocks_run(block, monkeypatch):
    if "../shared/scans-real" in block.code and not REAL.is_dir():
        pytest.skip(f"{block.source} reads the real scans in {REAL}, absent here")
    monkeypatch.chdir(ROOT)
    exec(compile(block.code, f"docs/{block.source}", "exec"), {})


@pytest.mark.slow
@pytest.mark.parametrize("block", [b for b in BLOCKS if b.lang == "sh" and b.skip is None],
                         ids=lambda b: f"{b.source}:{b.code.splitlines()[0][:40]}")
def test_the_shell_blocks_run(block, tmp_path):
    work = shell_workdir(tmp_path)
    for line in (ln for ln in block.code.splitlines() if ln.strip()):
        proc = subprocess.run(arsurf_command(line), cwd=work, capture_output=True, text=True, timeout=900)
        assert proc.returncode == 0, f"{line}\n{proc.stdout[-2000:]}\n{proc.stderr[-3000:]}"
