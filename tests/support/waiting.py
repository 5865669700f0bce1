"""Waiting on a device thread: poll a condition until it holds or a deadline passes (never a fixed
sleep that a loaded machine outruns)."""
from __future__ import annotations

import socket
import time
from pathlib import Path
from typing import Callable


def wait_until(condition: Callable[[], bool], timeout: float = 10.0, *, what: str = "the condition",
               poll: float = 0.002) -> None:
    """Return as soon as ``condition()`` is true; AssertionError naming ``what`` after ``timeout`` s."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"{what} did not happen within {timeout:g} s")
        time.sleep(poll)


def udp_port_bound(port: int) -> bool:
    """Whether a socket of any process is bound to UDP ``port``, read from the kernel's table
    (/proc/net/udp and udp6 on Linux: local address ``HEXIP:HEXPORT`` in the second column), so
    that asking never takes the port; elsewhere, a bind attempt (which holds it for an instant)."""
    tables = [Path("/proc/net/udp"), Path("/proc/net/udp6")]
    if not tables[0].exists():
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                return True
            return False
    for table in tables:
        try:
            rows = table.read_text().splitlines()[1:]
        except OSError:
            continue
        if any(int(row.split()[1].rsplit(":", 1)[1], 16) == port for row in rows if row.strip()):
            return True
    return False
