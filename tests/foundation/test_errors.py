"""One exception hierarchy in one module, one class per cause."""
from __future__ import annotations

import ast
import inspect
from pathlib import Path

import numpy as np
import pytest

import arsurf
from arsurf import errors
from arsurf.assembly import make_model
from arsurf.errors import ArsurfError, ContactError, PositionError, SurfaceError
from arsurf.spline.surface import BSplineSurface

ROOT = Path(__file__).resolve().parents[2]


def _exception_classes_defined_outside_errors() -> list[str]:
    found = []
    for folder in ("arsurf", "viewer"):
        for path in (ROOT / folder).rglob("*.py"):
            if path == ROOT / "arsurf" / "errors.py":
                continue
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.ClassDef):
                    bases = {ast.unparse(b) for b in node.bases}
                    if any(b.endswith(("Error", "Exception", "Warning", "NotFound", "Unavailable")) for b in bases):
                        found.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.name}")
    return found


def test_every_exception_lives_in_errors_py():
    assert _exception_classes_defined_outside_errors() == []


def test_every_error_is_an_arsurf_error():
    for name, obj in inspect.getmembers(errors, inspect.isclass):
        if issubclass(obj, Exception) and not issubclass(obj, Warning) and obj.__module__ == errors.__name__:
            assert issubclass(obj, ArsurfError), name


@pytest.fixture(scope="module")
def flat():
    return BSplineSurface.from_heights(np.zeros((8, 8)), (0.0, 50e-9), (0.0, 50e-9))


@pytest.mark.parametrize("call", ["collide", "project", "collide_many", "model"])
def test_a_nan_tip_centre_is_one_cause_whichever_stage_finds_it(flat, call):
    nan = (np.nan, 20e-9, 20e-9)
    with pytest.raises(PositionError, match="finite") as info:
        if call == "collide":
            arsurf.collide(flat, nan, 10e-9)
        elif call == "project":
            arsurf.project(flat, nan)
        elif call == "collide_many":
            arsurf.collide_many(flat, np.array([nan]), 10e-9)
        else:
            make_model(flat.copy(), tip_radius=10e-9, effective_modulus=10e9, work_of_adhesion=0.1).step(nan)
    assert isinstance(info.value, SurfaceError) and isinstance(info.value, ContactError)
