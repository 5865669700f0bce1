"""The order the suite runs in, and which tests run alone.

``make test`` runs the suite on every core with pytest-xdist, one file per unit of work
(``--dist loadfile --no-loadscope-reorder``, pyproject.toml), handed out in collection order to
whichever worker is free. :func:`slow_files_first` puts the files holding a test marked ``slow``
at the front: long units first, short ones last (list scheduling's longest-first rule), so the
workers start on the files that take tens of seconds and end together on the short ones instead
of one worker finishing a two-minute file alone. A file stays on one worker: its module fixtures
are built once and its tests keep their order.

A test marked ``realtime`` asserts what a loop, a simulated device or a killed process does
within a wall-clock budget; beside another worker's numba compile it would see a machine more
loaded than the one it was written for. :func:`machine_share` runs it alone: every test of a
parallel run holds a shared lock on a file of the run for its setup, call and teardown, and a
``realtime`` test an exclusive one (docs/testing.rst).
"""
from __future__ import annotations

import contextlib
from pathlib import Path


def slow_files_first(items: list) -> list:
    """``items`` with the files that hold a ``slow`` test moved to the front; otherwise (files
    among themselves, tests within a file) the order is kept."""
    slow = {item.path for item in items if item.get_closest_marker("slow") is not None}
    return sorted(items, key=lambda item: item.path not in slow)  # a stable sort


@contextlib.contextmanager
def machine_share(folder: str | Path | None, alone: bool):
    """Hold the run's lock in ``folder`` while one test runs: shared, or exclusive when ``alone``.

    Fair to the exclusive side: it first takes the ``turnstile`` (which every test passes through),
    so no new shared holder starts while it waits for the running ones to end. ``folder`` None (a
    run in one process) holds nothing. POSIX ``flock``: released by the kernel if a worker dies.
    """
    if folder is None:
        yield
        return
    import fcntl

    folder = Path(folder)
    with open(folder / "turnstile", "a") as gate, open(folder / "running", "a") as running:
        fcntl.flock(gate, fcntl.LOCK_EX)
        if not alone:
            fcntl.flock(gate, fcntl.LOCK_UN)
        fcntl.flock(running, fcntl.LOCK_EX if alone else fcntl.LOCK_SH)
        try:
            yield
        finally:
            fcntl.flock(running, fcntl.LOCK_UN)
            fcntl.flock(gate, fcntl.LOCK_UN)
