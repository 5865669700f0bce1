"""Waiting on a device thread: poll a condition until it holds or a deadline passes (never a fixed
sleep that a loaded machine outruns)."""
from __future__ import annotations

import time
from typing import Callable


def wait_until(condition: Callable[[], bool], timeout: float = 10.0, *, what: str = "the condition",
               poll: float = 0.002) -> None:
    """Return as soon as ``condition()`` is true; AssertionError naming ``what`` after ``timeout`` s."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"{what} did not happen within {timeout:g} s")
        time.sleep(poll)
