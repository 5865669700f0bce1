r"""The instrument interface: what every AFM (virtual, or a controller over its link) looks like.

In a real experiment the AR model's inputs are the instrument's - the tip position and the two
photodiode signals (deflection and torsion) - and its output is the commanded tip position.
An :class:`Instrument` is opened, read (one :class:`InstrumentSample`: tip x, y, z in metres
and both signals in the controller's units, with the time it was taken), commanded
(:meth:`Instrument.move_to`, checked against the :class:`InstrumentLimits`), engaged, withdrawn,
its Z feedback switched on and off, and closed.

Coordinates are the instrument's own (its *instrument frame*), in metres, with z the height of
the tip (growing away from the sample, as a withdraw moves it). :class:`InstrumentFrame` maps
the scan frame of the AR model onto it (an offset and a sign per axis: the bring-up checklist of
docs/instruments.rst measures both).

Every instrument is its own last line of defence, as every haptic device is: the public methods
check that it is open, that a target is finite and inside its limits, and that Z is commanded
only with the feedback off; implementations see checked values only.

Examples
--------
>>> lim = InstrumentLimits(low=(0, 0, -1e-6), high=(10e-6, 10e-6, 1e-6), max_speed=20e-6)
>>> lim.clamp(np.array([12e-6, 5e-6, 0.0]))[0].tolist()
[1e-05, 5e-06, 0.0]
>>> frame = InstrumentFrame(origin=(-4e-6, -4e-6, 0.0), signs=(1, -1, 1))
>>> (frame.to_instrument(np.array([1e-6, 1e-6, 2e-9])) * 1e6).round(6).tolist()   # um
[-3.0, -5.0, 0.002]
"""
from __future__ import annotations

import abc
import math
from dataclasses import dataclass, field

import numpy as np

from arsurf.errors import InstrumentError

__all__ = ["Instrument", "InstrumentFrame", "InstrumentLimits", "InstrumentSample"]

_AXES = "xyz"


def _vec3(value, name: str) -> np.ndarray:
    """``value`` as a finite float64 (3,) array, or a one-line InstrumentError."""
    try:
        a = np.array(value, dtype=np.float64).reshape(3)
    except (TypeError, ValueError):
        raise InstrumentError(f"{name} must be 3 numbers x, y, z in metres (got {value!r})") from None
    if not np.all(np.isfinite(a)):
        raise InstrumentError(f"{name} must be finite (got {a.tolist()}); NaN/inf cannot be a position in metres")
    return a


@dataclass(frozen=True, eq=False)
class InstrumentLimits:
    """The box the tip may be commanded in (instrument frame) and the speed it may be moved at.

    Parameters
    ----------
    low, high : (3,) float, metres
        Corners of the box, ``low < high`` on every axis.
    max_speed : float, m/s
        Largest speed of a commanded move (the live link limits each step to
        ``max_speed * dt``; a controller is also told it, where it can be).
    source : str
        Where the numbers come from (the user, the controller's report, a datasheet).
    """

    low: np.ndarray
    high: np.ndarray
    max_speed: float
    source: str = "set by the user"

    def __post_init__(self) -> None:
        lo, hi = _vec3(self.low, "low"), _vec3(self.high, "high")
        if not np.all(lo < hi):
            raise InstrumentError(f"the limits need low < high on every axis (got low {lo.tolist()}, high "
                                  f"{hi.tolist()} m)")
        v = float(self.max_speed)
        if not (math.isfinite(v) and v > 0.0):
            raise InstrumentError(f"max_speed must be positive and finite, m/s (got {self.max_speed!r})")
        for name, a in (("low", lo), ("high", hi)):
            a.setflags(write=False)
            object.__setattr__(self, name, a)
        object.__setattr__(self, "max_speed", v)

    def check(self, target: np.ndarray, axes: str = _AXES) -> None:
        """Raise :class:`InstrumentError` if an axis of ``axes`` of ``target`` is outside the box."""
        for j, a in enumerate(_AXES):
            if a in axes and not (self.low[j] <= target[j] <= self.high[j]):
                raise InstrumentError(
                    f"target {a} = {target[j]:.6g} m is outside the instrument's limits [{self.low[j]:.6g}, "
                    f"{self.high[j]:.6g}] m ({self.source}); command a point inside them"
                )

    def clamp(self, target: np.ndarray) -> tuple[np.ndarray, bool]:
        """``target`` clipped into the box, and whether it had to be."""
        c = np.minimum(np.maximum(target, self.low), self.high)
        return c, bool(np.any(c != target))

    def intersect(self, other: "InstrumentLimits") -> "InstrumentLimits":
        """The box both allow, at the lower of the two speeds."""
        return InstrumentLimits(np.maximum(self.low, other.low), np.minimum(self.high, other.high),
                                min(self.max_speed, other.max_speed),
                                " and ".join(dict.fromkeys(s for s in (self.source, other.source) if s)))


@dataclass(frozen=True, eq=False)
class InstrumentFrame:
    r"""The scan frame of the AR model mapped onto the instrument frame, axis by axis:

    .. math:: p_{instrument} = o + s \odot p_{scan}, \qquad s_j \in \{-1, +1\}

    Parameters
    ----------
    origin : (3,) float, metres
        Where the scan frame's origin is in the instrument frame.
    signs : (3,) of +1 / -1
        Direction of each scan axis in the instrument frame.
    """

    origin: np.ndarray = field(default_factory=lambda: np.zeros(3))
    signs: np.ndarray = field(default_factory=lambda: np.ones(3))

    def __post_init__(self) -> None:
        o = _vec3(self.origin, "origin")
        s = _vec3(self.signs, "signs")
        if not np.all(np.abs(s) == 1.0):
            raise InstrumentError(f"signs must be +1 or -1 per axis (got {s.tolist()}); they are the axis directions")
        for name, a in (("origin", o), ("signs", s)):
            a.setflags(write=False)
            object.__setattr__(self, name, a)

    def to_instrument(self, p: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Scan-frame point(s) ``p`` (..., 3) m in the instrument frame."""
        return np.add(self.origin, self.signs * p, out=out)

    def to_scan(self, q: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Instrument-frame point(s) ``q`` (..., 3) m in the scan frame."""
        return np.multiply(np.subtract(q, self.origin, out=out), self.signs, out=out)

    def to_metadata(self) -> dict:
        return {"origin": self.origin.tolist(), "signs": self.signs.tolist()}


@dataclass(eq=False)
class InstrumentSample:
    """One reading of the instrument.

    Parameters
    ----------
    position : (3,) float, metres
        Tip x, y, z in the instrument frame.
    signals : (2,) float
        Deflection (vertical) and torsion (lateral) photodiode signals, in the controller's units
        (:attr:`Instrument.signal_units`; volts on a Nanonis input).
    timestamp : float, s
        When it was read, on the instrument's clock (:meth:`Instrument.now`); ``-inf`` before the
        first reading.
    """

    position: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    signals: np.ndarray = field(default_factory=lambda: np.full(2, np.nan))
    timestamp: float = -math.inf

    def copy_into(self, out: "InstrumentSample") -> "InstrumentSample":
        """Copy this sample into ``out`` without allocating; returns ``out``."""
        out.position[:] = self.position
        out.signals[:] = self.signals
        out.timestamp = self.timestamp
        return out


class Instrument(abc.ABC):
    """Abstract AFM instrument: open, read tip position and signals, command moves, close.

    Subclasses implement :attr:`name`, :attr:`limits`, :meth:`now`, :meth:`_open`, :meth:`_close`,
    :meth:`_read`, :meth:`_move`, :meth:`_set_feedback`, :meth:`_engage` and :meth:`_withdraw`;
    the public methods check the state and the arguments first. An instrument is a context
    manager (``with NanonisAFM(...) as afm:``).
    """

    #: names of the two signals (deflection, torsion) and their units, for logs and sessions
    signal_units: tuple[str, str] = ("V", "V")

    def __init__(self) -> None:
        self._is_open = False
        self._feedback = False
        self._target = np.full(3, np.nan)

    # -- what a subclass provides ------------------------------------------------------------
    @property
    @abc.abstractmethod
    def name(self) -> str:
        """What the instrument is, for messages and the session metadata."""

    @property
    @abc.abstractmethod
    def limits(self) -> InstrumentLimits:
        """Where the tip may be commanded (valid once open)."""

    @abc.abstractmethod
    def now(self) -> float:
        """The instrument's clock, seconds (the clock of ``InstrumentSample.timestamp``)."""

    @abc.abstractmethod
    def _open(self) -> None: ...

    @abc.abstractmethod
    def _close(self) -> None:
        """Release the link; leave the tip where it is."""

    @abc.abstractmethod
    def _read(self, out: InstrumentSample) -> None:
        """Fill ``out`` with a fresh sample."""

    @abc.abstractmethod
    def _move(self, target: np.ndarray, axes: str, wait: bool) -> None:
        """Move the axes named in ``axes`` ("xy", "z" or "xyz") to ``target`` (checked)."""

    @abc.abstractmethod
    def _set_feedback(self, on: bool) -> None: ...

    @abc.abstractmethod
    def _engage(self) -> None:
        """Approach until the Z feedback holds the set point (feedback on at the end), or raise."""

    @abc.abstractmethod
    def _withdraw(self) -> None:
        """Switch the feedback off and retract the tip fully."""

    # -- public API ----------------------------------------------------------------------------
    @property
    def is_open(self) -> bool:
        return self._is_open

    @property
    def feedback(self) -> bool:
        """Whether the Z feedback is on (as last set or read from the instrument)."""
        return self._feedback

    def open(self) -> "Instrument":
        """Open the instrument (idempotent); returns ``self``."""
        if not self._is_open:
            self._open()
            self._is_open = True
        return self

    def close(self) -> None:
        """Close the link (idempotent). The tip stays where it is: nothing is moved."""
        if self._is_open:
            try:
                self._close()
            finally:
                self._is_open = False

    def __enter__(self) -> "Instrument":
        return self.open()

    def __exit__(self, *exc) -> None:
        self.close()

    def _require_open(self) -> None:
        if not self._is_open:
            raise InstrumentError(f"{self.name} is not open; call open() first or use it as a context manager")

    def read(self, out: InstrumentSample | None = None) -> InstrumentSample:
        """A fresh sample (tip position and both signals), filled into ``out`` if given."""
        if not self._is_open:
            self._require_open()
        if out is None:
            out = InstrumentSample()
        self._read(out)
        return out

    def move_to(self, target, *, wait: bool = False) -> None:
        """Move the tip to ``target`` (x, y, z) m, instrument frame.

        An axis given as NaN is left where it is (``(x, y, nan)`` moves in XY only). Z can be
        commanded only with the feedback off (the Z controller owns it otherwise), and every
        commanded axis must be inside :attr:`limits`.

        Raises
        ------
        InstrumentError
            Not open, a target outside the limits or not a number, Z with the feedback on.
        """
        self._require_open()
        try:
            t = np.array(target, dtype=np.float64).reshape(3)
        except (TypeError, ValueError):
            raise InstrumentError(f"target must be x, y, z in metres (NaN: leave that axis) (got {target!r})") from None
        if np.any(np.isinf(t)):
            raise InstrumentError(f"target must be finite or NaN per axis (got {t.tolist()})")
        given = ~np.isnan(t)
        if given[0] != given[1]:
            raise InstrumentError(f"x and y are commanded together (got {t.tolist()}); give both or neither")
        axes = ("xy" if given[0] else "") + ("z" if given[2] else "")
        if not axes:
            return
        if "z" in axes and self._feedback:
            raise InstrumentError(f"{self.name}: the Z feedback is on, so Z cannot be commanded "
                                  f"(z = {t[2]:.6g} m); switch the feedback off first (set_feedback(False))")
        self.limits.check(t, axes)
        self._move(t, axes, bool(wait))
        self._target[given] = t[given]

    def set_feedback(self, on: bool) -> None:
        """Switch the Z feedback on or off."""
        self._require_open()
        self._set_feedback(bool(on))
        self._feedback = bool(on)

    def engage(self) -> None:
        """Approach the sample until the Z feedback holds its set point (feedback on afterwards)."""
        self._require_open()
        self._engage()
        self._feedback = True

    def withdraw(self) -> None:
        """Switch the feedback off and retract the tip fully (the emergency move)."""
        self._require_open()
        self._withdraw()
        self._feedback = False

    def scan_image(self, settings=None):
        """Acquire an image of the sample (a :class:`~arsurf.scan.scan.Scan` of the Z channel,
        the metadata a file gives); ``settings`` are the instrument's own (None: its current
        ones). An instrument that cannot image raises :class:`InstrumentError`."""
        self._require_open()
        return self._scan_image(settings)

    def _scan_image(self, settings):
        raise InstrumentError(f"{self.name} cannot acquire images")
