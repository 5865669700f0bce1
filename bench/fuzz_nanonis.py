"""Fuzz the Nanonis protocol parsers (prints JSON): the big run of tests/instrument/test_nanonis.py's sample.

Random bodies, and valid replies/requests of every command with bytes flipped, cut or appended,
go through :func:`~arsurf.instrument.nanonis_protocol.decode_reply`,
:func:`~arsurf.instrument.nanonis_protocol.decode_request` and
:func:`~arsurf.instrument.nanonis_protocol.parse_header`; anything but
:class:`~arsurf.errors.InstrumentLinkLost` / :class:`~arsurf.errors.ControllerError` is a finding.
Reports the cases tried, how each was refused, the findings (should be 0), and the decode rate
against a peer timed in the same run (``struct.unpack`` of the valid reply's fixed layout).

Run: ``python bench/fuzz_nanonis.py [--n 200000] [--seed 0]``
"""
from __future__ import annotations

import argparse
import os
import struct
import sys
import time

import numpy as np

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from _timing import emit, stats, time_calls  # noqa: E402

from arsurf.errors import ControllerError, InstrumentLinkLost  # noqa: E402
from arsurf.instrument import nanonis_protocol as proto  # noqa: E402


def _values(command: str) -> tuple:
    types = proto.COMMANDS[command][1]
    if "*+c" in types:
        return (["X (m)", "Y (m)", "Input 1 (V)"],)
    if "*f" in types:
        return ([1.0, 2.0, 3.0, 4.0, 5.0],)
    return tuple(1 if c in "HIi" else 1.5e-9 for c in types)


def fuzz(n: int, seed: int) -> dict:
    rng = np.random.default_rng(seed)
    commands = list(proto.COMMANDS)
    replies = {c: proto.encode_reply_body(c, _values(c)) for c in commands}
    counts = {"accepted": 0, "InstrumentLinkLost": 0, "ControllerError": 0}
    findings = []
    for i in range(n):
        c = commands[i % len(commands)]
        base = bytearray(replies[c])
        kind = i % 4
        if kind == 0:
            data = rng.integers(0, 256, rng.integers(0, 96), dtype=np.uint8).tobytes()
        elif kind == 1:
            for _ in range(rng.integers(1, 6)):
                base[rng.integers(0, len(base))] = rng.integers(0, 256)
            data = bytes(base)
        elif kind == 2:
            data = bytes(base[:rng.integers(0, len(base))])
        else:
            data = bytes(base) + rng.integers(0, 256, rng.integers(1, 16), dtype=np.uint8).tobytes()
        for fn in (lambda: proto.decode_reply(c, data), lambda: proto.decode_request(c, data),
                   lambda: proto.parse_header(data[:40].ljust(40, b"\0"), request=bool(i % 2))):
            try:
                fn()
                counts["accepted"] += 1
            except (InstrumentLinkLost, ControllerError) as exc:
                counts[type(exc).__name__] += 1
            except Exception as exc:  # a finding
                findings.append(f"{c} {kind}: {type(exc).__name__}: {exc}"[:200])
    body = replies["Signals.ValsGet"]
    fixed = struct.Struct(">i5fIi")
    ours = time_calls(lambda: proto.decode_reply("Signals.ValsGet", body), 20000)
    peer = time_calls(lambda: fixed.unpack(body), 20000)
    return {"cases": n, "parser_calls": 3 * n, "outcomes": counts, "findings": len(findings),
            "first_findings": findings[:5], "decode_valsget": stats(ours), "peer_struct_unpack": stats(peer),
            "decode_over_struct": round(float(np.median(ours) / np.median(peer)), 2)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=200_000)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    t = time.perf_counter()
    out = fuzz(a.n, a.seed)
    out["wall_s"] = round(time.perf_counter() - t, 1)
    emit("fuzz_nanonis", out)


if __name__ == "__main__":
    main()
