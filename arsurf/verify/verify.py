r"""``arsurf verify``: a session's model against the scan after it, and the next session's start.

:func:`verify_scans` registers the scan after to the scan before (:mod:`arsurf.verify.register`:
the drift), finds the tubes in the scan after (:mod:`arsurf.verify.tubes`: segments, tip
broadening removed), pairs them with the model's poses at the session's end and flags a wrong
model (:mod:`arsurf.verify.compare`). :func:`verify_session` does it for a recorded session
(its scan is the scan before unless another is given; its last ``tube_poses`` row the
prediction; its tip radius the imaging tip's unless one is given or estimated) and writes into
``DIR``:

==================  =====================================================================
file                content
==================  =====================================================================
``verify.json``     the drift (nm and px, the affine map), every tube's predicted and
                    measured pose with its position (nm, px) and angle (deg) errors, the
                    flag with its reasons and thresholds, the found tubes (length, diameter,
                    height, nm); units in every key
``verify.png``      prediction, scan after and overlay (:mod:`arsurf.verify.figure`)
==================  =====================================================================

``reseed``: the next session's starting scene - the scan after (its own frame: where the
instrument is now) with the tubes at their measured poses in ``metadata["measured_tubes"]``
(end points and diameter, metres), an ``.npz`` that :func:`arsurf.scan.io.load_scan` reads and
:meth:`arsurf.manipulation.scene.TubeScene.from_scan` turns into the scene (``arsurf live
--tubes``, the demo).
"""
from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from arsurf._files import write_text
from arsurf.errors import ArsurfError, ChannelNotFound, VerifyError
from arsurf.scan.scan import Scan
from arsurf.verify.compare import (ANGLE_THRESHOLD_DEG, POSITION_THRESHOLD_PX, ObjectCheck, compare,
                                   model_wrong)
from arsurf.verify.register import Registration, level_substrate, register
from arsurf.verify.tubes import FoundTube, find_tubes

__all__ = ["VerifyResult", "verify_scans", "verify_session", "write_reseed"]


@dataclass
class VerifyResult:
    """What :func:`verify_scans` found (see the module docstring for the JSON it becomes)."""

    registration: Registration
    found: list
    checks: list
    wrong: bool
    reasons: list
    tip_radius: float
    tip_radius_source: str
    position_threshold: float
    angle_threshold: float
    dx: float
    dy: float
    files: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        return {"format": "arsurf-verify", "format_version": 1,
                "registration": self.registration.to_json(self.dx, self.dy),
                "tip_radius_nm": self.tip_radius * 1e9, "tip_radius_source": self.tip_radius_source,
                "objects": [c.to_json(self.dx) for c in self.checks],
                "found_tubes": [t.to_json() for t in self.found],
                "model_wrong": self.wrong, "reasons": list(self.reasons),
                "thresholds": {"position_nm": self.position_threshold * 1e9,
                               "angle_deg": math.degrees(self.angle_threshold)},
                "files": {k: str(v) for k, v in self.files.items()}}


def verify_scans(before: Scan, after: Scan, predicted: np.ndarray, tubes, *, tip_radius: float | None,
                 moved=None, position_threshold: float | None = None, angle_threshold: float | None = None,
                 min_height: float = 2e-9) -> VerifyResult:
    """Register, find, compare (module docstring).

    Parameters
    ----------
    before, after : Scan
        The same frame scanned before and after the manipulation.
    predicted : (k, 3) float
        The model's poses at the end (x, y m, angle rad), the scan before's frame.
    tubes : sequence of Nanotube
        The model's tubes (their lengths and diameters).
    tip_radius : float or None, metres
        The imaging tip; None: estimated from the tubes.
    moved : (k,) bool, optional
        Which tubes the model moved (default: all).
    position_threshold : float, metres, optional
        Default :data:`~arsurf.verify.compare.POSITION_THRESHOLD_PX` pixels.
    angle_threshold : float, radians, optional
        Default :data:`~arsurf.verify.compare.ANGLE_THRESHOLD_DEG`.
    """
    reg = register(before, after, min_height=min_height)
    found = find_tubes(after, tip_radius, min_height=min_height)
    k = len(tubes)
    p = np.asarray(predicted, dtype=np.float64).reshape(k, 3)
    moved = np.ones(k, bool) if moved is None else np.asarray(moved, bool)
    checks = compare(p, [t.length for t in tubes], [t.diameter for t in tubes], moved, found, reg, after.dx, after.dy)
    pos = POSITION_THRESHOLD_PX * after.dx if position_threshold is None else float(position_threshold)
    ang = math.radians(ANGLE_THRESHOLD_DEG) if angle_threshold is None else float(angle_threshold)
    wrong, reasons = model_wrong(checks, after.dx, pos, ang)
    R = found[0].tip_radius
    return VerifyResult(reg, found, checks, wrong, reasons, R, "given" if tip_radius is not None else "estimated",
                        pos, ang, after.dx, after.dy)


def write_reseed(after: Scan, found, path: str | os.PathLike) -> Path:
    """The next session's start: ``after`` with ``metadata["measured_tubes"]`` (the found tubes'
    end points and diameters in its own frame, metres), saved as ``.npz``."""
    from arsurf.scan.io import save_scan

    path = Path(path)
    if path.suffix.lower() != ".npz":
        raise VerifyError(f"--reseed writes an .npz scan (got {path.name!r}); name it e.g. next.npz")
    tubes = []
    for t in found:
        u = np.array([math.cos(t.angle), math.sin(t.angle)]) * 0.5 * t.length
        tubes.append({"start": [t.x - u[0], t.y - u[1]], "end": [t.x + u[0], t.y + u[1]], "diameter": t.diameter})
    meta = {**after.metadata, "measured_tubes": {"method": "arsurf verify", "units": "m", "tubes": tubes}}
    return save_scan(replace(after, metadata=meta), path)


def _load(path, channel, what: str) -> Scan:
    from arsurf.scan.io import load_scan

    try:
        return load_scan(path, channel)
    except ChannelNotFound:
        return load_scan(path)  # the pair check names both channels
    except ArsurfError as exc:
        raise VerifyError(f"the scan {what} ({path}) cannot be read: {exc}") from None


def verify_session(session_path, after_path, *, before_path=None, out_dir=None, reseed=None,
                   tip_radius: float | None = math.nan, position_threshold: float | None = None,
                   angle_threshold: float | None = None, figure_format: str = "png", dpi=None) -> VerifyResult:
    """:func:`verify_scans` on a recorded session (module docstring).

    Parameters
    ----------
    session_path : path-like
        The session (with a tube scene: ``tubes`` metadata and ``tube_poses`` ticks).
    after_path : path-like
        The scan after.
    before_path : path-like, optional
        The scan before (default: the session's scan file).
    out_dir : path-like, optional
        Where ``verify.json`` and the figure go (nothing written without it).
    reseed : path-like, optional
        The next session's starting scene (``.npz``).
    tip_radius : float, metres; NaN (default) the session's; None estimated from the scan
    position_threshold, angle_threshold : float, metres and radians, optional
    figure_format, dpi
        Of the figure (:func:`arsurf.replay.plots.save_figure`).
    """
    from arsurf.manipulation.scene import TubeScene
    from arsurf.sessions.reader import load_session

    session = load_session(session_path)
    meta = session.metadata
    if not meta.get("tubes"):
        raise VerifyError(f"the session {session_path} has no nano-objects (no 'tubes' in its metadata): there is no "
                          "prediction to verify")
    poses = session.ticks.get("tube_poses")
    if poses is None or not len(poses):
        raise VerifyError(f"the session {session_path} recorded no tube poses (ticks/tube_poses)")
    finite = np.isfinite(poses).all(axis=(1, 2))
    if not finite.any():
        raise VerifyError(f"the session {session_path} has no tick with every tube pose recorded")
    last = poses[np.flatnonzero(finite)[-1]]
    scene = TubeScene.from_metadata(meta["tubes"])
    initial = np.array([t.pose for t in scene.initial])
    moved = np.any(np.abs(last - initial) > 1e-12, axis=1)
    scan_meta = meta.get("scan") or {}
    before_path = before_path if before_path is not None else scan_meta.get("path")
    if before_path is None or not Path(before_path).exists():
        raise VerifyError(f"the session's scan {before_path!r} is not there; pass the scan before with --before SCAN")
    before = _load(before_path, scan_meta.get("channel"), "before")
    after = _load(after_path, before.channel, "after")
    R = float(meta["tip_radius"]) if tip_radius is not None and math.isnan(tip_radius) else tip_radius
    tubes = [t.with_pose(*map(float, p)) for t, p in zip(scene.initial, last)]
    result = verify_scans(before, after, last, tubes, tip_radius=R, moved=moved,
                          position_threshold=position_threshold, angle_threshold=angle_threshold)
    if tip_radius is not None and math.isnan(tip_radius):
        result.tip_radius_source = "the session's tip radius"
    if reseed is not None:
        result.files["reseed"] = write_reseed(after, result.found, reseed)
    if out_dir is not None:
        from arsurf.replay.plots import save_figure
        from arsurf.verify.figure import after_in_before_frame, verify_figure

        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        hb, ha = level_substrate(before)[0], level_substrate(after)[0]  # z drift and tilt removed from both
        margin = scene.substrate_margin or 2.0 * max(before.dx, before.dy)
        substrate = scene.substrate(before.with_heights(hb), margin=margin).heights
        fig = verify_figure(substrate, after_in_before_frame(ha, result.registration), before.dx, before.dy, tubes,
                            result.checks, result.wrong, tip_radius=result.tip_radius)
        result.files["figure"] = save_figure(fig, out / f"verify.{figure_format}", dpi=dpi or 200)
        result.files["report"] = out / "verify.json"
        write_text(out / "verify.json", json.dumps(result.to_json(), indent=1, allow_nan=False) + "\n",
                   what="verify report", error=VerifyError)  # atomic, never through a planted link
    return result
