"""Shared fixtures: the real scans in ../shared/scans-real (never copied into the project).

Every test that reads them (through :func:`real_scan_path`, :data:`REAL_SCANS` or the
``real_scans_dir`` fixture, in its own body or in a fixture it uses) carries the ``realscan``
marker, applied here at collection (:func:`pytest_collection_modifyitems`), so ``-m 'not realscan'``
leaves out exactly those.
"""
from __future__ import annotations

import functools
import inspect
from pathlib import Path

import numpy as np
import pytest

from tests.support.real_scans import REAL_SCANS

#: what a test's (or its fixtures') source names when it reads the real scans
REAL_SCAN_USES = ("real_scan_path(", "REAL_SCANS", "real_scans_dir")


@functools.lru_cache(maxsize=None)
def _reads_real_scans(func) -> bool:
    try:
        source = inspect.getsource(func)
    except (OSError, TypeError):
        return False
    return any(use in source for use in REAL_SCAN_USES)


def uses_real_scans(item) -> bool:
    """Whether a collected test reads the real scans: its function or a fixture it uses names them."""
    if "real_scans_dir" in getattr(item, "fixturenames", ()):
        return True
    funcs = [getattr(item, "function", None)]
    info = getattr(item, "_fixtureinfo", None)
    for defs in (info.name2fixturedefs.values() if info is not None else ()):
        funcs += [d.func for d in defs]
    return any(f is not None and _reads_real_scans(f) for f in funcs)


def pytest_collection_modifyitems(config, items):
    """The ``realscan`` marker on every test that reads the real scans (:func:`uses_real_scans`)."""
    for item in items:
        if item.get_closest_marker("realscan") is None and uses_real_scans(item):
            item.add_marker(pytest.mark.realscan)


@pytest.fixture
def real_scans_dir() -> Path:
    if not REAL_SCANS.is_dir():
        pytest.skip(f"{REAL_SCANS} is absent (../shared is not beside the project; CI always has it)")
    return REAL_SCANS


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20261121)


@pytest.fixture(scope="module")
def gl():
    """An OpenGL context for the viewer's rendering tests (skipped, saying why, without one)."""
    from arsurf_viewer.backend import probe

    result = probe()
    if not result.ok:
        pytest.skip(f"no OpenGL context can be made here: {result.detail}")
    return result
