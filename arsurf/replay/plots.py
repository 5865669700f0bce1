"""Figures of a session (matplotlib, no pyplot): returned as :class:`~matplotlib.figure.Figure`.

- :func:`forces_figure` - the force on the tip, one panel per component in nN against time in
  s, contact shaded, recorded/simulated/measured on the same axes, and a strip of feel and
  safety flags (buzz reversals, saturation, watchdog, passivity) under them;
- :func:`coupled_motion_figure` - probe z and y (nm) and the force sent to the haptic device
  (N), with the same flag strip;
- :func:`path_figure` - the probe's path: the whole scan with the zoom box, and the zoom on
  where the tip went (tubes before dashed, after solid);
- :func:`tubes_figure` - the model of the sample before and after the push, side by side;
- :func:`dent_figure` - the deformed topography with the dent as contour lines, and a profile.

Every function *builds* a figure and returns it (the Agg canvas attached, drawn with the default
style whatever the user's matplotlibrc says), so a user restyles it; :func:`save_figure` writes
it as PNG at any dpi, PDF or SVG, with the same bytes for the same data (no dates, no software
versions, a fixed SVG id salt). Maps follow one convention: lengths in nm with a scale bar,
perceptually uniform colour maps (:data:`HEIGHT_CMAP`), colour limits = the 1st and 99th
percentiles of the data shown (:func:`robust_limits`), the same for panels that are compared,
and a colour bar naming the unit.

Examples
--------
>>> import numpy as np, tempfile, os
>>> t = np.linspace(0, 1, 50); f = np.zeros((50, 3)); f[:, 2] = 1e-9 * np.sin(3 * t)
>>> fig = forces_figure(t, {"recorded": f}, t > 0.5)
>>> save_figure(fig, os.path.join(tempfile.mkdtemp(), "f.svg")).name
'f.svg'
"""
from __future__ import annotations

import argparse
import math
import os
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from arsurf import status
from arsurf._figure_style import HEIGHT_CMAP, PERCENTILES, robust_limits, scale_bar_length
from arsurf._files import atomic_write
from arsurf.errors import FigureError, require

__all__ = ["FORMATS", "DEFAULT_DPI", "HEIGHT_CMAP", "FLAG_ROWS", "FORCE_CAPTION", "robust_limits", "scale_bar_length",
           "add_scale_bar", "save_figure", "check_figure_options", "session_flags", "forces_figure", "coupled_motion_figure", "path_figure",
           "tubes_figure", "dent_figure", "add_figure_arguments"]

#: the file formats :func:`save_figure` writes
FORMATS = ("png", "pdf", "svg")
#: default resolution of PNG output (dots per inch); PDF and SVG are vector
DEFAULT_DPI = 200
DPI_RANGE = (50, 1200)
# the conventions shared with the 3D views (arsurf._figure_style): heights in HEIGHT_CMAP (the dent
# contours in a colour outside it), colour limits at the PERCENTILES of the data shown
#: the rows of the flag strip, top to bottom: (key, label)
FLAG_ROWS = (("buzz", "buzz (reversal)"), ("saturated", "saturated"), ("watchdog", "watchdog"),
             ("passivity", "passivity"))
_METADATA = {"png": {"Software": None}, "pdf": {"Creator": None, "Producer": None, "CreationDate": None},
             "svg": {"Creator": None, "Date": None}}
_STYLES = {"recorded": ("k", "-", 1.2), "simulated": ("tab:blue", "--", 1.0), "measured": ("tab:red", ":", 1.2),
           "tube": ("tab:green", "-.", 1.0)}
#: legend labels of the force curves (the caption says what each is: :data:`FORCE_CAPTION`)
_LABELS = {"tube": "tube reaction"}
#: what the curves and shadings of :func:`forces_figure` are, printed under it
FORCE_CAPTION = {
    "recorded": "recorded: the force on the tip the loop used (session file): the blend of measured and simulated, "
                "low-pass filtered, plus the tubes' reaction",
    "simulated": "simulated: the contact model re-run over the recorded probe path (the substrate only)",
    "measured": "measured: the force decoupled from the recorded angle signals (photodiode noise included)",
    "tube": "tube reaction: the pushed nanotubes' resistance on the tip, from the replayed scene",
}
_TUBE_SHADE = "#f6d7a7"
_FLAG_COLOURS = {"buzz": "tab:red", "saturated": "tab:orange", "watchdog": "tab:purple", "passivity": "tab:blue"}
_PATH, _CONTACT, _BEFORE, _AFTER, _DENT = "white", "#00e5ff", "0.8", "#7CFC00", "#00e5ff"


# ---------------------------------------------------------------------------------------------
# building blocks


def _figure(width: float, height: float):
    """(style module, Figure with an Agg canvas): no pyplot, no global backend switch."""
    style = require("matplotlib.style", "viewer", "figures")
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), dpi=100, layout="constrained")
    FigureCanvasAgg(fig)
    return style, fig


def add_scale_bar(ax, color: str = "white", loc: str = "lower left"):
    """Add a scale bar to a map whose axes are in nm (length from :func:`scale_bar_length` of the
    visible width, labelled in nm or um); returns the artist (gid ``"scale_bar"``, attribute
    ``length_nm``)."""
    from matplotlib import font_manager
    from mpl_toolkits.axes_grid1.anchored_artists import AnchoredSizeBar

    x0, x1 = ax.get_xlim()
    y0, y1 = ax.get_ylim()
    length = scale_bar_length(abs(x1 - x0))
    label = f"{length / 1000:g} µm" if length >= 1000 else f"{length:g} nm"
    bar = AnchoredSizeBar(ax.transData, length, label, loc, pad=0.5, borderpad=0.3, sep=3, color=color,
                          frameon=False, size_vertical=0.012 * abs(y1 - y0), label_top=True,
                          fontproperties=font_manager.FontProperties(size=8, weight="bold"))
    from matplotlib import patheffects

    bar.txt_label._text.set_path_effects([patheffects.withStroke(linewidth=1.5, foreground="black")])
    bar.set_gid("scale_bar")
    bar.length_nm = length
    ax.add_artist(bar)
    return bar


def _map(ax, fig, z_nm: np.ndarray, extent, clim, label: str = "height (nm)", colorbar: bool = True):
    """A map in nm: image (:data:`HEIGHT_CMAP`, ``clim``), equal aspect, nm axes, scale bar, colour bar."""
    im = ax.imshow(z_nm, origin="lower", extent=extent, cmap=HEIGHT_CMAP, vmin=clim[0], vmax=clim[1],
                   interpolation="nearest", aspect="equal")
    ax.set_xlim(extent[0], extent[1])
    ax.set_ylim(extent[2], extent[3])
    ax.set_xlabel("x (nm)")
    ax.set_ylabel("y (nm)")
    add_scale_bar(ax)
    if colorbar:
        fig.colorbar(im, ax=ax, label=label, shrink=0.9)
    return im


def save_figure(fig, path: str | os.PathLike, format: str | None = None, dpi: int = DEFAULT_DPI) -> Path:
    """Write ``fig`` to ``path`` as PNG (``dpi``), PDF or SVG (vector); return the path written.

    ``format`` defaults to the suffix of ``path``; given, the suffix is set to it. Output is
    deterministic: no creation date, no software text, a fixed SVG id salt.
    """
    import matplotlib

    path = Path(path)
    fmt = str(format or path.suffix.lstrip(".")).lower()
    dpi = check_figure_options(fmt, dpi)
    path = path.with_suffix("." + fmt)
    with matplotlib.rc_context({"svg.hashsalt": "arsurf", "svg.fonttype": "path", "pdf.fonttype": 42}):
        with atomic_write(path, what="figure", error=FigureError) as fh:
            fig.savefig(fh, format=fmt, dpi=dpi, metadata=_METADATA[fmt])
    return path


def check_figure_options(fmt: str, dpi=None) -> int:
    """Check a figure format (one of :data:`FORMATS`) and PNG resolution; return the dpi
    (:data:`DEFAULT_DPI` for None). Raises :class:`~arsurf.errors.FigureError`."""
    if fmt not in FORMATS:
        raise FigureError(f"figure format must be one of {', '.join(FORMATS)} (got {fmt!r})")
    return _check_dpi(DEFAULT_DPI if dpi is None else dpi)


def _check_dpi(dpi) -> int:
    try:
        value = int(dpi)
    except (TypeError, ValueError):
        raise FigureError(f"dpi must be a whole number of dots per inch (got {dpi!r})") from None
    if value != dpi or not DPI_RANGE[0] <= value <= DPI_RANGE[1]:
        raise FigureError(f"dpi must be a whole number in [{DPI_RANGE[0]}, {DPI_RANGE[1]}] (got {dpi!r})")
    return value


def add_figure_arguments(parser) -> None:
    """``--format {png,pdf,svg}`` and ``--dpi N`` (PNG resolution) on a command line."""
    def dpi(text: str) -> int:
        try:
            return _check_dpi(int(text))
        except (ValueError, FigureError):
            raise argparse.ArgumentTypeError(f"must be a whole number of dots per inch in [{DPI_RANGE[0]}, "
                                             f"{DPI_RANGE[1]}] (got {text!r})") from None
    parser.add_argument("--format", choices=FORMATS, default="png", dest="figure_format",
                        help="figure file format: png (raster, --dpi), pdf or svg (vector); default png")
    parser.add_argument("--dpi", type=dpi, default=DEFAULT_DPI,
                        help=f"resolution of PNG figures, dots per inch (default {DEFAULT_DPI})")


# ---------------------------------------------------------------------------------------------
# time series


def session_flags(t, device_force=None, safety_flags=None, passivity_damping=None, energy=None,
                  in_contact=None, energy_reserve: float = 0.0) -> tuple[dict, object]:
    """Per-tick feel and safety flags of a session, and its feel score.

    Parameters
    ----------
    t : (n,) float, s
    device_force : (n, 3) float, N, optional
        Force sent to the device: the feel is :func:`arsurf.haptics.feel.score_session` of it (the
        window from the first contact tick); ``buzz`` marks the ticks it counts as reversals.
    safety_flags : (n,) int, optional
        The loop's flag word (:mod:`arsurf.status`); negative: not recorded.
    passivity_damping : (n,) float, N s/m, optional
        Used for ``passivity`` when the flag word is not recorded.
    energy, in_contact : (n,), optional
        Passed to the feel score.
    energy_reserve : float, J
        The passive store the feel score allows (:func:`~arsurf.haptics.feel.score_force`).

    Returns
    -------
    flags : dict key -> (n,) bool or None (not recorded), keys of :data:`FLAG_ROWS`
    feel : FeelScore or None (no usable device force)
    """
    from arsurf.haptics.feel import reversal_ticks, score_session

    t = np.asarray(t, dtype=np.float64)
    n = t.size
    flags: dict = {key: None for key, _ in FLAG_ROWS}
    word = None if safety_flags is None else np.asarray(safety_flags).astype(np.int64)
    if word is not None and word.shape == (n,) and n and (word >= 0).all():
        flags["saturated"] = (word & status.SATURATED) != 0
        flags["watchdog"] = (word & status.WATCHDOG) != 0
        flags["passivity"] = (word & status.PASSIVITY) != 0
    elif passivity_damping is not None:
        d = np.asarray(passivity_damping, dtype=np.float64)
        if d.shape == (n,) and np.isfinite(d).all():
            flags["passivity"] = d > 0.0
    feel = None
    f = None if device_force is None else np.asarray(device_force, dtype=np.float64)
    if f is not None and f.shape == (n, 3) and n > 2:
        dt = float(np.median(np.diff(t)))
        feel = score_session(f, dt, contact=in_contact, energy=energy, energy_reserve=energy_reserve)
        if feel is not None:
            flags["buzz"] = reversal_ticks(f, dt, settle=feel.start)
    return flags, feel


def _shade_contact(ax, t: np.ndarray, in_contact: np.ndarray, label: bool, color: str = "0.88",
                   name: str = "contact") -> None:
    """Bands of ``color`` where ``in_contact`` (one artist, stepwise over the tick times)."""
    mask = np.asarray(in_contact, dtype=bool)
    if t.size and mask.any():
        ax.fill_between(t, 0.0, 1.0, where=mask, step="post", color=color, linewidth=0.0,
                        transform=ax.get_xaxis_transform(), label=name if label else None, zorder=0)


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) index pairs of the True runs of ``mask``."""
    m = np.concatenate([[False], np.asarray(mask, bool), [False]])
    edges = np.flatnonzero(np.diff(m.astype(np.int8)))
    return list(zip(edges[::2], edges[1::2]))


def _flag_strip(ax, t: np.ndarray, flags: Mapping | None, feel=None) -> None:
    """One row per flag of :data:`FLAG_ROWS`: bars where it is set, "not recorded" / "none"."""
    flags = flags or {}
    span = float(t[-1] - t[0]) if t.size > 1 else 1.0
    dt = float(np.median(np.diff(t))) if t.size > 1 else 1.0
    min_width = max(dt, 0.003 * span)  # a single tick stays visible at print size
    rows = len(FLAG_ROWS)
    for i, (key, label) in enumerate(FLAG_ROWS):
        y = rows - 1 - i
        mask = flags.get(key)
        if mask is None:
            ax.text(t[0] + 0.01 * span if t.size else 0.0, y, "not recorded", va="center", fontsize=7, color="0.45")
            continue
        mask = np.asarray(mask, bool)
        runs = _runs(mask)
        if not runs:
            ax.text(t[0] + 0.01 * span, y, "none", va="center", fontsize=7, color="0.45")
            continue
        bars = [(t[a], max(t[min(b, t.size - 1)] - t[a], min_width)) for a, b in runs]
        ax.broken_barh(bars, (y - 0.35, 0.7), facecolors=_FLAG_COLOURS[key], linewidth=0, gid=f"flag_{key}")
        ax.text(1.005, y, f"{int(mask.sum())}", transform=ax.get_yaxis_transform(), va="center", fontsize=7)
    ax.set_yticks(range(rows), [label for _, label in FLAG_ROWS][::-1], fontsize=8)
    ax.set_ylim(-0.6, rows - 0.4)
    ax.grid(True, axis="x", linewidth=0.3)
    ax.set_ylabel("flags (ticks)", fontsize=8)
    if feel is not None:
        hf = "/".join(f"{100 * x:.2f}" for x in feel.high_frequency)
        ax.set_title(f"feel ({feel.window:.2f} s scored): {'BUZZES' if feel.buzzes else 'smooth'}; above 100 Hz "
                     f"{hf} % of the mean normal force (x/y/z); {int(feel.reversals.sum())} reversals",
                     fontsize=7.5, loc="left")


def _time_panels(fig, n_panels: int, flags_row: bool):
    ratios = [3.0] * n_panels + ([1.6] if flags_row else [])
    return fig.subplots(len(ratios), 1, sharex=True, gridspec_kw={"height_ratios": ratios})


def forces_figure(t, forces: Mapping[str, np.ndarray], in_contact=None, flags: Mapping | None = None, feel=None,
                  title: str | None = None, tube_contact=None):
    """Force components in nN against time (s), one panel per component, contact shaded, the
    feel and safety flags (:func:`session_flags`) in a strip below, and a caption saying what
    each curve and shading is (:data:`FORCE_CAPTION`). 7 in wide: a two-column page's width.

    Parameters
    ----------
    t : (n,) float, s
    forces : dict name -> (n, 3) float, N
        Curves (``recorded``, ``simulated``, ``measured``...); all-NaN ones are skipped.
    in_contact : (n,) bool, optional
        Tip on the substrate: shaded grey.
    flags : dict key -> (n,) bool or None, optional
        No strip when None.
    feel : FeelScore, optional
        Its verdict above the strip.
    title : str, optional
    tube_contact : (n,) bool, optional
        Tip touching a tube (its reaction is not zero): shaded light orange.

    Returns
    -------
    matplotlib.figure.Figure
    """
    style, fig = _figure(7.0, 8.3 if flags is not None else 7.3)
    t = np.asarray(t, dtype=np.float64)
    contact = np.zeros(t.shape, bool) if in_contact is None else np.asarray(in_contact, dtype=bool)
    tubes = np.zeros(t.shape, bool) if tube_contact is None else np.asarray(tube_contact, dtype=bool)
    drawn = []
    with style.context("default"):
        axes = _time_panels(fig, 3, flags is not None)
        names = ("F$_x$ (lateral)", "F$_y$ (lateral)", "F$_z$ (normal)")
        for k, ax in enumerate(axes[:3]):
            _shade_contact(ax, t, contact, label=k == 0)
            _shade_contact(ax, t, tubes & ~contact, label=k == 0, color=_TUBE_SHADE, name="tube contact only")
            for name, f in forces.items():
                f = np.asarray(f, dtype=np.float64)
                if f.shape != (t.size, 3) or not np.isfinite(f[:, k]).any():
                    continue
                color, ls, lw = _STYLES.get(name, (None, "-", 1.0))
                ax.plot(t, f[:, k] * 1e9, color=color, linestyle=ls, linewidth=lw, label=_LABELS.get(name, name))
                if name not in drawn:
                    drawn.append(name)
            lo, hi = ax.dataLim.y0, ax.dataLim.y1
            if ax.lines and np.isfinite([lo, hi]).all() and hi - lo < 1e-3:  # a flat component (< 1 pN):
                mid = 0.5 * (lo + hi)                                     # no offset-scaled round-off noise
                ax.set_ylim(mid - 1.0, mid + 1.0)
            ax.set_ylabel(f"{names[k]} (nN)")
            ax.grid(True, linewidth=0.3)
        if flags is not None:
            _flag_strip(axes[3], t, flags, feel)
        if title:
            fig.suptitle(title)
        axes[-1].set_xlabel("time (s)")
        handles, labels = axes[0].get_legend_handles_labels()
        if handles:  # above the panels, clear of the curves
            fig.legend(handles, labels, loc="outside upper center", fontsize=8, ncol=len(handles), frameon=False)
        lines = [FORCE_CAPTION[name] for name in drawn if name in FORCE_CAPTION]
        shading = ["grey: the tip on the substrate"] if contact.any() else []
        if (tubes & ~contact).any():
            shading.append("orange: the tip touching a tube only")
        if shading:
            lines.append("shading: " + "; ".join(shading))
        if lines:
            fig.supxlabel("\n".join(lines), x=0.01, ha="left", fontsize=7, color="0.2", linespacing=1.35)
    return fig


def coupled_motion_figure(t, probe_position, device_force, in_contact=None, flags: Mapping | None = None,
                          feel=None):
    """Probe z (nm), device force z (mN), probe y (nm), device force y (mN) against time (s),
    contact shaded, the feel and safety flags in a strip below (when given).

    Parameters
    ----------
    t : (n,) float, s
    probe_position : (n, 3) float, m
    device_force : (n, 3) float, N (NaN where the loop recorded none)
    in_contact : (n,) bool, optional
    flags, feel : as :func:`forces_figure`

    Returns
    -------
    matplotlib.figure.Figure
    """
    style, fig = _figure(7.0, 8.5 if flags is not None else 7.5)
    t = np.asarray(t, dtype=np.float64)
    p = np.asarray(probe_position, dtype=np.float64)
    d = np.asarray(device_force, dtype=np.float64)
    contact = np.zeros(t.shape, bool) if in_contact is None else np.asarray(in_contact, dtype=bool)
    panels = ((p[:, 2] * 1e9, "probe z (nm)"), (d[:, 2] * 1e3, "device F$_z$ (mN)"),
              (p[:, 1] * 1e9, "probe y (nm)"), (d[:, 1] * 1e3, "device F$_y$ (mN)"))
    with style.context("default"):
        axes = _time_panels(fig, 4, flags is not None)
        for k, (ax, (y, label)) in enumerate(zip(axes, panels)):
            _shade_contact(ax, t, contact, label=k == 0)
            if np.isfinite(y).any():
                ax.plot(t, y, color="k", linewidth=1.0)
            else:
                ax.text(0.5, 0.5, "not recorded", transform=ax.transAxes, ha="center", va="center", color="0.4")
            ax.set_ylabel(label)
            ax.grid(True, linewidth=0.3)
        if flags is not None:
            _flag_strip(axes[4], t, flags, feel)
        axes[-1].set_xlabel("time (s)")
        if contact.any():
            axes[0].legend(loc="upper right", fontsize=8)
    return fig


# ---------------------------------------------------------------------------------------------
# maps


def _extent(shape, dx: float, dy: float, x0: float = 0.0, y0: float = 0.0) -> tuple:
    """imshow extent in nm of pixels centred at x0 + ix dx, y0 + iy dy (metres)."""
    ny, nx = shape
    return ((x0 - 0.5 * dx) * 1e9, (x0 + (nx - 0.5) * dx) * 1e9, (y0 - 0.5 * dy) * 1e9, (y0 + (ny - 0.5) * dy) * 1e9)


def _box(points_nm: np.ndarray, limits, pad_nm: float, min_aspect: float = 0.6) -> tuple:
    """(x0, x1, y0, y1) nm: the bounding box of ``points_nm`` padded, fattened to ``min_aspect``
    and kept inside ``limits``."""
    x0, y0 = np.nanmin(points_nm, axis=0)
    x1, y1 = np.nanmax(points_nm, axis=0)
    w, h = x1 - x0, y1 - y0
    pad = max(pad_nm, 0.15 * max(w, h))
    x0, x1, y0, y1 = x0 - pad, x1 + pad, y0 - pad, y1 + pad
    w, h = x1 - x0, y1 - y0
    if w < min_aspect * h:
        x0, x1 = x0 - 0.5 * (min_aspect * h - w), x1 + 0.5 * (min_aspect * h - w)
    elif h < min_aspect * w:
        y0, y1 = y0 - 0.5 * (min_aspect * w - h), y1 + 0.5 * (min_aspect * w - h)
    lx0, lx1, ly0, ly1 = limits
    return max(x0, lx0), min(x1, lx1), max(y0, ly0), min(y1, ly1)


def _outline(tube, n: int = 24) -> np.ndarray:
    """(m, 2) nm: the footprint of a capsule (its outline seen from above)."""
    a, b = tube.endpoints[0][:2], tube.endpoints[1][:2]
    u = tube.direction
    base = math.atan2(u[1], u[0])
    cap_b = base + np.linspace(-0.5 * np.pi, 0.5 * np.pi, n)
    cap_a = base + np.linspace(0.5 * np.pi, 1.5 * np.pi, n)
    r = tube.radius
    pts = np.concatenate([b + r * np.c_[np.cos(cap_b), np.sin(cap_b)], a + r * np.c_[np.cos(cap_a), np.sin(cap_a)]])
    return np.vstack([pts, pts[:1]]) * 1e9


def _draw_tubes(ax, before: Sequence, after: Sequence) -> None:
    for k, tube in enumerate(before):
        o = _outline(tube)
        ax.plot(o[:, 0], o[:, 1], color=_BEFORE, linestyle="--", linewidth=0.9, label="tube before" if k == 0 else None)
    for k, tube in enumerate(after):
        o = _outline(tube)
        ax.plot(o[:, 0], o[:, 1], color=_AFTER, linewidth=1.1, label="tube after" if k == 0 else None)


def _draw_path(ax, p_nm: np.ndarray, contact: np.ndarray, tip_radius: float | None) -> None:
    ax.plot(p_nm[:, 0], p_nm[:, 1], color=_PATH, linewidth=0.9, label="tip path")
    if contact.any():
        c = p_nm.copy()
        c[~contact] = np.nan
        ax.plot(c[:, 0], c[:, 1], color=_CONTACT, linewidth=2.2, label="in contact")
    ax.plot(*p_nm[0, :2], "o", color="tab:green", markersize=5, markeredgecolor="k", label="start")
    ax.plot(*p_nm[-1, :2], "s", color="tab:blue", markersize=5, markeredgecolor="k", label="end")
    if tip_radius:
        from matplotlib.patches import Circle

        ax.add_patch(Circle(tuple(p_nm[-1, :2]), tip_radius * 1e9, fill=False, color=_PATH, linestyle=":",
                            linewidth=0.8, label="tip radius"))


def _moved(before: Sequence, after: Sequence) -> list[int]:
    return [i for i, (a, b) in enumerate(zip(before, after)) if a.pose != b.pose]


def path_figure(heights, dx: float, dy: float, probe_position, in_contact=None, tubes_before: Sequence = (),
                tubes_after: Sequence = (), tip_radius: float | None = None):
    """The probe's path: (a) the whole scan with the zoom box, (b) the zoom on where the tip went
    (its path padded by 3 tip radii), path white, in contact cyan, tubes before dashed, after solid.

    Parameters
    ----------
    heights : (ny, nx) float, m
        The height map (``heights[iy, ix]`` at x = ix dx, y = iy dy).
    dx, dy : float, m
    probe_position : (n, 3) float, m
    in_contact : (n,) bool, optional
    tubes_before, tubes_after : sequences of :class:`~arsurf.manipulation.nanotube.Nanotube`
    tip_radius : float, m, optional
        Drawn as a circle at the end of the path.

    Returns
    -------
    matplotlib.figure.Figure
        Both maps share the colour limits (:func:`robust_limits` of the scan).
    """
    style, fig = _figure(9.0, 4.4)
    z = np.asarray(heights, dtype=np.float64) * 1e9
    p = np.asarray(probe_position, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or p.shape[0] == 0:
        raise FigureError(f"probe_position must be (n >= 1, 3) metres (got shape {p.shape})")
    p_nm = p * 1e9
    contact = np.zeros(p.shape[0], bool) if in_contact is None else np.asarray(in_contact, dtype=bool)
    extent = _extent(z.shape, dx, dy)
    clim = robust_limits(z)
    pad = max(3.0 * (tip_radius or 0.0) * 1e9, 5.0 * max(dx, dy) * 1e9)
    box = _box(p_nm[:, :2], extent, pad)
    with style.context("default"):
        ax0, ax1 = fig.subplots(1, 2, gridspec_kw={"width_ratios": [1.0, 1.25]})
        _map(ax0, fig, z, extent, clim, colorbar=False)
        from matplotlib.patches import Rectangle

        ax0.add_patch(Rectangle((box[0], box[2]), box[1] - box[0], box[3] - box[2], fill=False, color=_CONTACT,
                                linewidth=1.2))
        _draw_tubes(ax0, tubes_before, tubes_after)
        ax0.set_title("(a) scan", loc="left", fontsize=9)
        _map(ax1, fig, z, extent, clim)
        _draw_tubes(ax1, tubes_before, tubes_after)
        _draw_path(ax1, p_nm, contact, tip_radius)
        ax1.set_xlim(box[0], box[1])
        ax1.set_ylim(box[2], box[3])
        for art in [a for a in ax1.artists if a.get_gid() == "scale_bar"]:
            art.remove()
        add_scale_bar(ax1)  # for the zoomed width
        ax1.set_title("(b) where the tip went", loc="left", fontsize=9)
        handles, labels = ax1.get_legend_handles_labels()
        fig.legend(handles, labels, loc="outside lower center", ncol=len(handles), fontsize=7, facecolor="0.3",
                   edgecolor="none", labelcolor="white", framealpha=1.0)
    return fig


def _resample(heights: np.ndarray, dx: float, dy: float, box_nm: tuple, samples: int):
    """Heights (m) bilinearly resampled on a regular grid over ``box_nm``; (z, xs, ys) in metres."""
    from scipy.interpolate import RegularGridInterpolator

    ny, nx = heights.shape
    x0, x1, y0, y1 = (v * 1e-9 for v in box_nm)
    step = max(x1 - x0, y1 - y0) / samples
    xs = np.arange(x0 + 0.5 * step, x1, step)
    ys = np.arange(y0 + 0.5 * step, y1, step)
    f = RegularGridInterpolator((np.arange(ny) * dy, np.arange(nx) * dx), heights, bounds_error=False,
                                fill_value=None)
    yy, xx = np.meshgrid(ys, xs, indexing="ij")
    return f(np.stack([yy, xx], axis=-1)), xs, ys, step


def tubes_figure(substrate, dx: float, dy: float, tubes_before: Sequence, tubes_after: Sequence,
                 probe_position=None, in_contact=None, samples: int = 400):
    """The sample's model before and after the push, side by side: the substrate with every tube
    (true shape, :meth:`~arsurf.manipulation.nanotube.Nanotube.height_map`) at its initial and
    final pose, around the tubes that moved (the whole scan when none did); the after panel also
    shows the before outline and the tip path (in contact).

    Parameters
    ----------
    substrate : (ny, nx) float, m
        The height map without the tubes (:meth:`~arsurf.manipulation.scene.TubeScene.substrate`).
    dx, dy : float, m
    tubes_before, tubes_after : sequences of Nanotube (same length)
    probe_position : (n, 3) float, m, optional
    in_contact : (n,) bool, optional
    samples : int
        Grid points along the longer side of the zoom.

    Returns
    -------
    matplotlib.figure.Figure
        Both maps share the colour limits (:func:`robust_limits` of both).
    """
    if len(tubes_before) != len(tubes_after) or not len(tubes_before):
        raise FigureError(f"tubes_figure needs the same tubes before and after (got {len(tubes_before)} and "
                          f"{len(tubes_after)})")
    style, fig = _figure(9.0, 3.9)
    h = np.asarray(substrate, dtype=np.float64)
    extent = _extent(h.shape, dx, dy)
    moved = _moved(tubes_before, tubes_after)
    if moved:
        pts = [_outline(tubes_before[i]) for i in moved] + [_outline(tubes_after[i]) for i in moved]
        if probe_position is not None:
            pts.append(np.asarray(probe_position, dtype=np.float64)[:, :2] * 1e9)
        box = _box(np.vstack(pts), extent, 10.0 * max(dx, dy) * 1e9, min_aspect=0.75)
    else:
        box = extent
    base, xs, ys, step = _resample(h, dx, dy, box, samples)
    xx, yy = np.meshgrid(xs, ys)
    maps = []
    for tubes in (tubes_before, tubes_after):
        z = base.copy()
        for tube in tubes:
            z = np.fmax(z, tube.height_map(xx, yy))
        maps.append(z * 1e9)
    clim = robust_limits(*maps)
    ext = (xs[0] * 1e9 - 0.5 * step * 1e9, xs[-1] * 1e9 + 0.5 * step * 1e9,
           ys[0] * 1e9 - 0.5 * step * 1e9, ys[-1] * 1e9 + 0.5 * step * 1e9)
    with style.context("default"):
        ax0, ax1 = fig.subplots(1, 2, sharex=True, sharey=True)
        _map(ax0, fig, maps[0], ext, clim, colorbar=False)
        ax0.set_title("(a) before", loc="left", fontsize=9)
        im = _map(ax1, fig, maps[1], ext, clim, colorbar=False)
        ax1.set_title("(b) after", loc="left", fontsize=9)
        ax1.set_ylabel("")
        _draw_tubes(ax1, [tubes_before[i] for i in moved], [])
        if probe_position is not None:
            pc = np.asarray(probe_position, dtype=np.float64)[:, :2] * 1e9
            if in_contact is not None:
                pc = pc.copy()
                pc[~np.asarray(in_contact, bool)] = np.nan
            ax1.plot(pc[:, 0], pc[:, 1], color=_CONTACT, linewidth=1.5, label="tip path in contact")
        if moved:
            ax1.legend(loc="upper right", fontsize=7, framealpha=0.7)
        for ax in (ax0, ax1):
            ax.set_xlim(ext[0], ext[1])
            ax.set_ylim(ext[2], ext[3])
        fig.colorbar(im, ax=[ax0, ax1], label="height (nm)", shrink=0.9, pad=0.015, fraction=0.03)
    return fig


def dent_figure(surface, rest, center, half_width: float, contact_radius: float | None = None,
                samples: int = 201, levels: int = 4):
    r"""The dent over the topography: (a) the deformed surface's height map with the dent
    :math:`\delta = z_{rest} - z` as contour lines (nm), (b) both profiles through the centre.

    Parameters
    ----------
    surface, rest : BSplineSurface
        The deformed surface and the same surface at rest (x = u, y = v: a height-field net).
    center : (x, y) float, m
        Middle of the view (the contact point).
    half_width : float, m
    contact_radius : float, m, optional
        Drawn as a dashed circle.
    samples : int
        Grid points per side.
    levels : int
        Number of contour levels, evenly spaced in (0, max dent).

    Returns
    -------
    matplotlib.figure.Figure
    """
    cx, cy = float(center[0]), float(center[1])
    hw = float(half_width)
    if not (math.isfinite(cx) and math.isfinite(cy) and math.isfinite(hw) and hw > 0.0):
        raise FigureError(f"dent_figure needs a finite centre and a positive half width (got {center!r}, {half_width!r})")
    (u0, u1), (v0, v1) = surface.domain
    xs = np.linspace(max(cx - hw, u0), min(cx + hw, u1), samples)
    ys = np.linspace(max(cy - hw, v0), min(cy + hw, v1), samples)
    xx, yy = np.meshgrid(xs, ys)
    z = surface.evaluate(xx, yy)[..., 2] * 1e9
    z0 = rest.evaluate(xx, yy)[..., 2] * 1e9
    dent = z0 - z
    style, fig = _figure(9.5, 4.0)
    fig.get_layout_engine().set(wspace=0.06)
    step_x, step_y = xs[1] - xs[0], ys[1] - ys[0]
    ext = ((xs[0] - 0.5 * step_x) * 1e9, (xs[-1] + 0.5 * step_x) * 1e9,
           (ys[0] - 0.5 * step_y) * 1e9, (ys[-1] + 0.5 * step_y) * 1e9)
    with style.context("default"):
        ax0, ax1 = fig.subplots(1, 2, gridspec_kw={"width_ratios": [1.0, 1.1]})
        _map(ax0, fig, z, ext, robust_limits(z))
        top = float(np.nanmax(dent))
        if top > 0.0:
            lv = np.linspace(0.0, top, levels + 2)[1:-1]
            cs = ax0.contour(xs * 1e9, ys * 1e9, dent, levels=lv, colors=_DENT, linewidths=0.9)
            ax0.clabel(cs, fmt=lambda v: f"{v:.2g}", fontsize=6, colors=_DENT)
            cs.set_gid("dent_contours")
        if contact_radius:
            from matplotlib.patches import Circle

            ax0.add_patch(Circle((cx * 1e9, cy * 1e9), contact_radius * 1e9, fill=False, color="white",
                                 linestyle="--", linewidth=0.9))
        ax0.set_title(f"(a) height; contours: dent (nm), max {top:.2g} nm"
                      + ("; dashed: contact radius" if contact_radius else ""), loc="left", fontsize=8)
        row = int(np.argmin(np.abs(ys - cy)))
        ax1.plot(xs * 1e9, z0[row], color="0.4", linestyle="--", linewidth=1.0, label="at rest")
        ax1.plot(xs * 1e9, z[row], color="k", linewidth=1.2, label="deformed")
        ax1.fill_between(xs * 1e9, z[row], z0[row], where=dent[row] > 0, color=_DENT, alpha=0.4, linewidth=0,
                         label="dent")
        ax1.set_xlabel("x (nm)")
        ax1.set_ylabel("height (nm)")
        ax1.set_title(f"(b) profile at y = {cy * 1e9:.1f} nm", loc="left", fontsize=8)
        ax1.grid(True, linewidth=0.3)
        ax1.legend(fontsize=7, loc="lower right")
    return fig
