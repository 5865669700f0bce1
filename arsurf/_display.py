"""How arsurf's records show themselves in a notebook: a small table and a thumbnail PNG.

IPython asks an object for ``_repr_html_`` (Jupyter, VS Code) or ``_repr_png_`` (qtconsole);
:class:`~arsurf.scan.scan.Scan`, :class:`~arsurf.spline.surface.BSplineSurface`,
:class:`~arsurf.sessions.reader.Session` and :class:`~arsurf.replay.replay.ReplayResult` answer with
the helpers here. Values are shown with an SI prefix and their unit (``12.5 nm``, ``3.2 nN``), maps
with axes and a colour bar in units, colour limits from robust percentiles (1-99 %: one speck
does not wash out the map), a perceptually uniform colour map (viridis), at most
:data:`THUMB_PIXELS` samples a side whatever the size of the data. Text from files (channel
names, paths) is HTML-escaped. matplotlib is imported only when a picture is asked for.

Examples
--------
>>> quantity(1.25e-8, "m"), quantity(3.2e-9, "N"), quantity(0.5, "rad"), quantity(float("nan"), "m")
('12.5 nm', '3.2 nN', '0.5 rad', 'n/a')
"""
from __future__ import annotations

import base64
import html
import io
import math
import warnings

import numpy as np

__all__ = ["THUMB_PIXELS", "prefix", "quantity", "robust_limits", "card", "map_png", "series_png"]

#: largest number of samples along either side of a thumbnail map
THUMB_PIXELS = 200
#: thumbnail figure size, inches, and resolution: 288 x 216 pixels
_FIGSIZE = (3.6, 2.7)
_DPI = 80
#: units that take an SI prefix (others, e.g. rad or a channel's own unit, are printed as they are)
_PREFIXED = {"m", "N", "s", "Pa", "J", "Hz", "V", "A", "W"}
_PREFIXES = ((1e9, "G"), (1e6, "M"), (1e3, "k"), (1.0, ""), (1e-3, "m"), (1e-6, "µ"), (1e-9, "n"), (1e-12, "p"),
             (1e-15, "f"))


def prefix(value: float, unit: str) -> tuple[float, str]:
    """(scale, unit text) to show ``value`` with: ``value / scale`` lies in [1, 1000) when it can."""
    if unit not in _PREFIXED or not math.isfinite(value) or value == 0.0:
        return 1.0, unit
    a = abs(value)
    for scale, p in _PREFIXES:
        if a >= scale * 0.9995:
            return scale, p + unit
    return _PREFIXES[-1][0], _PREFIXES[-1][1] + unit


def quantity(value, unit: str, digits: int = 4) -> str:
    """``value`` (SI) as text with an SI prefix: ``quantity(1.25e-8, "m") == "12.5 nm"``."""
    try:
        value = float(value)
    except (TypeError, ValueError):
        return "n/a" if value is None else f"{value} {unit}"
    if not math.isfinite(value):
        return "n/a"
    scale, shown = prefix(value, unit)
    return f"{value / scale:.{digits}g} {shown}".rstrip()


def card(title: str, rows, image: bytes | None = None) -> str:
    """An HTML card: a bold title, a two-column table of ``rows`` ((label, text) pairs; the texts
    are escaped here), and the PNG ``image`` beside it when given."""
    cells = "".join(f"<tr><th style='text-align:left;padding-right:1em'>{html.escape(str(k))}</th>"
                    f"<td style='text-align:left'>{html.escape(str(v))}</td></tr>" for k, v in rows)
    table = f"<table>{cells}</table>"
    picture = ""
    if image is not None:
        data = base64.b64encode(image).decode("ascii")
        picture = f"<td style='vertical-align:top'><img src='data:image/png;base64,{data}' alt='thumbnail'/></td>"
    return (f"<div class='arsurf-repr'><b>{html.escape(title)}</b><table><tr>"
            f"<td style='vertical-align:top'>{table}</td>{picture}</tr></table></div>")


def _figure():
    from matplotlib.figure import Figure

    return Figure(figsize=_FIGSIZE, dpi=_DPI, layout="constrained")


def _png(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=_DPI, metadata={"Software": None})  # no version text: same bytes
    return buf.getvalue()


def _block_mean(values: np.ndarray, limit: int) -> np.ndarray:
    """Average ``values`` over square blocks so that neither side exceeds ``limit`` (NaN-aware)."""
    step = max(1, math.ceil(max(values.shape) / limit))
    if step == 1:
        return values
    ny, nx = (values.shape[0] // step) * step, (values.shape[1] // step) * step
    blocks = values[:ny, :nx].reshape(ny // step, step, nx // step, step)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN blocks stay NaN
        return np.nanmean(blocks, axis=(1, 3))


def robust_limits(values: np.ndarray) -> tuple[float, float]:
    """Colour limits: the 1st and 99th percentiles of the finite values (min/max when they coincide)."""
    finite = values[np.isfinite(values)]
    if finite.size == 0:
        return 0.0, 1.0
    lo, hi = np.percentile(finite, [1.0, 99.0])
    if hi <= lo:
        lo, hi = float(finite.min()), float(finite.max())
    if hi <= lo:
        lo, hi = lo - 0.5, hi + 0.5
    return float(lo), float(hi)


def map_png(values, extent, unit: str, label: str, contours=None) -> bytes:
    """A thumbnail of a map ``values[iy, ix]`` (SI) over ``extent`` = (x0, x1, y0, y1) metres.

    Parameters
    ----------
    values : (ny, nx) float
        The map; row 0 at the bottom (y up), NaN for missing samples.
    extent : (x0, x1, y0, y1) float, metres
        Where the first and last samples sit.
    unit : str
        Unit of ``values`` (``"m"`` for heights).
    label : str
        What the colour bar shows (``"height"``).
    contours : (ny, nx) float, optional
        A second layer drawn as white contours over the map (a dent over the topography).

    Returns
    -------
    bytes
        PNG, at most 288 x 216 pixels.
    """
    z = _block_mean(np.asarray(values, dtype=np.float64), THUMB_PIXELS)
    x0, x1, y0, y1 = (float(v) for v in extent)
    lo, hi = robust_limits(z)
    zs, zu = prefix(max(abs(lo), abs(hi)), unit)
    ls, lu = prefix(max(abs(x1 - x0), abs(y1 - y0)), "m")
    fig = _figure()
    ax = fig.add_subplot()
    image = ax.imshow(z / zs, origin="lower", extent=(x0 / ls, x1 / ls, y0 / ls, y1 / ls), cmap="viridis",
                      vmin=lo / zs, vmax=hi / zs, interpolation="nearest", aspect="equal")
    if contours is not None:
        c = _block_mean(np.asarray(contours, dtype=np.float64), THUMB_PIXELS)
        if np.isfinite(c).any() and np.nanmax(np.abs(c)) > 0.0:
            level = 0.1 * np.nanmax(np.abs(c))
            ax.contour(np.linspace(x0, x1, c.shape[1]) / ls, np.linspace(y0, y1, c.shape[0]) / ls, np.abs(c),
                       levels=[level], colors="white", linewidths=0.8)
    ax.set_xlabel(f"x ({lu})", fontsize=8)
    ax.set_ylabel(f"y ({lu})", fontsize=8)
    ax.tick_params(labelsize=7)
    bar = fig.colorbar(image, ax=ax, shrink=0.9)
    bar.set_label(f"{label} ({zu})" if zu else label, fontsize=8)
    bar.ax.tick_params(labelsize=7)
    return _png(fig)


def series_png(t, curves, unit: str, label: str, shade=None) -> bytes:
    """A thumbnail of time series: ``curves`` {name: (n,) values in ``unit``} against ``t`` (n,) s.

    ``shade`` (n,) bool: the ticks shaded grey (in contact). Non-finite samples are gaps.
    """
    t = np.asarray(t, dtype=np.float64)
    peak = max((float(np.nanmax(np.abs(y))) for y in curves.values() if np.isfinite(y).any()), default=0.0)
    ys, yu = prefix(peak, unit)
    fig = _figure()
    ax = fig.add_subplot()
    if shade is not None and np.any(shade) and t.size:
        ax.fill_between(t, 0, 1, where=np.asarray(shade, bool), color="0.85", transform=ax.get_xaxis_transform(),
                        step="mid", label="contact")
    for name, y in curves.items():
        ax.plot(t, np.asarray(y, dtype=np.float64) / ys, lw=0.9, label=name)
    ax.set_xlabel("t (s)", fontsize=8)
    ax.set_ylabel(f"{label} ({yu})" if yu else label, fontsize=8)
    ax.tick_params(labelsize=7)
    ax.legend(fontsize=7, loc="best", frameon=False)
    return _png(fig)
