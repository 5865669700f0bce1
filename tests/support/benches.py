"""The scripts of ``bench/`` as modules, for the tests of their functions."""
from __future__ import annotations

import importlib.util
from pathlib import Path

BENCH = Path(__file__).resolve().parents[2] / "bench"


def load_bench(name: str):
    """``bench/<name>.py`` imported as a module (the scripts import their siblings by name)."""
    spec = importlib.util.spec_from_file_location(f"bench_{name}", BENCH / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


#: a 100 nm/s slide of the families plan ``plan_table(4, 5, runs 1 1)`` (a smooth 0.6 nm power-law
#: surface under a 2.26 nm tip): the one row the diagnostic benches are run on
SLIDE_KEY = "5:1:1:power-law#613753790 h=0.599nm l=7.15nm px=0.944nm R=2.26nm"
#: that plan, as the diagnostic benches take it
PLAN = ("--families", "4", "--runs", "1", "1", "--seed", "5")


def run_on_row(name: str, table: Path, row: dict, *args: str, timeout: float = 300):
    """``bench/<name>`` (a file name) on a table of the one ``row`` written to ``table``, planned as
    :data:`PLAN`, with ``args``: the finished process (stdout, stderr as text)."""
    import json
    import subprocess
    import sys

    table.write_text(json.dumps(row) + "\n")
    return subprocess.run([sys.executable, str(BENCH / name), str(table), *PLAN, *args], capture_output=True,
                          text=True, timeout=timeout)
