"""The ``arsurf`` command: ``arsurf <subcommand> ...`` (``arsurf --help`` lists them).

Every error is one line on stderr naming the file or flag, the rule and the way out, with exit
status 2; a tracebacks never reaches the user.

Units at this edge: lengths on the command line are in nanometres (flags end in ``-nm``),
forces in nanonewtons; everything inside is SI.

Messages: results go to stdout; progress messages, notes and bars to stderr through the
``arsurf`` logger (:mod:`arsurf._logging`): ``-q``/``--quiet`` keeps only warnings and errors and
hides the bars, ``-v``/``--verbose`` adds debug messages (before or after the subcommand).

One module per command group: this one holds the parser, :func:`main` and the scan-file commands
(``info``, ``formats``, ``fit``, ``synth``, ``export``, ``convert``); :mod:`arsurf.cli.view`,
:mod:`arsurf.cli.live` and :mod:`arsurf.cli.batch` their commands; :mod:`arsurf.cli.args` the
argument types and flags they share; ``demo``, ``replay``, ``devices``, ``verify`` and ``warmup`` register themselves
(:data:`_EXTRA_COMMANDS`).
"""
from __future__ import annotations

import argparse
import importlib
import json
import sys
import time

import numpy as np

from arsurf.cli import batch, live, view
from arsurf.cli.args import _calibration, _calibration_flags, _frame_flag, _Parser, _penalty, _prepare, _processing_flags
from arsurf.errors import ArsurfError

def _scan_summary(scan) -> dict:
    finite = scan.heights[np.isfinite(scan.heights)]
    ny, nx = scan.shape
    unit = scan.metadata.get("z_unit") or "m"
    # lengths in nm (the CLI's unit); any other channel in its own SI unit, named in the key
    scale, shown = (1e9, "nm") if unit == "m" else (1.0, unit.replace("/", "_per_") or "arb")
    out = {
        "file": scan.source,
        "format": scan.metadata.get("format"),
        "channel": scan.channel,
        "channels": scan.metadata.get("channels"),
        "channel_units": scan.metadata.get("channel_units") or {},
        "pixels": f"{nx} x {ny}",
        "pixel_size_nm": [scan.dx * 1e9, scan.dy * 1e9],
        "scan_size_nm": [scan.extent[0] * 1e9, scan.extent[1] * 1e9],  # pixels x spacing (Scan.extent)
        "first_to_last_pixel_nm": [scan.size[0] * 1e9, scan.size[1] * 1e9],  # centre to centre (Scan.size)
        f"z_min_{shown}": float(finite.min() * scale) if finite.size else None,
        f"z_max_{shown}": float(finite.max() * scale) if finite.size else None,
        f"z_range_{shown}": float(np.ptp(finite) * scale) if finite.size else None,
        "nan_pixels": scan.nan_count,
        "units": {"stored": scan.metadata.get("file_z_unit") or unit, "reported": shown},
    }
    frames = scan.metadata.get("frames")
    if isinstance(frames, int) and not isinstance(frames, bool):  # a movie (.asd, .h5-jpk): which frame, of how many
        out["frame"] = f"{scan.metadata.get('frame', 0)} of 0..{frames - 1} (--frame N)"
    if scan.metadata.get("height") is False:
        out["height_channel"] = "no: not topography by its unit or name; arsurf fit refuses it (--as-height " \
            "overrides for a channel in metres)"
    if scan.metadata.get("calibrated") is False:  # NanoScope: the file leaves the channel in arbitrary units
        out["calibrated"] = "no: the file gives this channel in arbitrary units (its sensitivity has no unit)"
    if scan.metadata.get("log10_decoded"):
        out["decoded"] = "the file stores log10 of this channel; values shown are 10**stored"
    return out


def _print(obj: dict, as_json: bool) -> None:
    if as_json:
        print(json.dumps(obj, indent=2, default=str))
        return
    width = max(len(k) for k in obj)
    for key, value in obj.items():
        if isinstance(value, float):
            value = f"{value:.6g}"
        elif isinstance(value, list) and value and isinstance(value[0], float):
            value = " x ".join(f"{v:.6g}" for v in value)
        elif isinstance(value, dict):  # channel -> unit
            value = ", ".join(f"{k} [{v or '?'}]" for k, v in value.items())
        print(f"{key:<{width}}  {value}")


def cmd_info(args) -> int:
    from arsurf.scan.io import load_scan
    from arsurf.spline.storage import is_surface_file, load_surface, surface_summary

    if is_surface_file(args.scan) and not getattr(args, "material", False):  # `arsurf fit`'s output, not a scan
        meta = _surface_metadata(args.scan)
        _print({"file": str(args.scan), **surface_summary(load_surface(args.scan)),
                "fitted_from": meta.get("scan", "?")}, args.json)
        return 0
    scan = load_scan(args.scan, channel=args.channel, frame=args.frame, **_calibration(args))
    if getattr(args, "material", False):
        return _material_info(args, scan)
    _print(_scan_summary(scan), args.json)
    return 0


def _surface_metadata(path) -> dict:
    with np.load(path, allow_pickle=False) as f:
        try:
            meta = json.loads(str(f["metadata_json"]))
        except ValueError:
            return {}
    return meta if isinstance(meta, dict) else {}


def _material_info(args, scan) -> int:
    """``arsurf info --material``: the mechanical channels with their units, then (when their
    conversions are stated) the E* and w statistics of the map, median and 5-95 %."""
    from arsurf.contact.material_conversion import MaterialConversion
    from arsurf.contact.material_map import mechanical_channels, material_map_from_file

    listing = mechanical_channels(scan)
    out = {"file": scan.source, "format": scan.metadata.get("format"),
           "mechanical_channels": listing or "none (no modulus, adhesion, deformation or dissipation channel)"}
    if not listing:
        _print(out, args.json)
        return 0
    conv = MaterialConversion.from_cli(args)
    try:
        m = material_map_from_file(args.scan, conv, channels=MaterialConversion.cli_channels(args))
    except ArsurfError:
        _print(out, args.json)  # the listing, then the one-line reason on stderr (exit 2)
        raise
    st = m.statistics

    def pct(d, scale):
        v = {"median": d["median"] * scale, "p5": d["p5"] * scale, "p95": d["p95"] * scale}
        return v if args.json else f"median {v['median']:.6g}, 5-95 % {v['p5']:.6g} .. {v['p95']:.6g}"

    out.update({
        "channels_used": ", ".join(f"{k}: {v}" for k, v in m.channels.items()),
        "tip_radius_nm": conv.tip_radius * 1e9,
        "regime": conv.regime,
        # what the map means: convention, Poisson ratio and its source, cross-check, masks by reason
        **dict(zip(("convention", "sample_poisson", "channel_cross_check", "masked_modulus", "masked_adhesion"),
                   m.describe())),
        "effective_modulus_GPa": pct(st["reduced_modulus"], 1e-9),
        "work_of_adhesion_mJ_per_m2": pct(st["work_of_adhesion"], 1e3),
        "sample_modulus_GPa": pct(st["sample_modulus"], 1e-9),
        "pull_off_force_nN": pct(st["pull_off_force"], 1e9),
        "masked_modulus_percent": 100.0 * m.masked["modulus"]["masked"],
        "masked_adhesion_percent": 100.0 * m.masked["adhesion"]["masked"],
        "adhesion_floor_nN": m.masked["adhesion"]["floor_N"] * 1e9,
        "below_floor_percent": 100.0 * m.masked["adhesion"]["floored"],
        "conversion": ", ".join(f"{k}={v}" for k, v in m.conversion.to_metadata().items() if v is not None),
        "registration": m.registration,
        "map_sha256": m.sha256,
    })
    if args.json:
        out["summary"] = m.summary()
    _print(out, args.json)
    return 0


def cmd_fit(args) -> int:
    from arsurf.spline.fit import check_control_shape, fit_surface
    from arsurf.spline.storage import save_surface

    scan = _prepare(args, args.scan, args.channel, not args.no_inpaint, frame=args.frame, as_height=args.as_height,
                    **_calibration(args))
    ny, nx = scan.shape
    control = check_control_shape(nx, ny, args.control, args.smoothing, names=("--control", "--smoothing")) \
        if args.control else None
    t0 = time.perf_counter()
    surface = fit_surface(scan, control_shape=control, smoothing=args.smoothing)
    elapsed = time.perf_counter() - t0
    xx, yy = np.meshgrid(scan.x, scan.y)
    resid = surface.evaluate(xx, yy)[..., 2] - scan.heights
    out = save_surface(surface, args.output, metadata={"scan": str(args.scan), "history": scan.history})
    _print({
        "scan": str(args.scan),
        "processing": " -> ".join(step.get("operation", step.get("method", "?")) for step in scan.history) or "none",
        "control_points": f"{surface.shape[0]} x {surface.shape[1]}",
        "fit_time_ms": elapsed * 1e3,
        "rms_residual_nm": float(np.sqrt(np.mean(resid**2)) * 1e9),
        "max_residual_nm": float(np.abs(resid).max() * 1e9),
        "written": str(out),
    }, args.json)
    return 0


def cmd_synth(args) -> int:
    from arsurf.scan.synthetic import write_demo_scans

    for path in write_demo_scans(args.out):
        print(path)
    return 0


_SCAN_OUTPUTS = (".gwy", ".gsf", ".npz", ".npy")


def cmd_formats(args) -> int:
    """``arsurf formats``: the scan formats :func:`arsurf.load_scan` reads, with their extensions
    (the content decides first: a renamed file is still read)."""
    from arsurf.scan.io import format_extensions

    _print(format_extensions(), args.json)
    return 0


def cmd_export(args) -> int:
    from arsurf.export import export_surface
    from arsurf.spline.storage import load_surface

    surface = load_surface(args.surface)
    res = tuple(args.resolution) if args.resolution else None
    if str(args.output).lower().endswith(_SCAN_OUTPUTS):  # a height map for Gwyddion & co.
        from arsurf.scan.io import save_scan
        from arsurf.spline.sampling import surface_to_scan

        path = save_scan(surface_to_scan(surface, res, source=str(args.surface)), args.output)
    else:
        path = export_surface(surface, args.output, res, solid=args.solid)
    print(path)
    return 0


def cmd_convert(args) -> int:
    from arsurf.scan.io import save_scan

    scan = _prepare(args, args.scan, args.channel, not args.no_inpaint, frame=args.frame, **_calibration(args))
    print(save_scan(scan, args.output))
    return 0


def build_parser() -> argparse.ArgumentParser:
    from arsurf import __version__

    p = _Parser(prog="arsurf", description="arsurf: augmented-reality surface model for AFM nanomanipulation "
                "(scan -> B-spline -> contact -> 3D force -> haptics). Lengths on the command line are in "
                "nanometres (flags ending in -nm); everything inside is SI.")
    p.add_argument("--version", action="version", version=f"arsurf {__version__}")
    _log_flags(p, argparse.SUPPRESS)
    sub = p.add_subparsers(dest="command", required=True, parser_class=_Parser)

    s = sub.add_parser("info", help="describe a scan file: format, channel, pixels, size, z range (--material: "
                       "its mechanical channels and the E* and w they give)")
    s.add_argument("scan")
    s.add_argument("--channel", help="channel name (default: topography/height)")
    s.add_argument("--json", action="store_true", help="print JSON")
    _calibration_flags(s)
    _frame_flag(s)
    s.add_argument("--material", action="store_true", help="list the mechanical channels (modulus, adhesion, "
                   "deformation, dissipation) with their units and print the E* and w statistics of the material "
                   "map (median, 5-95 %%); channels the file leaves uncalibrated need the conversion flags")
    from arsurf.contact.material_conversion import MaterialConversion

    MaterialConversion.cli_arguments(s)
    s.set_defaults(func=cmd_info)

    s = sub.add_parser("fit", help="level, smooth and fit a bicubic B-spline; write it as .npz")
    s.add_argument("scan")
    s.add_argument("-o", "--output", required=True, help="output surface file (.npz)")
    s.add_argument("--channel")
    _processing_flags(s)
    s.add_argument("--control", type=int, nargs=2, metavar=("NU", "NV"), help="control points (approximating fit)")
    s.add_argument("--smoothing", type=_penalty, default=0.0, help="P-spline penalty weight (dimensionless)")
    s.add_argument("--no-inpaint", action="store_true", help="refuse NaN pixels instead of filling them")
    s.add_argument("--as-height", action="store_true", help="fit a channel in metres that its file names as "
                   "another quantity (an amplitude...) as if it were the topography")
    s.add_argument("--json", action="store_true")
    _calibration_flags(s)
    _frame_flag(s)
    s.set_defaults(func=cmd_fit)

    s = sub.add_parser("formats", help="list the scan formats arsurf reads and their extensions (detected by "
                       "content first)")
    s.add_argument("--json", action="store_true", help="print JSON")
    s.set_defaults(func=cmd_formats)

    s = sub.add_parser("synth", help="write the synthetic demo scans (gratings, tubes, particles...)")
    s.add_argument("--out", default="scans")
    s.set_defaults(func=cmd_synth)

    view.register(sub)

    live.register(sub)

    s = sub.add_parser("export", help="write a fitted (or deformed) surface as a mesh (STL/PLY/GLB) or a height "
                       "map (.gwy/.gsf/.npz/.npy)")
    s.add_argument("surface", help="surface file written by `arsurf fit`")
    s.add_argument("-o", "--output", required=True, help="output: mesh (.stl, .ply, .glb) or height map (.gwy, .gsf, "
                   ".npz, .npy)")
    s.add_argument("--resolution", type=int, nargs=2, metavar=("NU", "NV"), help="samples along u and v")
    s.add_argument("--solid", action="store_true", help="close the surface into a watertight solid")
    s.set_defaults(func=cmd_export)

    s = sub.add_parser("convert", help="read a scan channel and write it as .gwy, .gsf, .npz or .npy (optionally "
                       "levelled and smoothed)")
    s.add_argument("scan")
    s.add_argument("-o", "--output", required=True, help="output file (.gwy, .gsf, .npz, .npy)")
    s.add_argument("--channel")
    _processing_flags(s, level="none")
    s.add_argument("--no-inpaint", action="store_true", help="keep NaN pixels instead of filling them")
    _calibration_flags(s)
    _frame_flag(s)
    s.set_defaults(func=cmd_convert)

    batch.register(sub)

    for module in _EXTRA_COMMANDS:
        importlib.import_module(module).register(sub)
    for command in sub.choices.values():  # -q/-v after the subcommand too (not given: the top level's stand)
        _log_flags(command, argparse.SUPPRESS)
    return p


def _log_flags(parser, default) -> None:
    """-q/-v on ``parser`` and on the subcommands below it (``arsurf batch process -q``)."""
    parser.add_argument("-q", "--quiet", dest="log_quiet", action="store_true", default=default,
                        help="only warnings and errors on stderr; no progress bars")
    parser.add_argument("-v", "--verbose", dest="log_verbose", action="count", default=default,
                        help="more messages on stderr (debug)")
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for child in action.choices.values():
                _log_flags(child, default)


#: modules whose ``register(subparsers)`` adds a subcommand (higher pipeline stages)
_EXTRA_COMMANDS = ["arsurf.demo", "arsurf.replay.replay", "arsurf.devices", "arsurf.verify.command",
                   "arsurf.warmup"]


def main(argv=None) -> int:
    from arsurf._logging import LOGGER, configure_cli

    args = build_parser().parse_args(argv)
    verbosity = getattr(args, "log_verbose", 0) - (1 if getattr(args, "log_quiet", False) else 0)
    level = LOGGER.level
    handler = configure_cli(verbosity)
    try:
        return _run(args)
    finally:
        LOGGER.removeHandler(handler)
        LOGGER.setLevel(level)


def _run(args) -> int:
    try:
        return int(args.func(args) or 0)
    except ArsurfError as exc:
        print(f"arsurf {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # `arsurf info F | head -1`: the reader left; nothing more to say
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error at exit
        return 0
    except OSError as exc:  # a path the user gave: missing folder, no permission, full disk
        where = f" {exc.filename!r}" if exc.filename else ""
        print(f"arsurf {args.command}: error: cannot use{where}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # pragma: no cover
        print(f"arsurf {args.command}: interrupted", file=sys.stderr)
        return 130

