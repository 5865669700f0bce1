"""The command line's shared argument types and flags (lengths in nm at this edge, SI inside).

argparse ``type=`` parsers (:func:`_nm`, :func:`_count`, :func:`_positive`...), the flag groups
several commands share (processing, calibration, frame), the scan preparation behind them and the
``--record`` target check of ``arsurf view`` and ``arsurf live``.
"""
from __future__ import annotations

import argparse

import numpy as np

from arsurf._validation import positive_arg
from arsurf.scan.level import METHODS as _LEVEL_METHODS
from arsurf.scan.prepare import prepare_scan


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors: ``arsurf fit: error: argument --sigma-nm: ...`` (exit 2)."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")

#: what --level accepts: every arsurf.level method, and none
LEVEL_CHOICES = (*_LEVEL_METHODS, "none")


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


#: picture sizes ``--size`` accepts, pixels per side
PICTURE_SIDE = (64, 8192)


def _picture_size(text: str) -> tuple[int, int]:
    """An argparse type: a picture size ``WxH`` in pixels (e.g. ``2100x1500``: 7 x 5 in at 300 dpi)."""
    w, sep, h = text.lower().partition("x")
    try:
        size = (int(w), int(h)) if sep else None
    except ValueError:
        size = None
    if size is None or not all(PICTURE_SIDE[0] <= v <= PICTURE_SIDE[1] for v in size):
        raise argparse.ArgumentTypeError(f"must be WIDTHxHEIGHT in pixels, each {PICTURE_SIDE[0]}-{PICTURE_SIDE[1]} "
                                         f"(e.g. 2100x1500; got {text!r})")
    return size


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


_positive = positive_arg  # an argparse type: a positive finite number in a unit


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


def _protection_flags(s) -> None:
    """``--no-virtual-coupling``, ``--no-passivity`` and ``--no-jump-blend``: the loop's protections are
    on unless turned off here, and a session records which (``haptics.virtual_coupling``,
    ``haptics.passivity``, ``haptics.jump_blend``)."""
    g = s.add_argument_group("protections (on by default; turning one off is recorded in the session)")
    g.add_argument("--no-virtual-coupling", dest="virtual_coupling", action="store_false",
                   help="run without the virtual coupling (the spring, chosen from the device's limits and the "
                        "1 kHz rate, through which the hand feels the contact): the hand feels the sample's "
                        "stiffness, which can buzz on a rough scan")
    g.add_argument("--no-passivity", dest="passivity", action="store_false",
                   help="run without the passivity controller (the observer still logs the energy)")
    g.add_argument("--no-jump-blend", dest="jump_blend", action="store_false",
                   help="render a jump of the tip behind the coupling (a snap over an asperity) in one tick, a "
                        "step of the force, instead of over 15 ms")


def _contact_flag(s) -> None:
    """``--zone-energy``: the model's contact the energy of the whole tip; ``--zone-sum``: summed over
    the lattice everywhere, not in closed form where trusted (both recorded in the session)."""
    s.add_argument("--zone-energy", action="store_true",
                   help="the model's contact the energy of the whole tip summed over the surface "
                        "(arsurf.contact.zone_energy) instead of Maugis-Dugdale contacts at the minima of the "
                        "distance; measured, not yet the default (docs/feel.rst)")
    s.add_argument("--zone-sum", action="store_true",
                   help="with --zone-energy: sum the lattice everywhere, not the energy in closed form where the "
                        "contact is smooth and alone (the same feel, up to four times the tick)")


def _contact_options(args) -> dict:
    """The model's contact of :func:`_contact_flag` as :func:`arsurf.assembly.session_metadata`'s
    ``zone_energy`` and ``zone_closed_form``; ``--zone-sum`` without ``--zone-energy`` refused (one line)."""
    from arsurf.errors import ContactError

    if args.zone_sum and not args.zone_energy:
        raise ContactError("--zone-sum sums the zone energy's lattice everywhere: give --zone-energy too")
    return {"zone_energy": args.zone_energy, "zone_closed_form": not args.zone_sum}


def _protections(args) -> dict:
    """The haptic settings of :func:`_protection_flags`: ``{"virtual_coupling": False}``,
    ``{"passivity": False}`` and/or ``{"jump_blend": 0.0}`` when turned off, else nothing (the
    defaults: on)."""
    off = {k: False for k in ("virtual_coupling", "passivity") if getattr(args, k, True) is False}
    return {**off, "jump_blend": 0.0} if getattr(args, "jump_blend", True) is False else off


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
