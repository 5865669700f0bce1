"""Data files shipped inside the package, so ``pip install arsurf`` runs the demo without the sources.

``nanotubes.npz`` is the synthetic scan ``arsurf demo`` and ``arsurf view`` open by default
(:func:`arsurf.scan.synthetic.write_demo_scans` writes it, bit for bit, with the other demo scans
that stay in the source tree's ``scans/``). Files are found with :mod:`importlib.resources`, the
same way from a source checkout, an editable install or a wheel.

Examples
--------
>>> bundled_scan().name
'nanotubes.npz'
>>> bundled_scan().is_file()
True
"""
from __future__ import annotations

import importlib.resources
from pathlib import Path

from arsurf.errors import ScanFileNotFound

__all__ = ["BUNDLED", "bundled_scan"]

#: the scans shipped with the package (stem -> file name)
BUNDLED = {"nanotubes": "nanotubes.npz"}


def bundled_scan(name: str = "nanotubes") -> Path:
    """Path of a scan shipped with the package (default: the demo's nanotubes).

    Parameters
    ----------
    name : str
        One of :data:`BUNDLED`.

    Returns
    -------
    pathlib.Path
        A file on disk (installed packages are folders; a zipped install is not supported).

    Raises
    ------
    ScanFileNotFound
        An unknown name, or an installation that lacks the file.
    """
    if name not in BUNDLED:
        raise ScanFileNotFound(f"no bundled scan {name!r}; the package ships {', '.join(sorted(BUNDLED))}")
    resource = importlib.resources.files(__name__) / BUNDLED[name]
    path = Path(str(resource))
    if not path.is_file():
        raise ScanFileNotFound(f"the bundled scan {BUNDLED[name]!r} is missing from {path.parent}; the installation is "
                               "incomplete: reinstall arsurf (pip install --force-reinstall arsurf)")
    return path
