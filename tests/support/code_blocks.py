"""The code blocks of the README and of the docs pages, for the tests that run them as printed.

A block that cannot run in the tests says so just above it, with the reason and the test that
covers it instead: in the README an HTML comment ``<!-- not run by tests/project/test_readme.py:
... -->``, in a docs page an RST comment ``.. not run by tests/project/test_doc_blocks.py: ...``.
"""
from __future__ import annotations

import re
import shlex
import textwrap
import sys
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
#: extra arguments that make a documented command quick without changing what it shows
FAST = {"demo": ["--seconds", "3", "--no-images"], "sweep": ["--steps", "8"]}


@dataclass(frozen=True)
class Block:
    source: str
    lang: str
    code: str
    skip: str | None  # why it does not run (None: it runs)


_MD = re.compile(r"(?:(<!--[^>]*?-->)\n)?```(\w*)\n(.*?)```", re.S)
_MD_SKIP = "<!-- not run by tests/project/test_readme.py:"
_RST = re.compile(r"(?:^(\.\. not run by tests/project/test_doc_blocks\.py:(?:.*\n)(?:   .*\n)*)\n)?"
                  r"^\.\. code-block:: (\w+)\n\n((?:(?:   .*)?\n)+)", re.M)


def markdown_blocks(path: Path) -> list[Block]:
    out = []
    for m in _MD.finditer(path.read_text(encoding="utf-8")):
        comment, lang, code = m.groups()
        skip = comment[len(_MD_SKIP):-3].strip() if comment and comment.startswith(_MD_SKIP) else None
        out.append(Block(path.name, lang, code, skip))
    return out


def rst_blocks(path: Path) -> list[Block]:
    out = []
    for m in _RST.finditer(path.read_text(encoding="utf-8")):
        comment, lang, body = m.groups()
        code = textwrap.dedent(body).strip("\n") + "\n"
        skip = " ".join(comment.split(":", 1)[1].split()) if comment else None
        out.append(Block(path.name, lang, code, skip))
    return out


def arsurf_command(line: str) -> list[str]:
    """The argv that runs one documented ``arsurf ...`` (or ``mkdir -p``) shell line here (with
    :data:`FAST`), through the console script beside this interpreter: ``python -m arsurf`` would put the working folder first on
    ``sys.path``, where :func:`shell_workdir` made an ``arsurf/`` folder."""
    words = shlex.split(line, comments=True)
    if words[:2] == ["mkdir", "-p"]:
        return words
    assert words and words[0] == "arsurf", f"a documented shell line this test does not know how to run: {line!r}"
    for name, extra in FAST.items():
        if name in words[1:3]:
            words += extra
    script = Path(sys.executable).parent / "arsurf"
    return [str(script), *words[1:]] if script.is_file() else [sys.executable, "-m", "arsurf", *words[1:]]


def shell_workdir(tmp_path: Path) -> Path:
    """An empty folder holding the source tree's ``scans/`` and the bundled scan at the paths the
    documents use (``scans/...``, ``arsurf/data/nanotubes.npz``)."""
    (tmp_path / "scans").symlink_to(ROOT / "scans")
    (tmp_path / "arsurf" / "data").mkdir(parents=True)
    (tmp_path / "arsurf" / "data" / "nanotubes.npz").symlink_to(ROOT / "arsurf" / "data" / "nanotubes.npz")
    return tmp_path
