"""Shared fixtures: the real scans in ../shared/scans-real (never copied into the project).

Every test that reads them (through :func:`real_scan_path`, :data:`REAL_SCANS` or the
``real_scans_dir`` fixture, in its own body or in a fixture it uses) carries the ``realscan``
marker, applied here at collection (:func:`pytest_collection_modifyitems`), so ``-m 'not realscan'``
leaves out exactly those. The same hook moves the files holding a ``slow`` test to the front
(:func:`tests.support.scheduling.slow_files_first`: the order ``make test`` hands files to its workers),
and in a parallel run a test marked ``realtime`` runs alone (:func:`tests.support.scheduling.machine_share`).
"""
from __future__ import annotations

import functools
import inspect
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest

from tests.support.real_scans import REAL_SCANS
from tests.support.scheduling import machine_share, slow_files_first

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
    """The ``realscan`` marker on every test that reads the real scans (:func:`uses_real_scans`); the
    files holding a ``slow`` test first (:func:`slow_files_first`)."""
    for item in items:
        if item.get_closest_marker("realscan") is None and uses_real_scans(item):
            item.add_marker(pytest.mark.realscan)
    items[:] = slow_files_first(items)


@pytest.hookimpl(optionalhook=True)
def pytest_configure_node(node):
    """pytest-xdist's controller, for each worker it starts: the folder of the run's lock (made once,
    removed when the run ends)."""
    config = node.config
    if not hasattr(config, "arsurf_lock_folder"):
        config.arsurf_lock_folder = tempfile.mkdtemp(prefix="arsurf-test-lock-")
        config.add_cleanup(functools.partial(shutil.rmtree, config.arsurf_lock_folder, ignore_errors=True))
    node.workerinput["arsurf_lock_folder"] = config.arsurf_lock_folder


@pytest.hookimpl(wrapper=True)
def pytest_runtest_protocol(item, nextitem):
    """Setup, call and teardown of each test under the run's lock: a ``realtime`` test alone."""
    folder = getattr(item.config, "workerinput", {}).get("arsurf_lock_folder")
    with machine_share(folder, alone=item.get_closest_marker("realtime") is not None):
        return (yield)


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
