"""A session's metadata for the session tests (a scan that need not exist: its recorded hash
only; SI units)."""
from __future__ import annotations

from arsurf.assembly import session_metadata
from arsurf.contact.maugis_dugdale import MaugisDugdale
from arsurf.force.cantilever import Cantilever

R = 20e-9
SCAN = {"path": "scans/sinusoid.npz", "sha256": "ab" * 32, "channel": None,
        "processing": {"level": "plane", "sigma": 2e-9, "inpaint": True}}


def _meta():
    return session_metadata(scan=SCAN, tip_radius=R, contact=MaugisDugdale(R, 50e9, 0.1),
                            cantilever=Cantilever(450e-6, 50e-6, 2.5e-6, 15e-6, 169e9, 0.27), friction=0.25,
                            calibration={"gain": 1.5}, haptics={"device": "virtual"}, loop_rate=1000.0)


def _record(w, n, rng):
    for k in range(n):
        w.append(t=k * 1e-3, probe_position=rng.normal(size=3) * 1e-7, probe_velocity=rng.normal(size=3) * 1e-6,
                 force=rng.normal(size=3) * 1e-9, signals=rng.normal(size=2) * 1e-3, buttons=k % 3,
                 depth=float(rng.normal()) * 1e-9, md_status=k % 3 - 1, in_contact=k % 2)
