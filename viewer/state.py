"""The viewer's input: one :class:`SceneState` per frame, filled by the loop at 30-60 Hz.

Everything is SI (metres, newtons, hertz) like the engine; :class:`~arsurf_viewer.SurfaceView`
converts to its nanometre scene and to the HUD's nN / nm at its edge. This module does not
import pyvista, so the loop can build states without the viewer installed.

Examples
--------
>>> import numpy as np
>>> from arsurf.spline.surface import BSplineSurface
>>> s = BSplineSurface.from_heights(np.zeros((6, 6)), (0.0, 50e-9), (0.0, 50e-9))
>>> st = SceneState(s, tip_center=(25e-9, 25e-9, 19e-9), tip_radius=20e-9, depth=1e-9,
...                 contact_point=(25e-9, 25e-9, 0.0), contact_normal=(0, 0, 2), force=(0, 0, 3e-9))
>>> st.contact_normal.tolist(), round(st.force_magnitude * 1e9, 3)
([0.0, 0.0, 1.0], 3.0)
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from arsurf.errors import ViewerError
from arsurf.spline.surface import BSplineSurface

__all__ = ["ViewerError", "SceneState", "Tube"]


def _vec3(name: str, value, allow_none: bool = False) -> np.ndarray | None:
    if value is None:
        if allow_none:
            return None
        raise ViewerError(f"`{name}` is required: a (3,) vector in SI units")
    try:
        a = np.asarray(value, dtype=np.float64).reshape(3)
    except (TypeError, ValueError):
        raise ViewerError(f"`{name}` must be a (3,) vector (got {value!r})") from None
    if not np.isfinite(a).all():
        raise ViewerError(f"`{name}` must be finite (got {a.tolist()})")
    return a


def _scalar(name: str, value, *, positive: bool = False, nonneg: bool = False, allow_nan: bool = False) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ViewerError(f"`{name}` must be a number (got {value!r})") from None
    if math.isnan(x) and allow_nan:
        return x
    if not math.isfinite(x) or (positive and x <= 0.0) or (nonneg and x < 0.0):
        rule = "positive" if positive else "non-negative" if nonneg else "finite"
        raise ViewerError(f"`{name}` must be {rule} (got {value!r})")
    return x


@dataclass(frozen=True, slots=True)
class Tube:
    """A nanotube to draw: a capsule whose cylinder runs from centre - axis*length/2 to
    centre + axis*length/2 (metres), radius in metres."""

    centre: np.ndarray
    axis: np.ndarray
    length: float
    radius: float

    @classmethod
    def coerce(cls, item: Any) -> "Tube":
        if isinstance(item, Tube):
            return item
        try:
            centre, axis, length, radius = item
        except (TypeError, ValueError):
            raise ViewerError(f"a tube must be (centre (3,), axis (3,), length, radius) in metres (got {item!r})") from None
        c = _vec3("tube centre", centre)
        a = _vec3("tube axis", axis)
        n = float(np.linalg.norm(a))
        if n == 0.0:
            raise ViewerError("a tube axis must be a non-zero (3,) vector (got [0, 0, 0])")
        return cls(c, a / n, _scalar("tube length", length, nonneg=True), _scalar("tube radius", radius, positive=True))


@dataclass(slots=True)
class SceneState:
    """What the viewer shows in one frame (SI units).

    Parameters
    ----------
    surface : BSplineSurface
        The live (possibly deformed) surface; the view re-samples only the part of it whose
        control points changed since the last frame.
    tip_center : (3,) float, metres
        Centre of the tip sphere.
    tip_radius : float, metres
    contact_point : (3,) float, metres, or None
        Closest point of the surface to the tip (shown with the normal when given).
    contact_normal : (3,) float or None
        Contact normal, out of the sample (normalised here).
    depth : float, metres
        Indentation depth d = R - signed distance (negative = gap).
    contact_radius : float, metres
        Radius a of the contact disk (Maugis-Dugdale).
    force : (3,) float, newtons
        Force on the tip (decoupled from the measured signals, or the model's load).
    maugis_lambda : float
        Maugis parameter λ (NaN when there is no adhesive model).
    loop_rate_hz : float, Hz
        Measured rate of the haptic loop (NaN when unknown).
    device_status : str
        One line about the device ("virtual", "bridge 10.0.0.2 ok", "SAFETY: clamped").
    tubes : sequence of (centre (3,), axis (3,), length, radius), metres
        Nano-objects to draw (see :class:`Tube`).
    time : float, seconds, or NaN
        Session time shown in the HUD.
    flags : int
        Flag bits of :mod:`arsurf.status` to name in the HUD (the model's ``BEYOND_MODEL``, the
        loop's safety flags); 0: none.
    """

    surface: BSplineSurface
    tip_center: np.ndarray
    tip_radius: float
    contact_point: np.ndarray | None = None
    contact_normal: np.ndarray | None = None
    depth: float = 0.0
    contact_radius: float = 0.0
    force: np.ndarray = field(default_factory=lambda: np.zeros(3))
    maugis_lambda: float = math.nan
    loop_rate_hz: float = math.nan
    device_status: str = ""
    tubes: Sequence[Any] = ()
    time: float = math.nan
    flags: int = 0

    def __post_init__(self) -> None:
        if not isinstance(self.surface, BSplineSurface):
            raise ViewerError(f"`surface` must be a BSplineSurface (got {type(self.surface).__name__})")
        self.tip_center = _vec3("tip_center", self.tip_center)
        self.tip_radius = _scalar("tip_radius", self.tip_radius, positive=True)
        self.contact_point = _vec3("contact_point", self.contact_point, allow_none=True)
        n = _vec3("contact_normal", self.contact_normal, allow_none=True)
        if n is not None:
            norm = float(np.linalg.norm(n))
            if norm == 0.0:
                raise ViewerError("`contact_normal` must be non-zero (got [0, 0, 0]); pass None when there is no contact")
            n = n / norm
        self.contact_normal = n
        self.depth = _scalar("depth", self.depth)
        self.contact_radius = _scalar("contact_radius", self.contact_radius, nonneg=True)
        self.force = _vec3("force", self.force)
        self.maugis_lambda = _scalar("maugis_lambda", self.maugis_lambda, allow_nan=True)
        self.loop_rate_hz = _scalar("loop_rate_hz", self.loop_rate_hz, allow_nan=True)
        self.time = _scalar("time", self.time, allow_nan=True)
        self.device_status = str(self.device_status)
        self.tubes = tuple(Tube.coerce(t) for t in self.tubes)
        if isinstance(self.flags, bool) or not isinstance(self.flags, (int, np.integer)) or self.flags < 0:
            raise ViewerError(f"`flags` must be a non-negative integer of arsurf.status bits (got {self.flags!r})")
        self.flags = int(self.flags)

    @property
    def force_magnitude(self) -> float:
        """|F|, newtons."""
        return float(np.linalg.norm(self.force))

    @classmethod
    def from_contact(cls, surface: BSplineSurface, tip_center, tip_radius: float, contact=None, **fields) -> "SceneState":
        """Build a state from a contact record (duck-typed: ``point``, ``normal``, ``depth`` and
        optionally ``in_contact``), as :func:`arsurf.collide` returns.

        The contact point and normal are shown whatever the depth (the closest point and its
        normal are informative before touching too); ``depth`` is taken from the record.
        """
        if contact is not None:
            fields.setdefault("contact_point", getattr(contact, "point"))
            fields.setdefault("contact_normal", getattr(contact, "normal"))
            fields.setdefault("depth", getattr(contact, "depth"))
        return cls(surface, tip_center, tip_radius, **fields)
