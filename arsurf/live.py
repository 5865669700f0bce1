r"""A live session at the bench: the 1 kHz haptic loop on a haptic device, optionally on an AFM's
measured signals, recorded (what ``arsurf live`` runs).

:func:`run_live` builds the AR model from session metadata (:func:`arsurf.assembly.build_model`,
as replay rebuilds it), maps the stylus origin 2.5 tip radii above the middle of the surface
(:func:`arsurf.haptics.live_loop.bridge_start`) and runs

* without an instrument: :class:`arsurf.haptics.live_loop.LiveLoop` on the device, every tick recorded
  by :func:`arsurf.sessions.writer.record_loop_tick` (the simulated force, as ``arsurf view
  --bridge-port --record``);
* with an instrument: :func:`arsurf.sessions.instrument_session.record_instrument_session` (the
  force the decoupling reads from the instrument's deflection and torsion signals,
  ``source="measured"``; the commanded tip centre sent to the instrument through its
  :class:`~arsurf.instrument.link.InstrumentLink`).

Either way the session replays with ``arsurf replay``, and a fault (the device unplugged, the
instrument link stalled or dead) gives zero force in that tick, closes the device, keeps every
tick recorded (marked incomplete) and is raised as one line that says so.

:func:`open_instrument` makes the instrument of ``--instrument``: ``virtual`` (a
:class:`~arsurf.instrument.instrument.VirtualAFM` whose sample is the scan) or
``nanonis://HOST:PORT`` (:class:`~arsurf.instrument.nanonis.NanonisAFM`, the tip commanded
inside the scanned area and within :data:`Z_MARGIN` of its heights).

:func:`bridge_loop` is the live loop of ``arsurf view --bridge-port``: the UDP bridge device
(real hardware behind a C++ or Python client) driving the model with :data:`~arsurf.assembly.BRIDGE_HAPTICS`.

Examples
--------
>>> parse_instrument("nanonis://192.168.1.10:6501")
('nanonis', '192.168.1.10', 6501)
>>> round(float(press_trajectory(20e-9, 1e-5)(0.3)[2]), 6)   # stylus z (m): the probe 10 nm in at 0.3 s
-0.004
"""
from __future__ import annotations

import contextlib
import math
import tempfile
import time
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np

from arsurf.assembly import BRIDGE_HAPTICS, build_loop, build_model, loop_metadata, preset_metadata
from arsurf.contact.jump_blend import BLEND_TIME
from arsurf.errors import InstrumentError, LoopError

__all__ = ["Z_MARGIN", "LiveResult", "bridge_loop", "live_metadata", "open_instrument", "parse_instrument",
           "press_trajectory", "run_live"]

#: how far (m) above and below the scan's heights the tip may be commanded on a real instrument
Z_MARGIN = 1e-6
#: the virtual hand's script: press in 0.3 s, hold to 1 s, lift by 1.3 s, rest; period 2 s
_PRESS_TIMES = np.array([0.0, 0.3, 1.0, 1.3, 2.0])


@dataclass(frozen=True)
class LiveResult:
    """What a live session did: servo ticks run, their rate (Hz), the session file (None: not
    recorded) and, with an instrument, the samples its link read."""

    ticks: int
    rate: float
    path: Path | None
    instrument_samples: int | None = None


def parse_instrument(spec: str) -> tuple:
    """``"virtual"`` -> ``("virtual",)``; ``"nanonis://HOST:PORT"`` -> ``("nanonis", HOST, PORT)``."""
    if spec == "virtual":
        return ("virtual",)
    how = "give --instrument virtual or --instrument nanonis://HOST:PORT (the TCP programming interface, 6501-6504)"
    if not isinstance(spec, str) or not spec.startswith("nanonis://"):
        raise InstrumentError(f"unknown instrument {spec!r}; {how}")
    host, sep, port = spec[len("nanonis://"):].rpartition(":")
    host = host.strip("[]")  # an IPv6 address in brackets
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise InstrumentError(f"instrument {spec!r} is not nanonis://HOST:PORT with a port in 1..65535; {how}")
    return ("nanonis", host, int(port))


def live_metadata(scan, *, tip_radius: float, level: str, sigma: float, scale: float, measured: bool,
                  virtual_coupling: bool = True, passivity: bool = True, jump_blend: float = BLEND_TIME,
                  zone_energy: bool = False, zone_closed_form: bool = True) -> dict:
    """Session metadata of a live session: the viewer preset (Si tip on polystyrene) with the
    bridge loop's haptic settings (:data:`arsurf.assembly.BRIDGE_HAPTICS`) at ``scale`` probe m
    per stylus m; ``measured``: the force read from the instrument's signals. The virtual
    coupling, the passivity controller and the blend of the tip's jumps (``jump_blend`` s,
    :mod:`arsurf.contact.jump_blend`) are on unless turned off here (recorded either way;
    the coupling's stiffness is the one the loop chooses from the device,
    :func:`arsurf.assembly.loop_metadata`). ``zone_energy``: the model's contact the energy of the
    whole tip (:class:`~arsurf.model.ARModel`), ``zone_closed_form`` in closed form where trusted."""
    haptics = dict(BRIDGE_HAPTICS, scale=scale, source="measured" if measured else "simulated",
                   virtual_coupling=bool(virtual_coupling), passivity=bool(passivity), jump_blend=float(jump_blend))
    return preset_metadata(scan, "viewer", tip_radius=tip_radius, level=level, sigma=sigma, haptics=haptics,
                           zone_energy=bool(zone_energy), zone_closed_form=bool(zone_closed_form))


def bridge_loop(model, haptics=None, *, host: str = "127.0.0.1", port: int = 47474, key: bytes | None = None,
                peer_timeout: float | None = None, start=None, record=None, priority: int = 0):
    """A :class:`~arsurf.haptics.live_loop.LiveLoop` for real hardware: the UDP bridge device on
    ``host``:``port`` with the session ``key`` (a fresh one on loopback if None; see
    :class:`~arsurf.haptics.udp_bridge.UdpBridgeDevice`) driving the
    AR ``model`` through :func:`arsurf.assembly.build_loop` with ``haptics`` (default
    :data:`~arsurf.assembly.BRIDGE_HAPTICS`). The stylus origin maps to ``start`` (default
    :func:`~arsurf.haptics.live_loop.bridge_start`). ``record(loop, t, state)``: see the
    LiveLoop. ``priority``: ``SCHED_FIFO`` priority of the loop thread where the OS grants it (0:
    the ordinary policy); it keeps the loop's rate when other local processes - a flood of the
    bridge port among them - compete for the CPU (docs/bridge-safety.rst). Nothing is opened here:
    :meth:`LiveLoop.start <arsurf.haptics.live_loop.LiveLoop.start>` (or ``live.device.open()``)
    binds the port.

    Build the model with :func:`arsurf.assembly.build_model` from session metadata (what
    ``arsurf view --bridge-port`` does) and a recorded session replays bit for bit."""
    from arsurf.haptics.live_loop import LiveLoop, bridge_start
    from arsurf.haptics.udp_bridge import UdpBridgeDevice

    if start is None:
        start = bridge_start(model.surface, model.tip_radius)
    device = UdpBridgeDevice(host, port, key=key, peer_timeout=peer_timeout)
    loop = build_loop(model, BRIDGE_HAPTICS if haptics is None else haptics, device.info, start)
    return LiveLoop(loop, device, record=record, priority=priority)


def press_trajectory(tip_radius: float, scale: float, indent: float = 10e-9):
    """The virtual hand's set point ``t -> (3,)`` m (device frame): down until the probe, which
    starts 2.5 tip radii above the surface, is ``indent`` into it, held, lifted; every 2 s."""
    depth = -(1.5 * tip_radius + indent) / scale
    z = np.array([0.0, depth, depth, 0.0, 0.0])
    out = np.zeros(3)

    def trajectory(t: float) -> np.ndarray:
        out[2] = np.interp(t % _PRESS_TIMES[-1], _PRESS_TIMES, z)
        return out

    return trajectory


def open_instrument(spec: str, setup, probe_origin, *, deflection_sensitivity: float | None = None,
                    max_speed: float = 10e-6, origin=(0.0, 0.0, 0.0), **nanonis_options):
    """The instrument of ``spec`` (:func:`parse_instrument`), its photodiode and its frame.

    Parameters
    ----------
    spec : str
    setup : ModelSetup
        The model the session runs (its scan, lever and tip radius).
    probe_origin : (3,) float, m
        Tip-sphere centre (scan frame) at the stylus origin: where the virtual AFM's tip starts.
    nanonis_options
        :class:`~arsurf.instrument.nanonis.NanonisAFM` keywords (``acquisition_period``,
        ``on_link_loss``); a virtual instrument has no link and ignores them.
    deflection_sensitivity : float, m per signal unit
        Of the lever on the instrument (required for Nanonis: from its calibration); the virtual
        AFM's default is [Alabdulmuhsin]'s 1117 nm per unit.
    max_speed : float, m/s
        Largest speed a commanded move may have (Nanonis; the virtual AFM has its stages').
    origin : (3,) float, m
        Where the scan frame's origin is in the instrument frame (Nanonis).

    Returns
    -------
    (Instrument, Photodiode, InstrumentFrame)
        Not opened (the link opens it), except the virtual AFM, opened with its tip at the origin.
    """
    from arsurf.force.cantilever import Cantilever
    from arsurf.force.photodiode import Photodiode
    from arsurf.instrument.interface import InstrumentFrame, InstrumentLimits

    kind = parse_instrument(spec)
    lever = Cantilever(**setup.config.cantilever.arguments(drop_none=True))
    R = setup.model.tip_radius
    frame = InstrumentFrame(origin=np.asarray(origin, dtype=np.float64) + (0.0, 0.0, -R))
    if deflection_sensitivity is not None and not (math.isfinite(deflection_sensitivity)
                                                   and deflection_sensitivity != 0.0):
        raise InstrumentError(f"the deflection sensitivity must be a finite non-zero length per signal unit (got "
                              f"{deflection_sensitivity!r} m)")
    if kind[0] == "virtual":
        from arsurf.instrument.instrument import VirtualAFM

        if any(origin):
            raise InstrumentError("the virtual AFM's sample is the scan itself, in the scan frame: an instrument "
                                  "origin is for a real instrument")
        apex = frame.to_instrument(np.asarray(probe_origin, dtype=np.float64))
        kw = {} if deflection_sensitivity is None else {"deflection_sensitivity": deflection_sensitivity}
        afm = VirtualAFM(setup.scan, probe_height=float(apex[2]) + Z_MARGIN, tip_xy=apex[:2],
                         spring_constant=lever.normal_stiffness, keep_history=False, **kw).open()
        afm.move_to(apex)
        # calibrated as the virtual lever is: its torsion signal is S_l newtons per unit, a twist of c S_l
        twist = lever.torsion_compliance * afm.lateral_sensitivity  # rad per unit of the torsion signal
        pd = Photodiode.from_deflection_sensitivity(afm.deflection_sensitivity, lever.length, lateral_sensitivity=twist)
        return afm, pd, frame
    from arsurf.instrument.nanonis import NanonisAFM

    if deflection_sensitivity is None:
        raise InstrumentError("a Nanonis session needs the lever's deflection sensitivity (nm of deflection per "
                              "volt of the deflection input, from its calibration): give --deflection-sensitivity-nm")
    scan = setup.scan
    finite = scan.heights[np.isfinite(scan.heights)]
    corners = frame.to_instrument(np.array([[0.0, 0.0, finite.min() + R - Z_MARGIN],
                                            [(scan.shape[1] - 1) * scan.dx, (scan.shape[0] - 1) * scan.dy,
                                             finite.max() + R + Z_MARGIN]]))
    limits = InstrumentLimits(corners.min(0), corners.max(0), max_speed,
                              f"the scanned area, within {Z_MARGIN * 1e6:g} um of its heights")
    afm = NanonisAFM(kind[1], kind[2], limits=limits, **nanonis_options)
    return afm, Photodiode.from_deflection_sensitivity(deflection_sensitivity, lever.length), frame


def _device_metadata(device, backend: str) -> dict:
    """The ``device`` record of the session (:class:`~arsurf.config.DeviceConfig`)."""
    from arsurf.config import DeviceConfig

    record = getattr(device, "safety_record", None)  # a hardware adapter: its watchdog, limits' sources
    return DeviceConfig.of(device.info, backend, **(record() if callable(record) else {})).to_metadata()


def run_live(metadata, device, *, backend: str = "", instrument=None, photodiode=None, frame=None,
             axes: str = "xyz", max_age: float | None = None, record=None, seconds: float | None = None, stop=None,
             setup=None, priority: int = 0, **safety_kwargs) -> LiveResult:
    """Run the live loop on ``device`` until ``seconds`` pass, ``stop`` is set or a fault stops it.

    Parameters
    ----------
    metadata : dict
        Session metadata (:func:`live_metadata`); its haptics source is ``"measured"`` with an
        instrument.
    device : Device
        Opened here if it is not (and closed at the end, whatever happens).
    backend : str
        The device's backend name, recorded in the metadata.
    instrument, photodiode, frame : optional
        :func:`open_instrument`'s; ``axes`` and ``max_age`` (s) as in
        :func:`~arsurf.sessions.instrument_session.record_instrument_session`.
    record : path-like, optional
        The session file (must not exist); without one nothing is kept (an instrument session
        is written to a temporary file, deleted at the end).
    seconds : float, optional
        Wall time; None: until ``stop`` (a :class:`threading.Event`) is set.
    setup : ModelSetup, optional
        ``build_model(metadata)``, if already built.
    priority : int
        ``SCHED_FIFO`` priority of the loop thread where the OS grants it (0: the ordinary policy;
        :class:`~arsurf.haptics.scheduler.Scheduler`).
    **safety_kwargs
        For the loop's safety layer.

    Raises
    ------
    LoopError
        The device failed mid-session (one line; the hand got zero force, the session keeps
        its ticks, marked incomplete).
    InstrumentLinkLost
        The instrument link stalled or died (likewise; the tip was left where it was).
    """
    from arsurf.haptics.live_loop import bridge_start

    if setup is None:
        setup = build_model(metadata)
    origin = bridge_start(setup.surface, setup.model.tip_radius)
    try:
        if not device.is_open:
            device.open()
        meta = dict(metadata, device=_device_metadata(device, backend or type(device).__name__))
        if instrument is not None:
            return _instrument_run(meta, device, setup, origin, instrument, photodiode, frame, axes, max_age, record,
                                   seconds, stop, priority, safety_kwargs)
        return _device_run(meta, device, setup, origin, record, seconds, stop, safety_kwargs, priority)
    finally:
        if device.is_open:
            device.close()


def _instrument_run(meta, device, setup, origin, instrument, photodiode, frame, axes, max_age, record, seconds,
                    stop, priority, safety_kwargs) -> LiveResult:
    from arsurf.sessions.instrument_session import record_instrument_session

    with contextlib.ExitStack() as stack:
        path = record
        if path is None:
            path = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="arsurf-live-"))) / "session.h5"
        r = record_instrument_session(path, meta, device, instrument, photodiode=photodiode, seconds=seconds,
                                      stop=stop, probe_origin=origin, frame=frame, axes=axes, max_age=max_age,
                                      setup=setup, priority=priority, **safety_kwargs)
    return LiveResult(r.ticks, r.stats.rate, None if record is None else Path(record), r.instrument_samples)


def _device_run(meta, device, setup, origin, record, seconds, stop, safety_kwargs, priority) -> LiveResult:
    from arsurf.haptics.live_loop import LiveLoop
    from arsurf.sessions.writer import SessionWriter, record_loop_tick

    loop = build_loop(setup.model, setup.config.haptics, device.info, origin, scene=setup.scene, **safety_kwargs)
    meta = loop_metadata(meta, loop)  # the virtual coupling chosen from the device, for the replay
    live = LiveLoop(loop, device, priority=priority)
    writer = contextlib.nullcontext()
    if record is not None:
        writer = SessionWriter(record, meta)
        live.record = partial(record_loop_tick, writer)
    failure = None
    with writer:
        live.start()
        try:
            end = time.perf_counter() + (math.inf if seconds is None else seconds)
            while live.scheduler.is_running and time.perf_counter() < end and (stop is None or not stop.is_set()):
                time.sleep(0.005)
        finally:
            try:
                stats = live.stop()
            except LoopError as exc:
                cause = exc.__cause__ if exc.__cause__ is not None else exc
                failure = f"{cause}; the hand got zero force and the device was closed"
                if record is not None:
                    writer.close(complete=False, reason=failure)
    if failure is not None:
        kept = (f"; the session {str(record)!r} keeps the {writer.n_ticks} ticks recorded (marked incomplete)"
                if record is not None else "")
        raise LoopError(failure + kept) from None
    return LiveResult(stats.ticks, stats.rate, None if record is None else Path(record))
