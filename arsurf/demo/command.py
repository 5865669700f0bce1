"""The ``arsurf demo`` command: the nanotube demo (:func:`arsurf.demo.nanotubes.run_demo`), or with
``--material FILE`` the material demo (:func:`arsurf.demo.material.run_material_demo`)."""
from __future__ import annotations

from arsurf.assembly import BUNDLED_SCAN
from arsurf.demo.material import run_material_demo
from arsurf.demo.nanotubes import run_demo
from arsurf.demo.scripted import TIP_RADIUS
from arsurf.units import summary_json

__all__ = ["register"]


def register(sub) -> None:
    """Add ``arsurf demo`` to the CLI."""
    from arsurf.contact.material_conversion import MaterialConversion

    p = sub.add_parser("demo", help="run the full pipeline on a bundled scan, headless (the main job); --material "
                       "FILE: feel a PeakForce QNM file's soft, stiff and sticky regions")
    p.add_argument("--out", default="out/demo", help="output folder")
    p.add_argument("--scan", default=str(BUNDLED_SCAN), help="scan file (default: the bundled nanotubes)")
    p.add_argument("--seconds", type=float, default=6.0, help="simulated session length")
    p.add_argument("--no-images", action="store_true", help="skip the PNG views")
    from arsurf.replay.plots import add_figure_arguments

    add_figure_arguments(p)
    p.add_argument("--material", metavar="FILE", help="run the material demo on this file's mechanical channels "
                   "(DMTModulus, Adhesion...; uncalibrated channels need the conversion flags below)")
    MaterialConversion.cli_arguments(p, tip_radius_nm=TIP_RADIUS * 1e9)
    p.add_argument("--material-sigma-nm", type=float, default=None, metavar="NM",
                   help="Gaussian smoothing of the material map, nm (default: half the tip radius)")
    p.add_argument("--zone-energy", action="store_true",
                   help="with --material: the model's contact the energy of the whole tip, each surface element with "
                        "the map's local law (arsurf.contact.zone_energy; measured, not yet the default)")
    p.set_defaults(func=_cmd)


def _cmd(args) -> int:
    if args.zone_energy and args.material is None:
        from arsurf.errors import ContactError

        raise ContactError("--zone-energy runs the material demo: give --material FILE too")
    if args.material is not None:
        from arsurf.contact.material_conversion import MaterialConversion

        summary = run_material_demo(args.out, args.material, MaterialConversion.from_cli(args),
                                    MaterialConversion.cli_channels(args), images=not args.no_images,
                                    handle_signals=True,
                                    sigma=None if args.material_sigma_nm is None else args.material_sigma_nm * 1e-9,
                                    zone_energy=args.zone_energy)
    else:
        summary = run_demo(args.out, args.scan, args.seconds, images=not args.no_images, handle_signals=True,
                           figure_format=args.figure_format, dpi=args.dpi)
    print(summary_json(summary), end="")
    print(f"results in {args.out}/")
    return 0
