"""``arsurf live``: the haptic loop on a device (and an instrument) at the bench, recorded (:mod:`arsurf.live`)."""
from __future__ import annotations

import argparse
import sys

from arsurf.cli.args import (_contact_flag, _contact_options, _count, _nm, _positive, _processing_flags,
                              _protection_flags, _protections, _record_target)

#: ``arsurf live`` device flags: (argparse dest, flag, the adapters' option, SI factor or None)
_DEVICE_FLAGS = (
    ("max_force_n", "--max-force-n", "max_force", 1.0),
    ("workspace_mm", "--workspace-mm", "workspace", 1e-3),
    ("serial_port", "--serial-port", "port", None),
    ("handle_port", "--handle-port", "handle_port", None),
    ("device_index", "--device-index", "index", None),
    ("device_name", "--device-name", "name", None),
    ("calibrate", "--calibrate", "calibrate", None),
    ("allow_no_watchdog", "--allow-no-watchdog", "allow_no_watchdog", None),
)


def _priority(text: str) -> int:
    """An argparse type: a real-time priority, an integer in [0, 99] (0: none)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer in [0, 99] (got {text!r})") from None
    if not 0 <= value <= 99:
        raise argparse.ArgumentTypeError(f"must be an integer in [0, 99] (got {text}); 0: the ordinary policy")
    return value


#: devices whose driver answers from a thread of this process: a real-time loop thread would delay
#: it on a busy core (the simulated Haply went unanswered for 0.4 s), so they, and an instrument
#: (read by its link thread), keep the ordinary policy unless --realtime-priority N asks
_DEVICE_THREADS = ("haply", "openhaptics")


def _realtime_flags(s, what: str) -> None:
    """``--realtime-priority N`` / ``--no-realtime-priority`` (dest ``realtime_priority``: None
    is the default choice, :func:`arsurf.haptics.scheduler.choose_realtime`)."""
    s.add_argument("--realtime-priority", type=_priority, default=None, metavar="N",
                   help=f"run {what} under SCHED_FIFO at priority N (1-99) where the OS allows it (root, "
                        "CAP_SYS_NICE or an rtprio limit). Default: SCHED_FIFO priority 10 where allowed, else the "
                        "ordinary policy (what was chosen, and why, is printed and recorded in the session); "
                        "haply, openhaptics and --instrument keep the ordinary policy unless asked (docs/bridge-safety.rst)")
    s.add_argument("--no-realtime-priority", dest="realtime_priority", action="store_const", const=0,
                   help=f"run {what} under the ordinary policy (recorded in the session)")


def register(sub) -> None:
    from arsurf.haptics.backends import DEVICES

    s = sub.add_parser("live", help="run the 1 kHz haptic loop on a haptic device (virtual or real), optionally "
                       "driving an AFM on its measured signals; record it with --record")
    s.add_argument("scan", nargs="?", default=None, help="scan file (default: the bundled nanotubes)")
    s.add_argument("--device", default="virtual", metavar="NAME",
                   help=f"haptic device: {' | '.join(DEVICES)} (default virtual: a scripted hand presses the "
                        "stylus into the surface every 2 s; `arsurf devices` lists what is connected)")
    g = s.add_argument_group("device options (each adapter takes some; see docs/devices.rst)")
    g.add_argument("--max-force-n", type=_positive("N"), help="force limit in N, at most the device's own (default 1 N, "
                   "the first-connection limit, or the device's if lower)")
    g.add_argument("--workspace-mm", type=_positive("mm"), nargs=3, metavar=("X", "Y", "Z"),
                   help="workspace extents in mm (required for haply; forcedimension: a model the SDK does not "
                        "describe)")
    g.add_argument("--serial-port", metavar="PATH",
                   help="haply: the Inverse3's serial port (default: the first found)")
    g.add_argument("--handle-port", metavar="PATH", help="haply: the handle's serial port, or auto")
    g.add_argument("--device-index", type=_count, help="forcedimension: which connected device (default the first)")
    g.add_argument("--device-name", help="openhaptics: the device's configured name (default 'Default Device')")
    g.add_argument("--calibrate", action="store_true", help="forcedimension: let an uncalibrated device calibrate "
                   "itself (it moves by itself: hands off, workspace clear)")
    g.add_argument("--allow-no-watchdog", action="store_true", help="forcedimension: run even if the device's "
                   "firmware watchdog cannot be set (a stalled loop then keeps its last force; recorded in the session)")
    s.add_argument("--tip-radius-nm", type=_nm(strict=True), default=20.0, help="tip radius in nm (default 20)")
    _processing_flags(s)
    s.add_argument("--scale", type=_positive("probe m per stylus m"), default=1e-5,
                   help="probe metres per stylus metre (default 1e-5: 1 mm -> 10 nm)")
    s.add_argument("--seconds", type=_positive("seconds"), help="run this long (default: until Ctrl-C)")
    _realtime_flags(s, "the loop thread")
    s.add_argument("--record", metavar="FILE", help="record the session to FILE (.h5, must not exist), replayable "
                   "with `arsurf replay FILE --scan SCAN`")
    _protection_flags(s)
    _contact_flag(s)
    g = s.add_argument_group("instrument (the force read from its deflection and torsion signals)")
    g.add_argument("--instrument", metavar="SPEC", help="virtual (a virtual AFM whose sample is the scan) or "
                   "nanonis://HOST:PORT (the Nanonis TCP programming interface)")
    g.add_argument("--deflection-sensitivity-nm", type=float, metavar="NM",
                   help="lever deflection in nm per unit of the deflection signal (nm/V; required for nanonis; "
                        "virtual: 1117)")
    g.add_argument("--instrument-origin-nm", type=float, nargs=3, metavar=("X", "Y", "Z"),
                   help="nanonis: where the scan's origin is in the instrument's X, Y, Z (default 0 0 0)")
    g.add_argument("--max-speed-um-s", type=_positive("um/s"), default=10.0,
                   help="nanonis: largest speed of a commanded tip move in um/s (default 10)")
    g.add_argument("--instrument-axes", choices=("xyz", "xy"), default="xyz",
                   help="xyz: the stylus commands X, Y and Z (the Z feedback must be off); xy: the feedback holds Z")
    g.add_argument("--max-age-ms", type=_positive("ms"), default=None,
                   help="oldest instrument sample a force is rendered from, ms (default: nanonis derives it from "
                        "its acquisition period Tap and round trip; virtual 20); older: zero force, stop")
    g.add_argument("--acq-period-ms", type=_positive("ms"), default=None,
                   help="nanonis: set the TCP receiver's acquisition period Tap at open (default: keep the "
                        "controller's; it is read and recorded either way)")
    g.add_argument("--on-link-loss", choices=("withdraw", "feedback", "hold"), default="withdraw",
                   help="nanonis: what to do to the tip when the link is lost (default withdraw, over a second "
                        "connection; feedback: Z controller on; hold: leave it)")
    s.set_defaults(func=cmd_live)


def _live_device(args):
    """The device of ``--device`` and its flags (a flag the device does not take is refused)."""
    from arsurf.errors import HapticsError
    from arsurf.haptics.backends import device_options, make_device

    takes = device_options(args.device)
    options = {}
    for dest, flag, option, factor in _DEVICE_FLAGS:
        value = getattr(args, dest)
        if value is None or value is False:
            continue
        if option not in takes:
            fit = [f for _, f, o, _ in _DEVICE_FLAGS if o in takes]
            raise HapticsError(f"{flag} is not an option of --device {args.device} (it takes {', '.join(fit)})")
        options[option] = [v * factor for v in value] if isinstance(value, list) else \
            value * factor if factor is not None else value
    if args.device == "virtual":
        from arsurf.haptics.virtual_device import HandModel
        from arsurf.live import press_trajectory

        options["hand"] = HandModel(press_trajectory(args.tip_radius_nm * 1e-9, args.scale))
    return make_device(args.device, **options)


def _live_instrument_flags(args) -> None:
    """Refuse instrument flags without ``--instrument`` (one line)."""
    from arsurf.errors import InstrumentError

    if args.instrument is None:
        given = [f for f, v in (("--deflection-sensitivity-nm", args.deflection_sensitivity_nm),
                                ("--instrument-origin-nm", args.instrument_origin_nm)) if v is not None]
        if given:
            raise InstrumentError(f"{', '.join(given)} set up an instrument; give --instrument virtual or "
                                  "--instrument nanonis://HOST:PORT too")


def cmd_live(args) -> int:
    """``arsurf live``: the loop on a device (and an instrument) for ``--seconds`` or until Ctrl-C
    (which ends the session normally; a second Ctrl-C aborts it, the recording kept, incomplete)."""
    import signal
    import threading

    from arsurf.assembly import BUNDLED_SCAN, build_model
    from arsurf.live import live_metadata, open_instrument, parse_instrument, run_live

    record = _record_target(args)
    _live_instrument_flags(args)
    if args.instrument is not None:
        parse_instrument(args.instrument)  # a bad URL is refused before anything slow
    device = _live_device(args)
    scan_path = args.scan or str(BUNDLED_SCAN)
    meta = live_metadata(scan_path, tip_radius=args.tip_radius_nm * 1e-9, level=args.level,
                         sigma=args.sigma_nm * 1e-9, scale=args.scale, measured=args.instrument is not None,
                         **_contact_options(args), **_protections(args))
    setup = build_model(meta)
    instrument = photodiode = frame = None
    if args.instrument is not None:
        from arsurf.haptics.live_loop import bridge_start

        sens = args.deflection_sensitivity_nm
        instrument, photodiode, frame = open_instrument(
            args.instrument, setup, bridge_start(setup.surface, setup.model.tip_radius),
            deflection_sensitivity=None if sens is None else sens * 1e-9, max_speed=args.max_speed_um_s * 1e-6,
            origin=[v * 1e-9 for v in (args.instrument_origin_nm or (0.0, 0.0, 0.0))],
            acquisition_period=None if args.acq_period_ms is None else args.acq_period_ms * 1e-3,
            on_link_loss=args.on_link_loss)
    from arsurf.haptics.scheduler import choose_realtime

    realtime = choose_realtime(args.realtime_priority,
                               device_thread=args.device in _DEVICE_THREADS or args.instrument is not None)
    meta["realtime"] = realtime.to_metadata()
    stop = threading.Event()

    def on_signal(signum, frame_):
        if stop.is_set():
            raise KeyboardInterrupt
        stop.set()
        print("arsurf live: stopping (Ctrl-C again aborts)", file=sys.stderr)

    main_thread = threading.current_thread() is threading.main_thread()
    old = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)} if main_thread else {}
    try:
        device.open()  # a missing vendor package or device is reported here, before anything is recorded
        print(f"arsurf live: haptic loop at 1 kHz on {device.info.name}"
              + (f" with {args.instrument} (measured force)" if args.instrument else "")
              + (f" for {args.seconds:g} s" if args.seconds else " until Ctrl-C")
              + (f"; recording to {record}" if record else ""), file=sys.stderr)
        print(f"arsurf live: {realtime.describe()}", file=sys.stderr)
        result = run_live(meta, device, backend=args.device, instrument=instrument, photodiode=photodiode,
                          frame=frame, axes=args.instrument_axes, max_age=None if args.max_age_ms is None else args.max_age_ms * 1e-3, record=record,
                          seconds=args.seconds, stop=stop, setup=setup, priority=realtime.priority)
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)
        if device.is_open:  # run_live closes it; not if it never ran
            device.close()
        if instrument is not None and instrument.is_open:  # the virtual AFM was opened to place its tip
            instrument.close()
    print(f"arsurf live: loop stopped after {result.ticks} ticks at {result.rate:.0f} Hz"
          + (f"; {result.instrument_samples} instrument samples" if result.instrument_samples is not None else ""),
          file=sys.stderr)
    if record is not None:
        print(f"session recorded: {record} ({result.ticks} ticks; replay it with "
              f"arsurf replay {record} --scan {scan_path} --out DIR)")
    return 0
