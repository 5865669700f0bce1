r"""The live link to an instrument: a thread that reads it as fast as it answers and moves it.

The haptic loop runs at 1 kHz and must never wait on a network: :class:`InstrumentLink` owns
the instrument in its own thread, which, round after round,

1. moves the tip one step towards the newest commanded position (clipped to the instrument's
   box), the step at most ``max_speed`` times the time since the last round: a jump of the
   stylus becomes a bounded ramp,
2. reads one sample (tip position and both signals),
3. publishes it with the host time it arrived.

The loop reads the newest published sample (:meth:`InstrumentLink.latest`, a copy under a lock,
no I/O) and its age on the host clock. A round is paced to at most ``rate`` per second (an
instrument that answers faster, like the virtual AFM, is not spun on); a controller slower than
the loop simply gives older samples, which the loop sees in their age.

Any error in the thread (a stalled or dead link, a refused command) ends the thread: the link
stops sending moves - the tip stays where it is - and :attr:`InstrumentLink.error` holds the one
line that says why, which the loop turns into zero force (:mod:`arsurf.sessions.instrument_session`).

Examples
--------
>>> from arsurf.instrument.instrument import VirtualAFM
>>> afm = VirtualAFM(0.0, probe_height=1e-6, tip_xy=(5e-6, 5e-6), keep_history=False)
>>> with InstrumentLink(afm, axes="xy") as link:
...     s = link.wait_first(timeout=2.0)
>>> round(float(s.position[0]) * 1e6, 3), link.samples > 0
(5.0, True)
"""
from __future__ import annotations

import math
import threading
import time

import numpy as np

from arsurf.errors import InstrumentError, InstrumentLinkLost
from arsurf.instrument.interface import Instrument, InstrumentSample

__all__ = ["InstrumentLink"]


class InstrumentLink:
    """Read and command an :class:`Instrument` from a thread of its own.

    Parameters
    ----------
    instrument : Instrument
        Opened by :meth:`start` if it is not open (and then closed by :meth:`stop`).
    rate : float, Hz
        Most rounds per second (default 1000, the loop rate).
    axes : {"xyz", "xy"}
        What a commanded position moves: all three axes (the Z feedback must be off), or XY with
        the Z feedback holding the deflection.
    """

    def __init__(self, instrument: Instrument, *, rate: float = 1000.0, axes: str = "xyz") -> None:
        if not isinstance(instrument, Instrument):
            raise InstrumentError(f"instrument must be an arsurf Instrument (got {type(instrument).__name__})")
        if axes not in ("xyz", "xy"):
            raise InstrumentError(f"axes must be 'xyz' or 'xy' (got {axes!r})")
        rate = float(rate)
        if not (math.isfinite(rate) and 1.0 <= rate <= 20000.0):
            raise InstrumentError(f"rate must be in [1, 20000] Hz (got {rate!r})")
        self.instrument, self.axes, self.rate = instrument, axes, rate
        self._period = 1.0 / rate
        self._lock = threading.Lock()
        self._published = InstrumentSample()
        self._arrived = -math.inf  # host time the published sample arrived
        self._target = np.full(3, np.nan)
        self._new_target = False
        self._holding = False
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._opened_here = False
        self._limits = None
        self.error: str | None = None
        #: rounds completed, moves sent, commands clipped to the box, steps limited by the speed
        self.samples = self.moves = self.clamped = self.rate_limited = 0
        self.round_time = np.zeros(4096)  # the last round trips (read + move), s, a ring

    # -- lifecycle ---------------------------------------------------------------------------------
    def start(self) -> "InstrumentLink":
        if self._thread is not None:
            raise InstrumentError("the instrument link is already running")
        if not self.instrument.is_open:
            self.instrument.open()
            self._opened_here = True
        if "z" in self.axes and self.instrument.feedback:
            raise InstrumentError(f"{self.instrument.name}: the Z feedback is on, so the link cannot command Z; "
                                  "switch it off, or give axes='xy' to let the feedback hold Z")
        self._limits = self.instrument.limits  # read once: the servo thread's command() allocates nothing
        self.error = None
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="arsurf-instrument-link", daemon=True)
        self._thread.start()
        return self

    def stop(self, timeout: float = 2.0) -> None:
        """Stop the thread (a round in flight ends within the instrument's own reply timeout) and
        close the instrument if :meth:`start` opened it."""
        self._stop.set()
        t, self._thread = self._thread, None
        if t is not None:
            t.join(timeout)
        if self._opened_here:
            self.instrument.close()
            self._opened_here = False

    def __enter__(self) -> "InstrumentLink":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    @property
    def is_running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    # -- the loop's side (no I/O) ---------------------------------------------------------------------
    def latest(self, out: InstrumentSample) -> float:
        """Copy the newest sample into ``out``; returns its age on the host clock, s (``inf``
        before the first one)."""
        with self._lock:
            self._published.copy_into(out)
            arrived = self._arrived
        return time.perf_counter() - arrived

    def command(self, target: np.ndarray) -> None:
        """Ask for the tip at ``target`` (3,) m, instrument frame (the newest request wins; it
        is clipped to the instrument's limits as :meth:`start` read them - counted in
        :attr:`clamped` - never raised on). Only while the link runs."""
        lim = self._limits
        if lim is None:
            raise InstrumentError("the instrument link is not started; start() it before commanding the tip")
        with self._lock:
            if self._holding:
                return
            t = self._target
            t[:] = target
            if not np.all(np.isfinite(t)):
                return
            c, clipped = lim.clamp(t)
            t[:] = c
            self.clamped += clipped
            self._new_target = True

    def hold(self) -> None:
        """Send no more moves (the tip stays where it is); reading goes on."""
        with self._lock:
            self._holding = True
            self._new_target = False

    def wait_first(self, timeout: float = 2.0) -> InstrumentSample:
        """The first sample, waiting for it at most ``timeout`` s."""
        out = InstrumentSample()
        deadline = time.perf_counter() + timeout
        while self.latest(out) == math.inf:
            if self.error is not None:
                raise InstrumentLinkLost(self.error)
            if time.perf_counter() > deadline:
                raise InstrumentLinkLost(f"{self.instrument.name} gave no sample within {timeout:g} s")
            time.sleep(1e-3)
        return out

    # -- the link thread --------------------------------------------------------------------------------
    def _run(self) -> None:
        inst, period = self.instrument, self._period
        sample = InstrumentSample()
        sent = np.full(3, np.nan)
        goal = np.full(3, np.nan)
        moving = False
        clock = time.perf_counter
        nxt = t_prev = clock()
        try:
            inst.read(sample)
            sent[:] = sample.position  # moves start from where the tip is
            while not self._stop.is_set():
                t0 = clock()
                with self._lock:
                    if self._new_target:
                        goal[:] = self._target
                        self._new_target = False
                        moving = True
                    if self._holding:
                        moving = False
                if moving:  # one step towards the goal, at most max_speed x the time since the last round
                    step = goal - sent
                    if self.axes == "xy":
                        step[2] = 0.0
                    dist = float(np.linalg.norm(step))
                    allowed = self._limits.max_speed * max(period, t0 - t_prev)
                    if dist > allowed:
                        step *= allowed / dist
                        self.rate_limited += 1
                    else:
                        moving = False  # this step reaches it
                    if dist > 0.0:
                        sent += step
                        inst.move_to(sent if self.axes == "xyz" else (sent[0], sent[1], math.nan))
                        self.moves += 1
                t_prev = t0
                inst.read(sample)
                t1 = clock()
                with self._lock:
                    sample.copy_into(self._published)
                    self._arrived = t1
                self.round_time[self.samples % self.round_time.size] = t1 - t0
                self.samples += 1
                nxt += period
                if nxt > t1:
                    time.sleep(nxt - t1)
                else:
                    nxt = t1  # behind: no burst of catch-up rounds
        except Exception as exc:  # reported to the loop, never raised in this thread
            first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
            self.error = first if isinstance(exc, InstrumentError) else f"{type(exc).__name__}: {first}"
