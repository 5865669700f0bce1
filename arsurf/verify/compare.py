r"""The model's poses against the tubes the scan after shows: matching, errors, the flag.

The tubes found in the scan after (:mod:`arsurf.verify.tubes`, its own pixel frame) are carried
into the scan before's frame - the frame of the session and its model - by the registration's
affine map (:mod:`arsurf.verify.register`): the centre as a point, the axis as a direction. Each
tube of the model is then paired with one found tube (Hungarian assignment,
``scipy.optimize.linear_sum_assignment``) on the cost

.. math:: c = \frac{|\mathbf c_{model} - \mathbf c_{found}|}{L_{model}} + \frac{|\Delta\varphi|}{\pi/2},

pairs whose centres are more than half the model's length plus two diameters apart refused (the
tube is "not found" there). For each pair, the position error is the distance of the centres
(nm and pixels) and the angle error the axis difference modulo 180 degrees, in (-90, 90].

The model is flagged wrong when a tube of the model is not found, or when a position error
exceeds ``position_threshold`` (default :data:`POSITION_THRESHOLD_PX` pixels) or an angle error
``angle_threshold`` (default :data:`ANGLE_THRESHOLD_DEG` degrees): twice the errors the method
itself stays within on the virtual instrument (bench/verify.py: 1 pixel, 1 degree).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy.optimize import linear_sum_assignment

from arsurf.errors import VerifyError
from arsurf.verify.register import Registration
from arsurf.verify.tubes import FoundTube

__all__ = ["POSITION_THRESHOLD_PX", "ANGLE_THRESHOLD_DEG", "Pose", "ObjectCheck", "to_before_frame", "compare", "model_wrong"]

#: default thresholds of the wrong-model flag
POSITION_THRESHOLD_PX = 2.0
ANGLE_THRESHOLD_DEG = 2.0


@dataclass(frozen=True)
class Pose:
    """A tube's measured pose in the scan before's frame: centre (m), angle (rad, (-pi/2, pi/2]),
    length and diameter (m)."""

    x: float
    y: float
    angle: float
    length: float
    diameter: float


@dataclass(frozen=True)
class ObjectCheck:
    """One tube of the model against the scan after.

    Attributes
    ----------
    index : int
        The tube's index in the session's scene.
    predicted : (3,) float
        The model's pose at the session's end: x, y (m), angle (rad).
    moved : bool
        The model moved it during the session.
    found : Pose or None
        Its measured pose (before frame), None when not found.
    found_index : int or None
        Index in the list of found tubes.
    position_error : float, metres (inf when not found)
    angle_error : float, radians, (-pi/2, pi/2] (nan when not found)
    """

    index: int
    predicted: np.ndarray
    moved: bool
    found: Pose | None
    found_index: int | None
    position_error: float
    angle_error: float

    def to_json(self, dx: float) -> dict:
        f = self.found
        return {"tube_index": self.index, "moved_by_model": self.moved,
                "predicted": {"x_nm": self.predicted[0] * 1e9, "y_nm": self.predicted[1] * 1e9,
                              "angle_deg": math.degrees(self.predicted[2])},
                "measured": None if f is None else {"x_nm": f.x * 1e9, "y_nm": f.y * 1e9,
                                                     "angle_deg": math.degrees(f.angle), "length_nm": f.length * 1e9,
                                                     "diameter_nm": f.diameter * 1e9},
                "found": f is not None,
                "position_error_nm": None if f is None else self.position_error * 1e9,
                "position_error_px": None if f is None else self.position_error / dx,
                "angle_error_deg": None if f is None else math.degrees(self.angle_error)}


def _wrap_half(a):
    return (np.asarray(a) + 0.5 * np.pi) % np.pi - 0.5 * np.pi


def to_before_frame(tube: FoundTube, reg: Registration, dx: float, dy: float) -> Pose:
    """A tube found in the scan after (its frame, metres) in the scan before's frame."""
    lin = reg.affine[:, :2]
    fx, fy = reg.map(tube.x / dx, tube.y / dy)
    u = np.array([math.cos(tube.angle) / dx, math.sin(tube.angle) / dy])
    v = lin @ u
    v_m = np.array([v[0] * dx, v[1] * dy])
    stretch = float(np.hypot(*v_m))
    angle = float(_wrap_half(math.atan2(v_m[1], v_m[0])))
    return Pose(float(fx * dx), float(fy * dy), angle, tube.length * stretch, tube.diameter)


def compare(predicted: np.ndarray, lengths: Sequence[float], diameters: Sequence[float], moved: Sequence[bool],
            found: Sequence[FoundTube], reg: Registration, dx: float, dy: float) -> list[ObjectCheck]:
    """Pair the model's tubes with the found ones and measure their errors (module docstring).

    Parameters
    ----------
    predicted : (k, 3) float
        The model's poses at the session's end (x, y m, angle rad), the scan before's frame.
    lengths, diameters : (k,) float, metres
    moved : (k,) bool
    found : sequence of FoundTube
        In the scan after's frame.
    reg : Registration
    dx, dy : float, metres
    """
    p = np.asarray(predicted, dtype=np.float64).reshape(-1, 3)
    if not len(found):
        raise VerifyError("no objects found in the scan after: nothing to compare with the model")
    poses = [to_before_frame(t, reg, dx, dy) for t in found]
    k, m = len(p), len(poses)
    cost = np.full((k, m), 1e6)
    for i in range(k):
        for j, q in enumerate(poses):
            d = math.hypot(p[i, 0] - q.x, p[i, 1] - q.y)
            if d <= 0.5 * lengths[i] + 2.0 * diameters[i]:
                cost[i, j] = d / lengths[i] + abs(float(_wrap_half(p[i, 2] - q.angle))) / (0.5 * math.pi)
    rows, cols = linear_sum_assignment(cost)
    pair = {int(i): int(j) for i, j in zip(rows, cols) if cost[i, j] < 1e6}
    out = []
    for i in range(k):
        j = pair.get(i)
        if j is None:
            out.append(ObjectCheck(i, p[i].copy(), bool(moved[i]), None, None, math.inf, math.nan))
            continue
        q = poses[j]
        out.append(ObjectCheck(i, p[i].copy(), bool(moved[i]), q, j, math.hypot(p[i, 0] - q.x, p[i, 1] - q.y),
                               float(_wrap_half(q.angle - p[i, 2]))))
    return out


def model_wrong(checks: Sequence[ObjectCheck], dx: float, position_threshold: float | None = None,
                angle_threshold: float | None = None) -> tuple[bool, list[str]]:
    """(flag, reasons): a tube not found, or an error beyond a threshold (position m, angle rad;
    defaults :data:`POSITION_THRESHOLD_PX` pixels of ``dx`` and :data:`ANGLE_THRESHOLD_DEG`)."""
    pos = POSITION_THRESHOLD_PX * dx if position_threshold is None else float(position_threshold)
    ang = math.radians(ANGLE_THRESHOLD_DEG) if angle_threshold is None else float(angle_threshold)
    reasons = []
    for c in checks:
        if c.found is None:
            reasons.append(f"tube {c.index} is not found near its predicted pose")
        else:
            if c.position_error > pos:
                reasons.append(f"tube {c.index} is {c.position_error * 1e9:.1f} nm from its predicted position "
                               f"(threshold {pos * 1e9:.1f} nm)")
            if abs(c.angle_error) > ang:
                reasons.append(f"tube {c.index} is turned {math.degrees(c.angle_error):+.1f} deg from its predicted "
                               f"angle (threshold {math.degrees(ang):.1f} deg)")
    return bool(reasons), reasons
