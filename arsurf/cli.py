"""The ``arsurf`` command: ``arsurf <subcommand> ...`` (``arsurf --help`` lists them).

Every error is one line on stderr naming the file or flag, the rule and the way out, with exit
status 2; a tracebacks never reaches the user.

Units at this edge: lengths on the command line are in nanometres (flags end in ``-nm``),
forces in nanonewtons; everything inside is SI.

Messages: results go to stdout; progress messages, notes and bars to stderr through the
``arsurf`` logger (:mod:`arsurf._logging`): ``-q``/``--quiet`` keeps only warnings and errors and
hides the bars, ``-v``/``--verbose`` adds debug messages (before or after the subcommand).
"""
from __future__ import annotations

import argparse
import importlib
import json
import sys
import time

import numpy as np

from arsurf.errors import ArsurfError
from arsurf.scan.level import METHODS as _LEVEL_METHODS
from arsurf.scan.prepare import prepare_scan

#: what --level accepts: every arsurf.level method, and none
LEVEL_CHOICES = (*_LEVEL_METHODS, "none")


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

    scan = load_scan(args.scan, channel=args.channel, frame=args.frame, **_calibration(args))
    if getattr(args, "material", False):
        return _material_info(args, scan)
    _print(_scan_summary(scan), args.json)
    return 0


def _prepare(args, path, channel=None, inpaint: bool = True, **options):
    """:func:`prepare_scan` with the CLI's flags: a smoothing width wider than the scan is
    reported in nanometres and names ``--sigma-nm`` (the library speaks metres)."""
    from arsurf.errors import SigmaTooWide, SmoothingError

    try:
        return prepare_scan(path, channel, args.level, args.sigma_nm * 1e-9, inpaint, **options)
    except SigmaTooWide as exc:
        nm = exc.spacing * 1e9
        raise SmoothingError(
            f"--sigma-nm {args.sigma_nm:g} is {exc.pixels:.4g} pixels of {nm:.4g} nm along {exc.axis}, wider than "
            f"the scan ({exc.widest} pixels, {exc.widest * nm:.4g} nm); give a width of a few pixels in nm, e.g. "
            f"--sigma-nm {2 * nm:.3g}"
        ) from None


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
        "E*_GPa": pct(st["reduced_modulus"], 1e-9),
        "w_mJ_per_m2": pct(st["work_of_adhesion"], 1e3),
        "sample_modulus_GPa": pct(st["sample_modulus"], 1e-9),
        "pull_off_nN": pct(st["pull_off_force"], 1e9),
        "masked_modulus_percent": 100.0 * m.masked["modulus"]["masked"],
        "masked_adhesion_percent": 100.0 * m.masked["adhesion"]["masked"],
        "adhesion_floor_nN": m.masked["adhesion"]["floor_N"] * 1e9,
        "below_floor_percent": 100.0 * m.masked["adhesion"]["floored"],
        "conversion": ", ".join(f"{k}={v}" for k, v in conv.to_metadata().items() if v is not None),
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


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors: ``arsurf fit: error: argument --sigma-nm: ...`` (exit 2)."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _nm(minimum: float = 0.0, strict: bool = False):
    """An argparse type: a finite length in nanometres, >= (or >) ``minimum``."""
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be a number of nanometres (got {text!r})") from None
        if not np.isfinite(value) or value < minimum or (strict and value == minimum):
            rule = f"> {minimum:g}" if strict else f">= {minimum:g}"
            raise argparse.ArgumentTypeError(f"must be a finite length {rule} nm (got {text})")
        return value
    return parse


def _penalty(text: str) -> float:
    """An argparse type: a finite number >= 0 (the dimensionless P-spline penalty weight)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number (got {text!r})") from None
    if not (np.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0 (got {text})")
    return value


def _count(text: str) -> int:
    """An argparse type: an integer >= 0."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer >= 0 (got {text!r})") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be an integer >= 0 (got {text})")
    return value


def _values(unit: str, scale: float, strict: bool):
    """An argparse type: comma-separated finite numbers in ``unit`` (>= 0, or > 0 if ``strict``), as SI."""
    def parse(text: str) -> list[float]:
        out = []
        for part in text.split(","):
            try:
                value = float(part)
            except ValueError:
                raise argparse.ArgumentTypeError(f"must be comma-separated numbers{' in ' + unit if unit else ''} "
                                                 f"(got {text!r})") from None
            if not np.isfinite(value) or value < 0 or (strict and value == 0):
                rule = "> 0" if strict else ">= 0"
                raise argparse.ArgumentTypeError(f"every value must be finite and {rule}{' ' + unit if unit else ''} "
                                                 f"(got {part.strip()!r} in {text!r})")
            out.append(value * scale)
        return out
    return parse


def _calibration(args) -> dict:
    """``dx``, ``dy`` (m) and ``z_unit`` of a file that does not state them (flags in nm)."""
    return {"dx": None if args.dx_nm is None else args.dx_nm * 1e-9,
            "dy": None if args.dy_nm is None else args.dy_nm * 1e-9, "z_unit": args.z_unit}


def _processing_flags(s, level: str = "plane") -> None:
    """--level and --sigma-nm: the preprocessing of arsurf.scan.prepare.prepare_scan."""
    s.add_argument("--level", default=level, choices=LEVEL_CHOICES, metavar="METHOD",
                   help=f"levelling: {' | '.join(LEVEL_CHOICES)} (default: {level})")
    s.add_argument("--sigma-nm", type=_nm(), default=0.0, help="Gaussian smoothing width in nm (default 0: none)")


def _frame_flag(s) -> None:
    s.add_argument("--frame", type=_count, help="frame of a movie (high-speed AFM .asd, JPK .h5-jpk), from 0 (default 0)")


def _calibration_flags(s) -> None:
    s.add_argument("--dx-nm", type=_nm(strict=True), help="pixel spacing along x in nm, for a file that does "
                   "not state it (a bare .txt/.npy matrix)")
    s.add_argument("--dy-nm", type=_nm(strict=True), help="pixel spacing along y in nm (as --dx-nm)")
    s.add_argument("--z-unit", help="unit of the values of such a file (nm, um, m, V...)")


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

    s = sub.add_parser("synth", help="write the synthetic demo scans (gratings, tubes, particles...)")
    s.add_argument("--out", default="scans")
    s.set_defaults(func=cmd_synth)

    s = sub.add_parser("view", help="open the interactive 3D viewer (offscreen PNG without a display)")
    s.add_argument("scan", nargs="?", default=None, help="scan file (default: the bundled nanotubes)")
    s.add_argument("--tip-radius-nm", type=_nm(strict=True), default=20.0, help="tip radius in nm (default 20)")
    _processing_flags(s)
    s.add_argument("--bridge-port", type=int, default=None,
                   help="run the full haptic loop against a device on the UDP bridge at 127.0.0.1:PORT "
                        "(authenticated poses in, forces out; protocol in docs/bridge-protocol.md; "
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
    s.add_argument("--scale", type=float, default=1e-5, help="probe metres per stylus metre with --bridge-port")
    s.add_argument("--record", metavar="FILE", help="with --bridge-port: record the haptic loop's session to FILE "
                   "(.h5, must not exist), replayable with `arsurf replay FILE --scan SCAN`")
    s.add_argument("--tubes", action="store_true",
                   help="make the nanotubes of a synthetic scan live objects the tip can push (not with --bridge-port)")
    s.add_argument("--out", default="out/view", help="without a display: folder of the offscreen PNG frames "
                   "(default out/view)")
    s.add_argument("--frames", type=_count, default=90, help="without a display: how many frames (default 90); with "
                   "--bridge-port, 0: no view at all, the loop serves the client until it sends RELEASE")
    s.add_argument("--material", action="store_true", help="colour the surface by the file's mechanical channels "
                   "(key c cycles the colourings); uncalibrated channels need the conversion flags below")
    s.add_argument("--color-by", default=None, choices=("height", "deformation", "modulus", "adhesion",
                                                        "sample_deformation", "dissipation"),
                   help="the surface's colouring (default height; the last four need --material)")
    from arsurf.contact.material_conversion import MaterialConversion

    MaterialConversion.cli_arguments(s, tip_radius_nm=None)
    s.set_defaults(func=cmd_view)

    _live_parser(sub)

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

    _batch_parser(sub)

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


def _batch_parser(sub) -> None:
    """``arsurf batch {process,replay,sweep} INPUT... -o DIR [--workers N | --scheduler ADDR] [--resume]``."""
    from arsurf.assembly import PRESETS

    s = sub.add_parser("batch", help="run a pipeline (process | replay | sweep) over a folder or glob of files, on "
                       "local processes or a Dask cluster; results.csv is written as items finish (--resume)")
    bsub = s.add_subparsers(dest="pipeline", required=True, parser_class=_Parser, metavar="PIPELINE")

    def common(b) -> None:
        b.add_argument("inputs", nargs="+", metavar="INPUT",
                       help="files, folders (their files of the pipeline's kind) or quoted glob patterns ('**' recurses)")
        b.add_argument("-o", "--out", required=True, help="output folder: results.csv, summary.json, batch.json and "
                       "the items' files")
        where = b.add_mutually_exclusive_group()
        where.add_argument("--workers", type=_count, help="local worker processes (default: the CPU count; 0: run "
                           "in this process)")
        where.add_argument("--scheduler", metavar="ADDRESS", help="run on the Dask cluster of this scheduler "
                           "(tcp://HOST:8786; needs pip install 'arsurf[dask]'; workers must see the files and --out)")
        b.add_argument("--resume", action="store_true", help="continue the batch in --out: skip the items already "
                       "done (status ok), rerun the others")
        b.set_defaults(func=cmd_batch)

    b = bsub.add_parser("process", help="level, smooth, fit (and export) every scan: <item>.surface.npz")
    common(b)
    b.add_argument("--channel")
    _processing_flags(b)
    b.add_argument("--control", type=int, nargs=2, metavar=("NU", "NV"), help="control points (approximating fit)")
    b.add_argument("--smoothing", type=_penalty, default=0.0, help="P-spline penalty weight (dimensionless)")
    b.add_argument("--no-inpaint", action="store_true", help="refuse NaN pixels instead of filling them")
    b.add_argument("--export", action="append", metavar="EXT", choices=("stl", "ply", "glb", "gwy", "gsf", "npz", "npy"),
                   help="also write the fitted surface as a mesh (stl, ply, glb) or height map (gwy, gsf, npz, npy); "
                        "repeat for several")
    b.add_argument("--resolution", type=int, nargs=2, metavar=("NU", "NV"), help="samples along u and v of an export")
    b.add_argument("--solid", action="store_true", help="close exported meshes into watertight solids")
    _calibration_flags(b)

    b = bsub.add_parser("replay", help="replay every recorded session (.h5 in a folder): <item>/")
    common(b)
    b.add_argument("--scan", help="the scan file every session was recorded on (default: each session's recorded "
                   "path, or beside the session)")

    b = bsub.add_parser("sweep", help="press, slide and retract the tip on each scan over a grid of friction x tip "
                        "radius x modulus: one row per scan and grid point")
    common(b)
    b.add_argument("--friction", type=_values("", 1.0, False), metavar="LIST",
                   help="kinetic friction coefficients, comma-separated (default: the preset's)")
    b.add_argument("--tip-radius-nm", type=_values("nm", 1e-9, True), metavar="LIST",
                   help="tip radii in nm, comma-separated (default: the preset's)")
    b.add_argument("--modulus-gpa", type=_values("GPa", 1e9, True), metavar="LIST",
                   help="effective contact moduli E* in GPa, comma-separated (default: the preset's)")
    b.add_argument("--preset", default="demo", choices=sorted(PRESETS), metavar="NAME",
                   help=f"scan processing, adhesion and cantilever: {' | '.join(sorted(PRESETS))} (default demo)")
    b.add_argument("--depth-nm", type=_nm(strict=True), default=2.0, help="indentation of the press in nm (default 2)")
    b.add_argument("--slide-nm", type=_nm(), default=20.0, help="slide length along x in nm (default 20)")
    b.add_argument("--steps", type=int, default=40, help="ticks of each leg: press, slide, retract (default 40)")
    b.add_argument("--at-nm", type=float, nargs=2, metavar=("X", "Y"), help="where to press, nm (default: the middle)")


def _batch_options(args) -> dict:
    """The SI options of :func:`arsurf.batch.run_batch` from the flags of ``arsurf batch PIPELINE``."""
    if args.pipeline == "process":
        cal = _calibration(args)
        return {"channel": args.channel, "level": args.level, "sigma": args.sigma_nm * 1e-9,
                "inpaint": not args.no_inpaint, "control_shape": args.control, "smoothing": args.smoothing,
                "export": args.export or [], "resolution": args.resolution, "solid": args.solid, **cal}
    if args.pipeline == "replay":
        return {"scan": args.scan}
    opts = {"preset": args.preset, "depth": args.depth_nm * 1e-9, "slide": args.slide_nm * 1e-9, "steps": args.steps,
            "at": None if args.at_nm is None else [v * 1e-9 for v in args.at_nm]}
    for name, flag in (("friction", args.friction), ("tip_radius", args.tip_radius_nm),
                       ("effective_modulus", args.modulus_gpa)):
        if flag is not None:
            opts[name] = flag
    return opts


def cmd_batch(args) -> int:
    """``arsurf batch``: exit 0 when every item succeeded, 1 when some failed (listed on stderr)."""
    from arsurf.batch import run_batch

    r = run_batch(args.pipeline, args.inputs, args.out, options=_batch_options(args), workers=args.workers,
                  scheduler=args.scheduler, resume=args.resume,
                  progress=not getattr(args, "log_quiet", False))  # -q: no progress counter
    shown = 20
    for item, reason in r.errors[:shown]:
        print(f"arsurf batch: failed: {item}: {reason}", file=sys.stderr)
    if len(r.errors) > shown:
        print(f"arsurf batch: ... and {len(r.errors) - shown} more failures (see {r.table})", file=sys.stderr)
    print(f"{r.total} items: {r.ok} ok, {r.failed} failed, {r.total - r.ok - r.failed} not run; {r.ran} run now, "
          f"{r.skipped} done before, in {r.elapsed:.2f} s ({r.items_per_second:.3g} items/s)")
    print(f"results: {r.table}")
    print(f"summary: {r.summary}")
    return 1 if r.failed else 0


#: modules whose ``register(subparsers)`` adds a subcommand (higher pipeline stages)
_EXTRA_COMMANDS = ["arsurf.demo", "arsurf.replay.replay", "arsurf.devices"]


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
                                ("--bridge-peer-timeout", args.bridge_peer_timeout), ("--record", args.record))
                 if v is not None]
        if given:
            raise HapticsError(f"{', '.join(given)} set up the UDP bridge's haptic loop; give --bridge-port PORT too")
        if args.frames == 0:
            raise HapticsError("--frames 0 (no view) is for a --bridge-port loop; without one give at least 1 frame")
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


def _record_target(args):
    """The session file of ``--record`` (None without it), refused before anything slow runs:
    it must not exist (a recording never replaces another) and its folder must."""
    import os

    from arsurf.errors import SessionError

    if args.record is None:
        return None
    path = os.path.abspath(args.record)
    if os.path.lexists(path):
        raise SessionError(f"--record {args.record!r} exists; a recording never replaces another: pick a new file")
    if not os.path.isdir(os.path.dirname(path)):
        raise SessionError(f"--record {args.record!r}: its folder does not exist; create it first")
    return path


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
              frames=args.frames, **colour)
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

    from arsurf.assembly import BRIDGE_HAPTICS, BUNDLED_SCAN, build_model, preset_metadata
    from arsurf.errors import require
    from arsurf.haptics.udp_bridge import VERSION
    from arsurf.live import bridge_loop
    from arsurf.sessions.writer import SessionWriter, record_loop_tick
    from arsurf_viewer.backend import has_display

    show = args.frames > 0
    if show:
        require("pyvista", "viewer", "arsurf view")
    scan_path = args.scan or str(BUNDLED_SCAN)
    meta = preset_metadata(scan_path, "viewer", tip_radius=args.tip_radius_nm * 1e-9, level=args.level,
                           sigma=args.sigma_nm * 1e-9, haptics=dict(BRIDGE_HAPTICS, scale=args.scale))
    setup = build_model(meta)
    live = bridge_loop(setup.model, meta["haptics"], host=bridge.host, port=bridge.port, key=bridge.key,
                       peer_timeout=bridge.peer_timeout)
    dev = live.device
    try:
        dev.open()  # a busy port fails here, before a recording starts
        host, port = dev.address
        writer = contextlib.nullcontext()
        if record is not None:  # the key is never recorded; where the client came in is
            info = dev.info
            meta = dict(meta, device={"interface": "udp-bridge", "protocol_version": VERSION, "host": host,
                                      "port": port, "name": info.name, "max_force": info.max_force})
            writer = SessionWriter(record, meta, handle_signals=True)
            live.record = partial(record_loop_tick, writer)
        with writer:
            live.start()
            print(f"arsurf view: haptic loop running at 1 kHz, listening for authenticated stylus poses on UDP "
                  f"{host}:{port} (`python -m arsurf.haptics.client` and examples/cpp are clients)"
                  + (f"; recording to {record}" if record else ""), file=sys.stderr)
            try:
                if show and has_display():
                    from arsurf_viewer.interactive import run_interactive
                    from arsurf_viewer.live import live_scene

                    run_interactive(setup.surface, tip_radius=setup.model.tip_radius, physics=partial(live_scene, live),
                                    pose_source=live.pose, out_dir=args.out, frames=args.frames)
                else:
                    _serve_headless(args, live, setup)
            finally:
                stats = live.stop()
                print(f"arsurf view: loop stopped after {stats.ticks} ticks at {stats.rate:.0f} Hz", file=sys.stderr)
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
                        pose_source=live.pose, out_dir=args.out, frames=args.frames)
    while dev.peer is not None and running.is_running:
        time.sleep(0.01)


#: ``arsurf live`` device flags: (argparse dest, flag, the adapters' option, SI factor or None)
_DEVICE_FLAGS = (
    ("max_force_n", "--max-force-n", "max_force", 1.0),
    ("workspace_mm", "--workspace-mm", "workspace", 1e-3),
    ("serial_port", "--serial-port", "port", None),
    ("handle_port", "--handle-port", "handle_port", None),
    ("device_index", "--device-index", "index", None),
    ("device_name", "--device-name", "name", None),
    ("calibrate", "--calibrate", "calibrate", None),
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


def _positive(unit: str):
    """An argparse type: a positive finite number in ``unit``."""
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be a number in {unit} (got {text!r})") from None
        if not (np.isfinite(value) and value > 0):
            raise argparse.ArgumentTypeError(f"must be a positive finite number in {unit} (got {text})")
        return value
    return parse


def _live_parser(sub) -> None:
    from arsurf.haptics.backends import DEVICES

    s = sub.add_parser("live", help="run the 1 kHz haptic loop on a haptic device (virtual or real), optionally "
                       "driving an AFM on its measured signals; record it with --record")
    s.add_argument("scan", nargs="?", default=None, help="scan file (default: the bundled nanotubes)")
    s.add_argument("--device", default="virtual", metavar="NAME",
                   help=f"haptic device: {' | '.join(DEVICES)} (default virtual: a scripted hand presses the "
                        "stylus into the surface every 2 s; `arsurf devices` lists what is connected)")
    g = s.add_argument_group("device options (each adapter takes some; see README, Haptic devices)")
    g.add_argument("--max-force-n", type=_positive("N"), help="force limit in N, at most the device's own (required "
                   "for haply)")
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
    s.add_argument("--tip-radius-nm", type=_nm(strict=True), default=20.0, help="tip radius in nm (default 20)")
    _processing_flags(s)
    s.add_argument("--scale", type=_positive("probe m per stylus m"), default=1e-5,
                   help="probe metres per stylus metre (default 1e-5: 1 mm -> 10 nm)")
    s.add_argument("--seconds", type=_positive("seconds"), help="run this long (default: until Ctrl-C)")
    s.add_argument("--realtime-priority", type=_priority, default=0, metavar="N",
                   help="run the loop thread under SCHED_FIFO at priority N (1-99) where the OS allows it (root, "
                        "CAP_SYS_NICE or an rtprio limit); 0, the default: the ordinary policy. Not with a device "
                        "that answers from a thread of this process (haply, openhaptics): see README")
    s.add_argument("--record", metavar="FILE", help="record the session to FILE (.h5, must not exist), replayable "
                   "with `arsurf replay FILE --scan SCAN`")
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
    g.add_argument("--max-age-ms", type=_positive("ms"), default=20.0,
                   help="oldest instrument sample a force is rendered from, ms (default 20); older: zero force, stop")
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
                         sigma=args.sigma_nm * 1e-9, scale=args.scale, measured=args.instrument is not None)
    setup = build_model(meta)
    instrument = photodiode = frame = None
    if args.instrument is not None:
        from arsurf.haptics.live_loop import bridge_start

        sens = args.deflection_sensitivity_nm
        instrument, photodiode, frame = open_instrument(
            args.instrument, setup, bridge_start(setup.surface, setup.model.tip_radius),
            deflection_sensitivity=None if sens is None else sens * 1e-9, max_speed=args.max_speed_um_s * 1e-6,
            origin=[v * 1e-9 for v in (args.instrument_origin_nm or (0.0, 0.0, 0.0))])
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
        result = run_live(meta, device, backend=args.device, instrument=instrument, photodiode=photodiode,
                          frame=frame, axes=args.instrument_axes, max_age=args.max_age_ms * 1e-3, record=record,
                          seconds=args.seconds, stop=stop, setup=setup, priority=args.realtime_priority)
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


_SCAN_OUTPUTS = (".gwy", ".gsf", ".npz", ".npy")


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


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
