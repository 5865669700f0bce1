"""``arsurf devices``: which haptic device backends are installed, and which devices answer.

One line per backend, the built-in ``virtual`` one first (:data:`VIRTUAL`), then the hardware ones
(:data:`~arsurf.haptics.backends.BACKENDS`: name -> adapter module, each with
``probe() -> BackendReport``), whatever is missing: a backend that is not installed
says what to install, one that is installed lists the devices it finds (``none connected`` is not
an error). Exit status 0 in every case; ``--json`` prints the same as a JSON list.

Examples
--------
>>> sorted(BACKENDS)
['forcedimension', 'haply', 'openhaptics']
"""
from __future__ import annotations

import importlib
import json

from arsurf.haptics.backends import BACKENDS
from arsurf.haptics.hardware import BackendReport

__all__ = ["BACKENDS", "VIRTUAL", "list_backends", "register"]

#: the built-in simulated device (``arsurf live --device virtual``), always there
VIRTUAL = BackendReport("virtual", True, "built in: arsurf.haptics.virtual_device; the UDP bridge takes any other "
                        "device", ["virtual (a simulated stylus and hand)"])


def list_backends() -> list[BackendReport]:
    """The built-in backend, then every hardware backend probed; a probe that fails is reported on its
    line, never raised."""
    reports = [VIRTUAL]
    for name, (module, _) in BACKENDS.items():
        try:
            reports.append(importlib.import_module(module).probe())
        except Exception as exc:  # noqa: BLE001 - one backend's failure must not hide the others
            first = (str(exc).strip().splitlines() or [""])[0]
            reports.append(BackendReport(name, True, f"probe failed: {type(exc).__name__}: {first}"))
    return reports


def register(sub) -> None:
    """Add ``arsurf devices`` to the CLI."""
    p = sub.add_parser("devices", help="list the haptic device backends installed and the devices connected")
    p.add_argument("--json", action="store_true", help="print a JSON list instead of one line per backend")
    p.set_defaults(func=_cmd)


def _cmd(args) -> int:
    reports = list_backends()
    if args.json:
        print(json.dumps([r.__dict__ for r in reports], indent=2))
    else:
        for r in reports:
            print(r.line())
    return 0
