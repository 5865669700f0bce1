"""``arsurf batch``: one pipeline over many files (:mod:`arsurf.batch`)."""
from __future__ import annotations

import sys

from arsurf.cli.args import (_calibration, _calibration_flags, _count, _nm, _Parser, _penalty, _processing_flags,
                             _values)

def register(sub) -> None:
    """``arsurf batch {process,replay,sweep} INPUT... -o DIR [--workers N | --scheduler ADDR] [--resume]``."""
    from arsurf.assembly import PRESET_ALIASES, PRESETS

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
                       "done (status ok, their output files there with the size and SHA-256 of their row), rerun "
                       "the others")
        b.add_argument("--item-timeout", type=float, default=3600.0, metavar="S",
                       help="time limit of one item, s (default 3600); an item past it is an error row")
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
    b.add_argument("--preset", default="demo", choices=[*sorted(PRESETS), *sorted(PRESET_ALIASES)],
                   metavar="NAME",
                   help=f"scan processing, adhesion and cantilever: {' | '.join(sorted(PRESETS))} (default demo; "
                        "seed000..seed003 are the old names of the four source presets)")
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
                  scheduler=args.scheduler, resume=args.resume, item_timeout=args.item_timeout,
                  progress=not getattr(args, "log_quiet", False))  # -q: no progress counter
    shown = 20
    for item, reason in r.errors[:shown]:
        print(f"arsurf batch: failed: {item}: {reason}", file=sys.stderr)
    if len(r.errors) > shown:
        print(f"arsurf batch: ... and {len(r.errors) - shown} more failures (see {r.table})", file=sys.stderr)
    print(f"{r.total} items: {r.ok} ok, {r.failed} failed, {r.total - r.ok - r.failed} not run; {r.ran} run now, "
          f"{r.skipped} done before, in {r.elapsed:.2f} s ({r.items_per_second:.3g} items/s)")
    if r.not_inputs:
        from arsurf.batch.inputs import skipped_note
        from pathlib import Path

        print(skipped_note([Path(n) for n in r.not_inputs]) + f" (listed in {r.summary})")
    print(f"results: {r.table}")
    print(f"summary: {r.summary}")
    return 1 if r.failed else 0
