"""``arsurf verify SESSION AFTER_SCAN [--before SCAN] [--reseed OUT] [--out DIR]``: the session's
model against the scan after it (:mod:`arsurf.verify.verify`).

Prints the drift and each tube's errors; exit status 0 when the model agrees with the scan, 1
when it is flagged wrong, 2 on an input it cannot use (one line, :mod:`arsurf.cli`).
"""
from __future__ import annotations

import math

from arsurf._validation import positive_arg
from arsurf.errors import VerifyError

__all__ = ["register", "cmd_verify"]


_positive = positive_arg  # an argparse type: a positive finite number in a unit, to SI


def cmd_verify(args) -> int:
    """``arsurf verify``: run :func:`~arsurf.verify.verify.verify_session`, print what it found."""
    from arsurf.verify.verify import verify_session

    if args.blind_tip and args.tip_radius is not None:
        raise VerifyError("give --tip-radius or --blind-tip, not both")
    tip = None if args.blind_tip else (math.nan if args.tip_radius is None else args.tip_radius)
    r = verify_session(args.session, args.after_scan, before_path=args.before, out_dir=args.out, reseed=args.reseed,
                       tip_radius=tip, position_threshold=args.position_threshold,
                       angle_threshold=args.angle_threshold, figure_format=args.figure_format, dpi=args.dpi)
    if not getattr(args, "log_quiet", False):
        g = r.registration
        print(f"drift {g.drift[0] * 1e9:+.2f}, {g.drift[1] * 1e9:+.2f} nm ({g.shift_px[0]:+.2f}, {g.shift_px[1]:+.2f} px) "
              f"at the frame's centre; overlap {g.overlap:.0%}; tip radius {r.tip_radius * 1e9:.2f} nm "
              f"({r.tip_radius_source})")
        for c in r.checks:
            if c.found is None:
                print(f"  tube {c.index}: not found near its predicted pose")
            else:
                print(f"  tube {c.index}{' (moved)' if c.moved else ''}: position error {c.position_error * 1e9:.2f} nm "
                      f"({c.position_error / r.dx:.2f} px), angle error {math.degrees(c.angle_error):+.2f} deg")
        print("model WRONG: " + "; ".join(r.reasons) if r.wrong else
              f"model agrees within {r.position_threshold * 1e9:.1f} nm and {math.degrees(r.angle_threshold):.1f} deg")
        for name, path in r.files.items():
            print(f"  {name}: {path}")
    return 1 if r.wrong else 0


def register(subparsers) -> None:
    """Add the ``verify`` subcommand."""
    s = subparsers.add_parser("verify", help="compare a session's predicted object poses with the scan after it; "
                                             "report the drift and each object's error")
    s.add_argument("session", help="session file (.h5) with a tube scene")
    s.add_argument("after_scan", help="the scan taken after the session (same frame, pixels and channel)")
    s.add_argument("--before", help="the scan before (default: the session's scan file)")
    s.add_argument("--reseed", help="write the next session's starting scene here (.npz: the scan after with the "
                                    "tubes at their measured poses)")
    s.add_argument("--out", help="folder for verify.json and the figure")
    s.add_argument("--tip-radius", type=_positive("nm", 1e-9), help="imaging tip radius in nm (default: the "
                                                                    "session's)")
    s.add_argument("--blind-tip", action="store_true", help="estimate the tip radius from the tubes in the scan")
    s.add_argument("--position-threshold", type=_positive("nm", 1e-9),
                   help="flag the model when a tube is farther than this, nm (default 2 pixels)")
    s.add_argument("--angle-threshold", type=_positive("degrees", math.pi / 180.0),
                   help="flag the model when a tube is turned more than this, degrees (default 2)")
    from arsurf.replay.plots import add_figure_arguments

    add_figure_arguments(s)
    s.set_defaults(func=cmd_verify)
