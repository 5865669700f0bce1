"""The front of the pipeline in one call: load -> inpaint NaN -> level -> smooth."""
from __future__ import annotations


def prepare_scan(path, channel=None, level_method="plane", sigma=0.0, inpaint=True, *, dx=None, dy=None,
                 z_unit=None, frame=None, as_height=False):
    """Load a scan file and make it ready for :func:`arsurf.fit_surface`.

    Parameters
    ----------
    path : path-like
    channel : str, optional
        Channel name (default: the topography).
    level_method : str or None
        :func:`arsurf.level` method, or ``None``/``"none"`` for no levelling.
    sigma : float, metres
        Gaussian smoothing width (0: none).
    inpaint : bool
        Fill NaN pixels by :func:`arsurf.inpaint` (False: leave them; the fit then refuses).
    dx, dy : float, metres, optional
        Pixel spacing of a file that does not state it (a bare matrix): :func:`arsurf.load_scan`.
    z_unit : str, optional
        Unit of the values of such a file (``"nm"``, ``"m"``...).
    frame : int, optional
        Frame of a movie (``.asd``, ``.h5-jpk``), from 0: :func:`arsurf.load_scan`.
    as_height : bool
        Use a channel in metres that its file names as another quantity as a height
        (:meth:`Scan.as_height`); without it :func:`arsurf.fit_surface` refuses such a channel.

    Returns
    -------
    Scan
        With every step recorded in ``metadata["history"]``. The CLI (``arsurf fit``), the demo
        and :func:`arsurf.assembly.build_model` all call this one function, so a replay
        rebuilds exactly the surface the recording used.
    """
    from arsurf.scan.io import load_scan
    from arsurf.scan.level import level
    from arsurf.scan.smooth import smooth

    scan = load_scan(path, channel=channel, dx=dx, dy=dy, z_unit=z_unit, frame=frame)
    if as_height:
        scan = scan.as_height()
    if scan.nan_count and inpaint:
        from arsurf.scan.inpaint import inpaint as fill

        scan = fill(scan)
    if level_method and level_method != "none":
        scan = level(scan, level_method)
    if sigma > 0.0:
        scan = smooth(scan, sigma)
    return scan
