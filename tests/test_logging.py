"""Messages go through one logger tree (``arsurf``), bars through tqdm, ``print`` only in the CLI;
``-q``/``-v`` on the command line."""
from __future__ import annotations

import ast
import io
import logging
from pathlib import Path

import pytest

from arsurf._logging import LOGGER, configure_cli, progress

ROOT = Path(__file__).resolve().parents[1]
SOURCES = sorted((ROOT / "arsurf").rglob("*.py")) + sorted((ROOT / "viewer").rglob("*.py"))


def _is_main_guard(node) -> bool:
    return (isinstance(node, ast.If) and isinstance(node.test, ast.Compare)
            and isinstance(node.test.left, ast.Name) and node.test.left.id == "__name__")


def _prints_outside_the_cli(code: str) -> list[int]:
    """Lines of print() calls not in a command handler (cmd_*, _cmd, main) or a __main__ block."""
    found = []

    def visit(node, allowed: bool):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            allowed = allowed or node.name.startswith("cmd_") or node.name in ("_cmd", "main")
        if _is_main_guard(node):
            allowed = True
        if (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "print"
                and not allowed):
            found.append(node.lineno)
        for child in ast.iter_child_nodes(node):
            visit(child, allowed)

    visit(ast.parse(code), False)
    return found


def test_print_only_in_the_command_line():
    found = [f"{path.relative_to(ROOT)}:{line}" for path in SOURCES if ROOT / "arsurf" / "cli" not in path.parents
             for line in _prints_outside_the_cli(path.read_text())]
    assert found == [], f"use logging (logging.getLogger(__name__)) instead of print: {found}"


def test_the_print_check_sees_a_print_in_a_library_function():
    code = ("def f():\n    print('x')\n\ndef cmd_g():\n    print('y')\n\n"
            "class A:\n    def m(self):\n        print('w')\n\nif __name__ == '__main__':\n    print('z')\n")
    assert _prints_outside_the_cli(code) == [2, 9]


def test_every_logger_is_in_the_arsurf_tree():
    names = []
    for path in SOURCES:
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "getLogger"
                    and node.args):
                arg = node.args[0]
                if not (isinstance(arg, ast.Constant) or (isinstance(arg, ast.Name) and arg.id == "__name__")):
                    continue  # a variable: another library's logger (silenced by the readers)
                ok = (isinstance(arg, ast.Name) and arg.id == "__name__" and "arsurf" in path.relative_to(ROOT).parts[0]
                      ) or (isinstance(arg, ast.Constant) and str(arg.value).split(".")[0] == "arsurf")
                names.append((f"{path.relative_to(ROOT)}:{node.lineno}", ok))
    assert names and all(ok for _, ok in names), [n for n, ok in names if not ok]


def test_the_package_logger_prints_nothing_unless_configured(capsys):
    logging.getLogger("arsurf.demo").warning("quiet library")
    assert capsys.readouterr().err == ""  # NullHandler: no lastResort output


class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


@pytest.mark.parametrize("tty, level, enabled, shown", [
    (True, logging.INFO, True, True),
    (False, logging.INFO, True, False),      # not a terminal (CI logs, pipes)
    (True, logging.WARNING, True, False),    # -q
    (True, logging.INFO, False, False),      # the caller said no
])
def test_progress_bars_only_on_a_terminal_and_not_with_quiet(monkeypatch, request, tty, level, enabled, shown):
    stream = _Tty() if tty else io.StringIO()
    monkeypatch.setattr("sys.stderr", stream)
    old = LOGGER.level
    LOGGER.setLevel(level)  # (setLevel, not the attribute: the logger caches isEnabledFor)
    request.addfinalizer(lambda: LOGGER.setLevel(old))
    bar = progress(total=7, desc="work", unit="tick", enabled=enabled)
    for _ in range(7):
        bar.update(1)
    bar.close()
    assert ("work:" in stream.getvalue() and "/7" in stream.getvalue()) is shown, stream.getvalue()


def test_cli_verbosity_levels_and_format(monkeypatch):
    stream = io.StringIO()
    monkeypatch.setattr("sys.stderr", stream)
    level = LOGGER.level
    log = logging.getLogger("arsurf.demo")
    try:
        for verbosity in (-1, 0, 1):
            handler = configure_cli(verbosity)
            log.debug("d%d", verbosity)
            log.info("i%d", verbosity)
            log.warning("w%d", verbosity)
            LOGGER.removeHandler(handler)
    finally:
        LOGGER.setLevel(level)
    lines = stream.getvalue().splitlines()
    assert lines == ["arsurf: warning: w-1", "i0", "arsurf: warning: w0",
                     "[arsurf.demo] d1", "[arsurf.demo] i1", "arsurf: warning: w1"]


@pytest.mark.parametrize("argv, level", [
    (["info", "S"], logging.INFO), (["-q", "info", "S"], logging.WARNING), (["info", "S", "--quiet"], logging.WARNING),
    (["-v", "info", "S"], logging.DEBUG), (["info", "-v", "S"], logging.DEBUG),
])
def test_cli_flags_set_the_level_for_the_command_only(monkeypatch, argv, level):
    import arsurf.cli as cli

    seen = {}

    def fake(args):
        seen["level"] = LOGGER.getEffectiveLevel()
        seen["handlers"] = len(LOGGER.handlers)
        return 0

    before = (LOGGER.level, list(LOGGER.handlers))
    monkeypatch.setattr(cli, "cmd_info", fake)
    assert cli.main(argv) == 0
    assert seen["level"] == level and seen["handlers"] == len(before[1]) + 1
    assert (LOGGER.level, list(LOGGER.handlers)) == before  # restored after the command
