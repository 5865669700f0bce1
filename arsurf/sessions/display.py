"""Notebook display of sessions and replays (IPython's ``_repr_html_`` / ``_repr_png_``).

A :class:`~arsurf.sessions.reader.Session` shows what was recorded (ticks, duration, rate, scan,
tip and contact law, whether it is complete and verified) and a thumbnail of the force on the tip
against time with the contact shaded; a :class:`~arsurf.replay.replay.ReplayResult` shows what the
replay found (peaks, agreement with the recording, the files written) and the replayed force
read back from its ``replay.h5`` (by :class:`~arsurf.replay.replay.ReplayResult`: this module imports
nothing of the replay package, which imports it lazily). Everything in SI with a prefix (:mod:`arsurf._display`).
"""
from __future__ import annotations

import math

import numpy as np

from arsurf._display import card, quantity, series_png

__all__ = ["session_rows", "session_png", "session_html", "replay_rows", "replay_png", "replay_html"]


def _peak_norm(a) -> float:
    if a is None or a.size == 0:
        return math.nan
    n = np.linalg.norm(a.reshape(a.shape[0], -1), axis=1)
    n = n[np.isfinite(n)]
    return float(n.max()) if n.size else math.nan


def _max(a) -> float:
    if a is None:
        return math.nan
    a = a[np.isfinite(a)]
    return float(a.max()) if a.size else math.nan


def session_rows(s) -> list[tuple[str, str]]:
    """The table of a session: file, status, ticks and time, scan, tip and contact law, peaks."""
    t = s.ticks.get("t")
    duration = float(t[-1] - t[0]) if t is not None and t.size > 1 else 0.0
    meta = s.metadata
    contact = meta.get("contact") or {}
    scan = meta.get("scan") or {}
    rate = meta.get("loop_rate")
    status = ("complete" if s.complete else f"incomplete ({s.attrs.get('aborted', 'not closed')})") + \
        (", checksums verified" if s.verified else ", not verified") + (", recovered from its journal" if s.recovered
                                                                        else "")
    rows = [("file", str(s.path) if s.path is not None else "(in memory)"),
            ("format", f"{s.attrs.get('format', '?')} version {s.attrs.get('format_version', '?')}"),
            ("status", status),
            ("ticks", f"{s.n_ticks} over {quantity(duration, 's')}"
                      + (f" at {quantity(rate, 'Hz')}" if isinstance(rate, (int, float)) else "")),
            ("scan", f"{scan.get('path', '?')} (sha256 {str(scan.get('sha256', ''))[:12]}...)"),
            ("tip radius", quantity(meta.get("tip_radius"), "m")),
            ("contact", f"E* {quantity(contact.get('effective_modulus'), 'Pa')}, "
                        f"w {quantity(contact.get('work_of_adhesion'), 'J/m^2')}"),
            ("ticks in contact", str(int(np.count_nonzero(s.ticks["in_contact"]))) if "in_contact" in s.ticks else "?"),
            ("peak force on the tip", quantity(_peak_norm(s.ticks.get("force")), "N")),
            ("max depth", quantity(_max(s.ticks.get("depth")), "m"))]
    tubes = (meta.get("tubes") or {}).get("tubes") if isinstance(meta.get("tubes"), dict) else None
    if tubes:
        rows.append(("nano-objects", f"{len(tubes)} tubes (poses recorded per tick)"))
    rows.extend(("note", n) for n in s.notes)
    return rows


def session_png(s) -> bytes | None:
    """|force on the tip| against time, contact shaded (None: nothing recorded to draw)."""
    t = s.ticks.get("t")
    f = s.ticks.get("force")
    if t is None or f is None or t.size < 2 or not np.isfinite(f).any():
        return None
    contact = s.ticks["in_contact"] == 1 if "in_contact" in s.ticks else None
    return series_png(t, {"|F| on the tip": np.linalg.norm(f, axis=1)}, "N", "force", shade=contact)


def session_html(s) -> str:
    """The HTML card of a session (IPython's ``_repr_html_``)."""
    return card("Session", session_rows(s), session_png(s))


def replay_rows(r) -> list[tuple[str, str]]:
    """The table of a replay result: peaks, agreement with the recording, files."""
    rows = [("output", str(r.out_dir)), ("ticks", str(r.n_ticks)),
            ("peak force (model)", quantity(r.peak_force, "N")),
            ("peak force (decoupled signals)", quantity(r.peak_measured_force, "N")),
            ("max depth", quantity(r.max_depth, "m")), ("max contact radius", quantity(r.max_contact_radius, "m")),
            ("vs recording: depth", quantity(r.depth_difference, "m")),
            ("vs recording: load", quantity(r.load_difference, "N")),
            ("contact-state mismatches", str(r.contact_mismatches)), ("collision failures", str(r.collision_failures))]
    if r.tube_poses is not None:
        rows.append(("tube poses vs recording", f"{r.tube_pose_difference:.3g} (largest |x, y (m), angle (rad)|)"))
    rows.append(("files", f"{len(r.files)}: " + ", ".join(f for f in r.files if not f.startswith("frames/"))
                 + (f" and {r.frames} frames" if r.frames else "")))
    rows.extend(("note", n) for n in r.notes)
    return rows


def replay_png(r, ticks) -> bytes | None:
    """The replayed and the recorded |force| against time, from the per-tick arrays of the result's
    ``replay.h5`` (``ticks``; None when the folder is gone or damaged: no picture, no exception)."""
    if ticks is None:
        return None
    curves = {"model": np.linalg.norm(ticks["simulated_force"], axis=1),
              "recorded": np.linalg.norm(ticks["recorded_force"], axis=1)}
    if np.isfinite(ticks["measured_force"]).any():
        curves["decoupled"] = np.linalg.norm(ticks["measured_force"], axis=1)
    return series_png(ticks["t"], curves, "N", "|F| on the tip", shade=ticks["in_contact"] == 1)


def replay_html(r, ticks) -> str:
    """The HTML card of a replay result (IPython's ``_repr_html_``); ``ticks`` as :func:`replay_png`."""
    return card("Replay", replay_rows(r), replay_png(r, ticks))
