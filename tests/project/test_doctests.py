"""Every docstring example of the engine and the viewer runs and prints what it says."""
from __future__ import annotations

import doctest
import importlib
from pathlib import Path

import pytest

from arsurf.errors import MissingDependency

ROOT = Path(__file__).resolve().parents[2]


def _module_names() -> list[str]:
    names = []
    for folder, package in (("arsurf", "arsurf"), ("viewer", "arsurf_viewer")):
        for path in sorted((ROOT / folder).rglob("*.py")):
            parts = [package, *path.relative_to(ROOT / folder).with_suffix("").parts]
            if parts[-1] == "__init__":
                parts = parts[:-1]
            if parts[-1] != "__main__":
                names.append(".".join(parts))
    return names


@pytest.mark.parametrize("name", _module_names())
def test_docstring_examples(name):
    try:
        module = importlib.import_module(name)
    except (ImportError, MissingDependency) as exc:  # an optional extra that is not installed
        pytest.skip(f"{name} needs an optional dependency: {exc}")
    failed, attempted = doctest.testmod(module, optionflags=doctest.NORMALIZE_WHITESPACE | doctest.ELLIPSIS,
                                        report=True)
    assert failed == 0, f"{failed} of {attempted} docstring examples of {name} failed (see the output above)"
