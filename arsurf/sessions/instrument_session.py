r"""A live session driven by an AFM: the haptic loop on the instrument's measured signals, recorded.

Per servo tick (1 kHz, :class:`~arsurf.haptics.scheduler.Scheduler`):

1. the newest instrument sample (:class:`~arsurf.instrument.link.InstrumentLink`: tip position
   and the deflection and torsion signals, read in the link's own thread) and its age;
2. the signals as the cantilever's angles, :math:`\alpha = S_v (V_d - V_{d0})`,
   :math:`\theta = S_h (V_t - V_{t0})` (the :class:`~arsurf.force.photodiode.Photodiode`'s
   sensitivities; the free-lever baselines :math:`V_{d0}, V_{t0}` averaged over the first
   samples, the tip out of contact, unless given);
3. the loop tick with those angles (``source="measured"``: the force on the hand is the one the
   decoupling reads from the instrument) - the model at the commanded tip centre;
4. the commanded tip centre, mapped to the instrument frame
   (:class:`~arsurf.instrument.interface.InstrumentFrame`, the tip apex one radius below the
   centre), sent to the link (clipped to the limits, speed-limited);
5. one session row: the stylus, the commanded probe, the angles the loop used, the forces, the
   contact, and where the instrument measured the tip (``instrument_position``, scan frame).

The session replays like any other (:func:`arsurf.replay.replay.replay`): the model re-run at the
recorded probe positions with the recorded angles gives back the recorded contact and measured
force.

**Fail safe.** A sample older than ``max_age`` (a stalled or slow link), an error of the link
(a dead link, a refused move, bytes that are not the protocol) or a signal that is not a number
stops the servo loop in that tick: the hand gets zero force (the scheduler's stop hook), no
further move is sent (the tip stays where it is), the device is closed, the session is closed
with every tick recorded and marked incomplete, and :class:`~arsurf.errors.InstrumentLinkLost`
says, in one line, what happened and where the tip was left.

Examples
--------
>>> # sim = NanonisSimulator(VirtualAFM(...)).start()
>>> # afm = NanonisAFM(*sim.address, limits=InstrumentLimits(...))
>>> # record_instrument_session("s.h5", meta, VirtualDevice(), afm, photodiode=pd, seconds=2.0,
>>> #                           probe_origin=(x, y, z), frame=InstrumentFrame(origin=(0, 0, -R)))
"""
from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np

from arsurf.assembly import build_loop, build_model, loop_metadata
from arsurf.config import DeviceConfig
from arsurf.errors import InstrumentError, InstrumentLinkLost, LoopError, SessionError
from arsurf.force.photodiode import Photodiode
from arsurf.haptics.device import DeviceState
from arsurf.haptics.loop import LOOP_OUT
from arsurf.haptics.scheduler import Scheduler, TimingStats
from arsurf.instrument.interface import Instrument, InstrumentFrame, InstrumentSample
from arsurf.instrument.link import InstrumentLink
from arsurf.sessions.schema import contact_fields
from arsurf.sessions.writer import SessionWriter

__all__ = ["InstrumentSessionResult", "record_instrument_session"]


@dataclass(frozen=True)
class InstrumentSessionResult:
    """What a completed session did.

    Attributes
    ----------
    path : Path
        The session file.
    ticks : int
        Servo ticks recorded.
    stats : TimingStats
        The servo loop's timing.
    instrument_samples : int
        Samples the link read (the controller's rate is ``instrument_samples / duration``).
    baseline : (2,) float
        Free-lever deflection and torsion signals subtracted (the controller's units).
    round_trip_median, round_trip_p99 : float, s
        The link's read-and-move round trips.
    clamped, rate_limited : int
        Commanded positions clipped to the limits, steps limited by the speed.
    """

    path: Path
    ticks: int
    stats: TimingStats
    instrument_samples: int
    baseline: np.ndarray
    round_trip_median: float
    round_trip_p99: float
    clamped: int
    rate_limited: int


def _baseline(link: InstrumentLink, n: int, timeout: float) -> np.ndarray:
    """Mean of the signals of ``n`` distinct link samples (the tip out of contact)."""
    s = link.wait_first(timeout)
    acc, seen, last = np.zeros(2), 0, -1
    deadline = time.perf_counter() + timeout
    while seen < n:
        if link.error is not None:
            raise InstrumentLinkLost(link.error)
        k = link.samples
        if k != last:
            link.latest(s)
            acc += s.signals
            seen, last = seen + 1, k
        elif time.perf_counter() > deadline:
            raise InstrumentLinkLost(f"{link.instrument.name} gave {seen} of the {n} baseline samples within "
                                     f"{timeout:g} s")
        else:
            time.sleep(2e-4)
    return acc / n


#: s: the sample-age limit of an instrument that states none of its own
DEFAULT_MAX_AGE = 0.02


def record_instrument_session(path: str | os.PathLike, metadata, device, instrument: Instrument, *,
                              photodiode: Photodiode, seconds: float | None = None, probe_origin,
                              ticks: int | None = None,
                              frame: InstrumentFrame | None = None, baseline=None, baseline_samples: int = 50,
                              max_age: float | None = None, axes: str = "xyz", scan_path=None, first_sample_timeout=2.0,
                              handle_signals: bool = False, setup=None, stop=None, priority: int = 0,
                              **safety_kwargs) -> InstrumentSessionResult:
    """Run and record ``seconds`` of the haptic loop on ``instrument``'s measured signals.

    Parameters
    ----------
    path : path-like
        The session file to write (:class:`~arsurf.sessions.writer.SessionWriter`).
    metadata : dict
        Session metadata (:func:`arsurf.assembly.session_metadata`) whose ``haptics`` source is
        ``"measured"`` (or ``"blended"``); ``instrument`` and ``calibration`` are added here.
    device : Device
        The haptic device (opened here if needed, closed at the end).
    instrument : Instrument
        Opened by the link if needed (and then closed).
    photodiode : Photodiode
        Radians per unit of each signal (its ``convention`` is recorded).
    seconds : float, optional
        Wall time to run ...
    ticks : int, optional
        ... or servo ticks to run (in real time; at most one of the two).
    stop : threading.Event, optional
        Ends the session normally (complete) when it is set, e.g. by the command line's Ctrl-C;
        with neither ``seconds`` nor ``ticks`` the session runs until then.
    priority : int
        ``SCHED_FIFO`` priority of the servo thread where the OS grants it (0: the ordinary
        policy; :class:`~arsurf.haptics.scheduler.Scheduler`).
    probe_origin : (3,) float, m
        Tip-sphere centre (scan frame) when the stylus is at its origin.
    frame : InstrumentFrame, optional
        Scan frame -> instrument frame of the tip-sphere centre; default: the same axes, the
        instrument's z being the apex one tip radius below the centre.
    baseline : (2,) float, optional
        Free-lever signals; default: the mean of ``baseline_samples`` samples at the start.
    max_age : float, s, optional
        Oldest instrument sample the loop renders a force from; None (default): the instrument's
        own limit (``sample_age_limit``: a Nanonis derives it from its acquisition period Tap and
        round trip), else 20 ms. Recorded with its source.
    axes : {"xyz", "xy"}
        What the stylus commands (see :class:`~arsurf.instrument.link.InstrumentLink`).
    scan_path : path-like, optional
        The scan, if not where ``metadata`` says.
    handle_signals : bool
        SIGINT/SIGTERM close the recording (incomplete) before stopping.
    setup : ModelSetup, optional
        The model :func:`~arsurf.assembly.build_model` already built from ``metadata`` (default:
        built here).
    **safety_kwargs
        For the loop's safety layer (``ramp_time`` ...).

    Returns
    -------
    InstrumentSessionResult

    Raises
    ------
    InstrumentLinkLost
        The link stalled, died or sent something unusable during the session: the hand got zero
        force, the tip was left where it was, the session keeps every tick (incomplete).
    SessionError
        A metadata whose haptic source does not use measured signals.
    """
    if (seconds is not None and ticks is not None) or all(v is None for v in (seconds, ticks, stop)):
        raise SessionError("give the session's length as seconds (wall time) or ticks (servo ticks), one of the two "
                           "(or a stop event that ends it)")
    if stop is not None and not callable(getattr(stop, "is_set", None)):
        raise SessionError(f"stop must be a threading.Event (got {type(stop).__name__})")
    if seconds is not None and not (isinstance(seconds, (int, float)) and math.isfinite(seconds) and seconds > 0.0):
        raise SessionError(f"seconds must be a positive duration (got {seconds!r})")
    if ticks is not None and not (isinstance(ticks, int) and ticks > 0):
        raise SessionError(f"ticks must be a positive number of servo ticks (got {ticks!r})")
    if max_age is not None and not (isinstance(max_age, (int, float)) and math.isfinite(max_age) and max_age > 0.0):
        raise SessionError(f"max_age must be a positive time in seconds or None (got {max_age!r})")
    if not isinstance(photodiode, Photodiode):
        raise SessionError(f"photodiode must be an arsurf Photodiode (got {type(photodiode).__name__})")
    source = dict(metadata.get("haptics") or {}).get("source")
    if source not in ("measured", "blended"):
        raise SessionError(f"an instrument session renders the measured force: the metadata's haptics source must "
                           f"be 'measured' or 'blended' (got {source!r})")
    if setup is None:
        setup = build_model(metadata, scan_path)
    model = setup.model
    if frame is None:
        frame = InstrumentFrame(origin=(0.0, 0.0, -model.tip_radius))
    loop = build_loop(model, metadata["haptics"], device.info, probe_origin, scene=setup.scene, **safety_kwargs)
    loop.warm_up()
    link = InstrumentLink(instrument, rate=loop.config.rate, axes=axes)
    try:
        link.start()
        max_age, age_source = _max_age(instrument, axes, max_age)
        base = (np.asarray(baseline, dtype=np.float64).reshape(2) if baseline is not None
                else _baseline(link, int(baseline_samples), first_sample_timeout))
        meta = loop_metadata(metadata, loop)  # the virtual coupling chosen from the device, for the replay
        if meta.get("device") is None:  # the limits the reader bounds the stylus and device force by
            meta["device"] = DeviceConfig.of(device.info, type(device).__name__).to_metadata()
        meta["instrument"] = {
            "name": instrument.name, "signal_units": list(instrument.signal_units), "axes": axes,
            "frame": frame.to_metadata(), "max_age": max_age, "max_age_source": age_source,
            **{k: v for k, v in (("acquisition_period_s", getattr(instrument, "acquisition_period", None)),
                                 ("round_trip_s", getattr(instrument, "round_trip", None)),
                                 ("on_link_loss", getattr(instrument, "on_link_loss", None))) if v is not None},
            "limits": {"low": instrument.limits.low.tolist(), "high": instrument.limits.high.tolist(),
                       "max_speed": instrument.limits.max_speed, "source": instrument.limits.source},
            "signals": list(getattr(instrument, "signal_names", ("deflection", "torsion")))}
        meta["calibration"] = {**dict(metadata.get("calibration") or {}),
                               "vertical_sensitivity": photodiode.vertical_sensitivity,
                               "lateral_sensitivity": photodiode.lateral_sensitivity,
                               "convention": photodiode.convention, "baseline": base.tolist()}
        if not device.is_open:
            device.open()
        return _run(Path(path), meta, device, link, loop, model, frame, photodiode, base, seconds, ticks, max_age,
                    handle_signals, stop, priority)
    finally:
        link.stop()
        if device.is_open:
            device.command_force(np.zeros(3))
            device.close()


def _max_age(instrument, axes: str, max_age):
    """``(max_age s, where it came from)``: the given one, else the instrument's own limit (a
    Nanonis: from its acquisition period Tap and round trip), else 20 ms."""
    if max_age is not None:
        return float(max_age), "given"
    limit = getattr(instrument, "sample_age_limit", None)
    if callable(limit):
        return float(limit(axes)), "instrument (acquisition period and round trip)"
    return DEFAULT_MAX_AGE, "default"


def _run(path, meta, device, link, loop, model, frame, pd, base, seconds, ticks, max_age, handle_signals, stop,
         priority):
    sample = InstrumentSample()
    ang = np.zeros(2)
    cmd = np.zeros(3)
    measured = np.zeros(3)
    sv, sh = pd.vertical_sensitivity, pd.lateral_sensitivity
    v0d, v0t = float(base[0]), float(base[1])
    get, out, mout = LOOP_OUT.get, loop.out, model.out
    probe = out[LOOP_OUT.slice("probe")]
    name = link.instrument.name
    now = device.now
    writer = SessionWriter(path, meta, handle_signals=handle_signals)

    def where() -> str:
        p = sample.position
        return ("at an unknown position" if not np.all(np.isfinite(p))
                else f"at ({p[0] * 1e9:.1f}, {p[1] * 1e9:.1f}, {p[2] * 1e9:.1f}) nm (instrument frame)")

    def step(state, inputs, dt):
        age = link.latest(sample)
        if link.error is not None:
            raise InstrumentLinkLost(f"instrument link lost: {link.error}")
        if age > max_age:
            raise InstrumentLinkLost(f"instrument link stalled: the newest sample from {name} is {age * 1e3:.1f} ms "
                                     f"old (limit {max_age * 1e3:.0f} ms)")
        d, t = sample.signals[0], sample.signals[1]
        if not (math.isfinite(d) and math.isfinite(t)) or not np.all(np.isfinite(sample.position)):
            raise InstrumentLinkLost(f"instrument link unusable: {name} sent a signal or position that is not a "
                                     f"number (signals {d!r}, {t!r})")
        ang[0] = sv * (d - v0d)
        ang[1] = sh * (t - v0t)
        f = loop.step(inputs, now(), signals=ang)
        link.command(frame.to_instrument(probe, out=cmd))
        frame.to_scan(sample.position, out=measured)
        writer.append(t=inputs.timestamp, stylus_position=inputs.position, stylus_velocity=inputs.velocity,
                      buttons=inputs.buttons, probe_position=probe, probe_velocity=get(out, "probe_velocity"),
                      tip_position=get(out, "tip"), energy=get(out, "energy"),
                      passivity_damping=get(out, "passivity_damping"), signals=ang, force=get(out, "probe_force"),
                      device_force=get(out, "device_force"), instrument_position=measured,
                      **contact_fields(model.record(mout)))
        return f

    def on_stop() -> None:  # in the servo thread, in the tick that failed: zero force, no more moves
        link.hold()
        if device.is_open:
            device.command_force(np.zeros(3))

    sched = Scheduler(step, loop, rate=loop.config.rate, source=partial(device.read_state, DeviceState()),
                      sink=device.command_force,
                      on_stop=on_stop, priority=priority)
    failure = None
    with writer:
        try:
            sched.start()
            try:
                end = time.perf_counter() + (seconds if seconds is not None else math.inf)
                while sched.is_running and time.perf_counter() < end and (ticks is None or sched.ticks < ticks) \
                        and (stop is None or not stop.is_set()):
                    time.sleep(2e-3)
            finally:
                stats = sched.stop()
        except LoopError as exc:
            cause = exc.__cause__
            secured = getattr(link.instrument, "loss_action", "")  # a Nanonis withdrew it over a second link
            tip = (f"the tip was last measured {where()}" if secured and "failed" not in secured
                   else f"the tip was left {where()}")
            failure = (str(cause) if isinstance(cause, InstrumentError) else str(exc)) + \
                f"; the hand got zero force and {tip}"
            writer.close(complete=False, reason=failure)
    if failure is not None:
        raise InstrumentLinkLost(f"{failure}; the session {str(path)!r} keeps the {writer.n_ticks} ticks recorded "
                                 "(marked incomplete)")
    rt = link.round_time[:min(link.samples, link.round_time.size)]
    return InstrumentSessionResult(path, writer.n_ticks, stats, link.samples, base,
                                   float(np.median(rt)) if rt.size else math.nan,
                                   float(np.percentile(rt, 99)) if rt.size else math.nan, link.clamped,
                                   link.rate_limited)
