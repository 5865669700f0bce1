"""``arsurf view``: the 3D view of a scan, or of the live haptic loop on the UDP bridge (``--bridge-port``).

The one command group of the CLI that opens a view: it imports :mod:`arsurf_viewer` (pyvista)
inside the functions that draw, so ``arsurf live`` and the other commands never need it.
"""
from __future__ import annotations

import sys
import time

from arsurf.cli.args import (_contact_flag, _contact_options, _count, _nm, _picture_size, _positive, _prepare,
                              _processing_flags, _protection_flags, _protections, _record_target)
from arsurf.cli.live import _realtime_flags

#: frames of the scripted offscreen path (approach, indent, slide, retract: one at least each);
#: the same bound as :func:`arsurf_viewer.interactive.scripted_path`, which this module must not import
MIN_SCRIPTED_FRAMES = 4


def register(sub) -> None:
    """Add ``arsurf view`` to the subcommands ``sub``."""
    s = sub.add_parser("view", help="open the interactive 3D viewer (offscreen PNG without a display)")
    s.add_argument("scan", nargs="?", default=None, help="scan file (default: the bundled nanotubes)")
    s.add_argument("--tip-radius-nm", type=_nm(strict=True), default=20.0, help="tip radius in nm (default 20)")
    _processing_flags(s)
    s.add_argument("--bridge-port", type=int, default=None,
                   help="run the full haptic loop against a device on the UDP bridge at 127.0.0.1:PORT "
                        "(authenticated poses in, forces out; protocol in docs/bridge-protocol.rst; "
                        "`python -m arsurf.haptics.client` is a reference client)")
    s.add_argument("--host", "--bridge-host", dest="bridge_host", default=None, metavar="ADDRESS",
                   help="address the bridge listens on (default 127.0.0.1: this machine only); any other address "
                        "needs --bridge-key-file or --bridge-key")
    s.add_argument("--bridge-key-file", metavar="PATH",
                   help="the bridge's session key (hex, owner-only file): read if PATH exists, else a new key is "
                        "written there with mode 600 (default: a new key in a private temporary file, path printed)")
    s.add_argument("--bridge-key", metavar="HEX", help="the session key as hex (other users can see it in the "
                   "process list: prefer --bridge-key-file)")
    s.add_argument("--bridge-peer-timeout", type=_positive("seconds"), default=None, metavar="S",
                   help="let another client take over after the pinned one has been silent S seconds "
                        "(default: never during the session; the client's RELEASE always does)")
    _realtime_flags(s, "the haptic loop thread of --bridge-port")
    s.add_argument("--scale", type=float, default=1e-5, help="probe metres per stylus metre with --bridge-port")
    _protection_flags(s)
    _contact_flag(s)
    s.add_argument("--record", metavar="FILE", help="with --bridge-port: record the haptic loop's session to FILE "
                   "(.h5, must not exist), replayable with `arsurf replay FILE --scan SCAN`")
    s.add_argument("--tubes", action="store_true",
                   help="make the nanotubes of a synthetic scan live objects the tip can push (not with --bridge-port)")
    s.add_argument("--out", default="out/view", help="without a display: folder of the offscreen PNG frames "
                   "(default out/view)")
    s.add_argument("--size", type=_picture_size, default=(960, 720), metavar="WxH",
                   help="picture size in pixels (default 960x720; e.g. 2100x1500 prints 7 x 5 in at 300 dpi); the "
                        "saved frames leave the HUD out and state the scale bar and the vertical exaggeration")
    s.add_argument("--frames", type=_count, default=90, help=f"without a display: how many frames (default 90, at "
                   f"least {MIN_SCRIPTED_FRAMES}); with --bridge-port any number, 0: no view at all, the loop serves "
                   "the client until it sends RELEASE")
    s.add_argument("--material", action="store_true", help="colour the surface by the file's mechanical channels "
                   "(key c cycles the colourings); uncalibrated channels need the conversion flags below")
    s.add_argument("--color-by", default=None, choices=("height", "deformation", "modulus", "adhesion",
                                                        "sample_deformation", "dissipation"),
                   help="the surface's colouring (default height; the last four need --material)")
    from arsurf.contact.material_conversion import MaterialConversion

    MaterialConversion.cli_arguments(s, tip_radius_nm=None)
    s.set_defaults(func=cmd_view)


def _bridge_setup(args):
    """Host, session key and key file of ``arsurf view --bridge-port`` (None without it).

    Refuses (one line) a non-loopback ``--host`` without a key given by the operator. Without a
    key, a fresh one is written to a private temporary file (mode 600 in a 700 folder) whose path
    is printed; the caller deletes the folder when the loop stops. The key itself is never printed.
    """
    import os
    import tempfile
    from types import SimpleNamespace

    from arsurf.errors import HapticsError
    from arsurf.haptics.udp_bridge import generate_key, is_loopback, key_from_hex, load_key, save_key

    if args.bridge_port is None:
        given = [f for f, v in (("--host", args.bridge_host), ("--bridge-key", args.bridge_key),
                                ("--bridge-key-file", args.bridge_key_file),
                                ("--bridge-peer-timeout", args.bridge_peer_timeout), ("--record", args.record),
                                ("--realtime-priority" if args.realtime_priority else "--no-realtime-priority",
                                 args.realtime_priority))
                 if v is not None]
        given += [f for f, on in (("--no-virtual-coupling", args.virtual_coupling), ("--no-passivity", args.passivity),
                                  ("--no-jump-blend", args.jump_blend)) if not on]
        if given:
            raise HapticsError(f"{', '.join(given)} set up the UDP bridge's haptic loop; give --bridge-port PORT too")
        if args.frames < MIN_SCRIPTED_FRAMES:
            raise HapticsError(f"--frames {args.frames}: at least {MIN_SCRIPTED_FRAMES} without --bridge-port (the "
                               "offscreen path approaches, indents, slides and retracts); 0 (no view) is only for a "
                               "--bridge-port loop")
        return None
    if args.tubes:
        raise HapticsError("--tubes is not available with --bridge-port yet (the bridge loop has no tube scene); "
                           "leave out one of them")
    if args.material or args.color_by is not None:
        raise HapticsError("--material/--color-by are not available with --bridge-port yet (the bridge session's "
                           "model is rebuilt from its metadata, which has no material map); leave out one of them")
    host = args.bridge_host or "127.0.0.1"
    if args.bridge_key is not None and args.bridge_key_file is not None:
        raise HapticsError("give the bridge key once: --bridge-key HEX or --bridge-key-file PATH, not both")
    if not is_loopback(host) and args.bridge_key is None and args.bridge_key_file is None:
        raise HapticsError(f"--host {host} is not loopback: a client on the network is accepted only with a key you "
                           "give (--bridge-key-file PATH; a new key is written there if PATH does not exist)")
    tmpdir = None
    if args.bridge_key is not None:
        key, path = key_from_hex(args.bridge_key), None
    elif args.bridge_key_file is not None and os.path.exists(args.bridge_key_file):
        key, path = load_key(args.bridge_key_file), args.bridge_key_file
    else:
        key = generate_key()
        if args.bridge_key_file is not None:
            path = save_key(args.bridge_key_file, key)
        else:
            tmpdir = tempfile.mkdtemp(prefix="arsurf-bridge-")  # mode 700
            path = save_key(os.path.join(tmpdir, "bridge.key"), key)
        print(f"arsurf view: new bridge session key written to {path} (owner-only); give the client "
              f"--key-file {path}", file=sys.stderr)
    return SimpleNamespace(host=host, port=args.bridge_port, key=key, key_file=path, tmpdir=tmpdir,
                           peer_timeout=args.bridge_peer_timeout)


def cmd_view(args) -> int:
    record = _record_target(args)
    bridge = _bridge_setup(args)  # refuse a bad bridge setup before anything slow
    try:
        return _view(args, bridge, record)
    finally:
        if bridge is not None and bridge.tmpdir is not None:
            import shutil

            shutil.rmtree(bridge.tmpdir, ignore_errors=True)


def _view(args, bridge, record) -> int:
    from arsurf.errors import require

    if bridge is not None:
        return _bridge_view(args, bridge, record)
    require("pyvista", "viewer", "arsurf view")
    from arsurf.assembly import BUNDLED_SCAN
    from arsurf_viewer import view_scan

    tip_radius = args.tip_radius_nm * 1e-9
    path = args.scan or str(BUNDLED_SCAN)
    scan = _prepare(args, path)
    colour = {}
    if args.material:
        from arsurf.contact.material_conversion import MaterialConversion
        from arsurf.contact.material_map import material_map_from_file

        colour["material"] = material_map_from_file(path, MaterialConversion.from_cli(args), height=scan,
                                                    channels=MaterialConversion.cli_channels(args))
    if args.color_by is not None:
        colour["color_by"] = args.color_by
    view_scan(scan, tip_radius=tip_radius, level_method=None, sigma=None, tubes=args.tubes, out_dir=args.out,
              frames=args.frames, window_size=tuple(args.size), **colour)
    return 0


def _bridge_view(args, bridge, record) -> int:
    """Real hardware: the full haptic loop at 1 kHz against the UDP bridge, the view following it,
    the session recorded with ``--record``.

    The model is built from session metadata by :func:`arsurf.assembly.build_model` (as replay
    rebuilds it) and every tick is recorded by :func:`arsurf.sessions.writer.record_loop_tick`
    (as in ``arsurf demo``), so ``arsurf replay FILE`` gives back the forces bit for bit. With a
    display the loop runs until the window closes; without one (or with ``--frames 0``) it waits
    for a client, renders the frames while it plays, and serves it until it sends RELEASE (or
    falls silent for ``--bridge-peer-timeout``); Ctrl-C stops it (the recording is kept, marked
    incomplete)."""
    import contextlib
    from functools import partial

    from arsurf.assembly import BRIDGE_HAPTICS, BUNDLED_SCAN, build_model, loop_metadata, preset_metadata
    from arsurf.config import DeviceConfig
    from arsurf.errors import require
    from arsurf.haptics.scheduler import choose_realtime
    from arsurf.haptics.udp_bridge import VERSION
    from arsurf.live import bridge_loop
    from arsurf.sessions.writer import SessionWriter, record_loop_tick
    from arsurf_viewer.backend import has_display

    show = args.frames > 0
    if show:
        require("pyvista", "viewer", "arsurf view")
    scan_path = args.scan or str(BUNDLED_SCAN)
    meta = preset_metadata(scan_path, "viewer", tip_radius=args.tip_radius_nm * 1e-9, level=args.level,
                           sigma=args.sigma_nm * 1e-9, haptics={**BRIDGE_HAPTICS, "scale": args.scale, "virtual_coupling": True,
                                                                  "passivity": True, **_protections(args)},
                           **_contact_options(args))
    setup = build_model(meta)
    realtime = choose_realtime(args.realtime_priority)
    meta["realtime"] = realtime.to_metadata()
    live = bridge_loop(setup.model, setup.config.haptics, host=bridge.host, port=bridge.port, key=bridge.key,
                       peer_timeout=bridge.peer_timeout, priority=realtime.priority)
    dev = live.device
    try:
        dev.open()  # a busy port fails here, before a recording starts
        host, port = dev.address
        writer = contextlib.nullcontext()
        if record is not None:  # the key is never recorded; where the client came in is
            meta = dict(meta, device=DeviceConfig.of(dev.info, "udp-bridge", protocol_version=VERSION, host=host,
                                                     port=port).to_metadata())
            meta = loop_metadata(meta, live.loop)  # the virtual coupling chosen from the device, for the replay
            writer = SessionWriter(record, meta, handle_signals=True)
            live.record = partial(record_loop_tick, writer)
        with writer:
            live.start()
            print(f"arsurf view: haptic loop running at 1 kHz, listening for authenticated stylus poses on UDP "
                  f"{host}:{port} (`python -m arsurf.haptics.client` and examples/cpp are clients)"
                  + (f"; recording to {record}" if record else ""), file=sys.stderr)
            print(f"arsurf view: {realtime.describe()}", file=sys.stderr)
            try:
                if show and has_display():
                    from arsurf_viewer.interactive import run_interactive
                    from arsurf_viewer.live import live_scene

                    run_interactive(setup.surface, tip_radius=setup.model.tip_radius, physics=partial(live_scene, live),
                                    pose_source=live.pose, out_dir=args.out, frames=args.frames,
                                    window_size=tuple(args.size))
                else:
                    _serve_headless(args, live, setup)
            finally:
                stats = live.stop()
                print(f"arsurf view: loop stopped after {stats.ticks} ticks at {stats.rate:.0f} Hz"
                      + (f" (SCHED_FIFO priority {stats.realtime_priority})" if stats.realtime_priority else ""),
                      file=sys.stderr)
    finally:
        dev.close()
    if record is not None:
        print(f"session recorded: {record} ({writer.n_ticks} ticks; replay it with "
              f"arsurf replay {record} --scan {scan_path} --out DIR)")
    return 0


def _serve_headless(args, live, setup) -> None:
    """No window: wait for a client, render ``--frames`` following the loop, serve the client
    until it sends RELEASE (or the peer timeout unpins it); return early if the loop stops."""
    dev = live.device
    host, port = dev.address
    running = live.scheduler
    print(f"arsurf view: {'no display' if args.frames else '--frames 0'}: waiting for a client on UDP {host}:{port}, "
          f"then serving it until it sends RELEASE (Ctrl-C stops)", file=sys.stderr)
    while dev.peer is None and running.is_running:
        time.sleep(0.01)
    if args.frames and running.is_running:
        from functools import partial

        from arsurf_viewer.interactive import run_interactive
        from arsurf_viewer.live import live_scene

        run_interactive(setup.surface, tip_radius=setup.model.tip_radius, physics=partial(live_scene, live),
                        pose_source=live.pose, out_dir=args.out, frames=args.frames, window_size=tuple(args.size))
    while dev.peer is not None and running.is_running:
        time.sleep(0.01)
