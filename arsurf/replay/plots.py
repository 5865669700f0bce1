"""Replay figures (matplotlib, Agg canvas, no pyplot): forces vs time and the probe path.

- :func:`plot_forces` - the force on the tip, one panel per component in nN against time in s,
  contact intervals shaded; recorded (what the loop used), simulated and measured (replayed)
  on the same axes. Seed 000 Fig. 10 shows the normal and lateral force of a push this way.
- :func:`plot_coupled_motion` - four stacked panels as seed 001 Fig. 4.21: probe z (nm), the
  z force sent to the haptic device (N), probe y (nm), the y device force (N).
- :func:`plot_path` - the probe path drawn over the scan's height map (nm axes, colour bar),
  contact parts of the path highlighted.

The figures are drawn with the default style whatever the user's matplotlibrc says, on a
:class:`~matplotlib.backends.backend_agg.FigureCanvasAgg` (no global backend switch), and saved
as PNG without the ``Software`` text chunk: the same data give the same bytes.

Examples
--------
>>> import numpy as np, tempfile, os
>>> t = np.linspace(0, 1, 50); f = np.zeros((50, 3)); f[:, 2] = 1e-9 * np.sin(3 * t)
>>> p = plot_forces(os.path.join(tempfile.mkdtemp(), "f.png"), t, {"recorded": f}, t > 0.5)
>>> p.name
'f.png'
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Mapping

import numpy as np

from arsurf.errors import require

__all__ = ["plot_forces", "plot_coupled_motion", "plot_path", "PNG_METADATA"]

#: PNG text chunks: none (matplotlib would add its version as ``Software``)
PNG_METADATA = {"Software": None}
_DPI = 100
_STYLES = {"recorded": ("k", "-", 1.2), "simulated": ("tab:blue", "--", 1.0), "measured": ("tab:red", ":", 1.2)}


def _figure(width: float, height: float):
    style = require("matplotlib.style", "viewer", "replay plots")
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), dpi=_DPI)
    FigureCanvasAgg(fig)
    return style, fig


def _save(fig, path) -> Path:
    path = Path(path)
    fig.savefig(path, format="png", dpi=_DPI, metadata=PNG_METADATA)
    return path


def _shade_contact(ax, t: np.ndarray, in_contact: np.ndarray, label: bool) -> None:
    """Grey bands where ``in_contact`` (one artist, stepwise over the tick times)."""
    mask = np.asarray(in_contact, dtype=bool)
    if t.size and mask.any():
        ax.fill_between(t, 0.0, 1.0, where=mask, step="post", color="0.85", linewidth=0.0,
                        transform=ax.get_xaxis_transform(), label="contact" if label else None, zorder=0)


def plot_forces(path: str | os.PathLike, t, forces: Mapping[str, np.ndarray], in_contact=None,
                title: str = "Force on the tip") -> Path:
    """Force components in nN against time (s), one panel per component, contact shaded.

    Parameters
    ----------
    path : path-like
        PNG file to write.
    t : (n,) float, seconds
    forces : dict name -> (n, 3) float, newtons
        Curves to draw (e.g. ``recorded``, ``simulated``, ``measured``); all-NaN ones are skipped.
    in_contact : (n,) bool, optional
        Ticks in contact (shaded).
    title : str

    Returns
    -------
    Path
        The written file (seed 000 Fig. 10 and seed 001 Fig. 4.21 show the forces this way).
    """
    style, fig = _figure(8.0, 7.0)
    t = np.asarray(t, dtype=np.float64)
    contact = np.zeros(t.shape, bool) if in_contact is None else np.asarray(in_contact, dtype=bool)
    with style.context("default"):
        axes = fig.subplots(3, 1, sharex=True)
        names = ("F$_x$ (lateral)", "F$_y$ (lateral)", "F$_z$ (normal)")
        for k, ax in enumerate(axes):
            _shade_contact(ax, t, contact, label=k == 0)
            for name, f in forces.items():
                f = np.asarray(f, dtype=np.float64)
                if f.shape != (t.size, 3) or not np.isfinite(f[:, k]).any():
                    continue
                color, ls, lw = _STYLES.get(name, (None, "-", 1.0))
                ax.plot(t, f[:, k] * 1e9, color=color, linestyle=ls, linewidth=lw, label=name)
            lo, hi = ax.dataLim.y0, ax.dataLim.y1
            if ax.lines and np.isfinite([lo, hi]).all() and hi - lo < 1e-3:  # a flat component (< 1 pN):
                mid = 0.5 * (lo + hi)                                     # no offset-scaled round-off noise
                ax.set_ylim(mid - 1.0, mid + 1.0)
            ax.set_ylabel(f"{names[k]} (nN)")
            ax.grid(True, linewidth=0.3)
        axes[0].set_title(title)
        axes[-1].set_xlabel("time (s)")
        handles, labels = axes[0].get_legend_handles_labels()
        if handles:
            axes[0].legend(handles, labels, loc="upper right", fontsize=8, ncol=len(handles))
        fig.tight_layout()
        return _save(fig, path)


def plot_coupled_motion(path: str | os.PathLike, t, probe_position, device_force, in_contact=None) -> Path:
    """Seed 001 Fig. 4.21: probe z (nm), device force z (N), probe y (nm), device force y (N).

    Parameters
    ----------
    path : path-like
    t : (n,) float, seconds
    probe_position : (n, 3) float, metres
    device_force : (n, 3) float, newtons (NaN where the loop recorded none)
    in_contact : (n,) bool, optional

    Returns
    -------
    Path
    """
    style, fig = _figure(8.0, 8.0)
    t = np.asarray(t, dtype=np.float64)
    p = np.asarray(probe_position, dtype=np.float64)
    d = np.asarray(device_force, dtype=np.float64)
    contact = np.zeros(t.shape, bool) if in_contact is None else np.asarray(in_contact, dtype=bool)
    panels = ((p[:, 2] * 1e9, "probe z (nm)"), (d[:, 2], "device F$_z$ (N)"),
              (p[:, 1] * 1e9, "probe y (nm)"), (d[:, 1], "device F$_y$ (N)"))
    with style.context("default"):
        axes = fig.subplots(4, 1, sharex=True)
        for k, (ax, (y, label)) in enumerate(zip(axes, panels)):
            _shade_contact(ax, t, contact, label=k == 0)
            if np.isfinite(y).any():
                ax.plot(t, y, color="k", linewidth=1.0)
            else:
                ax.text(0.5, 0.5, "not recorded", transform=ax.transAxes, ha="center", va="center", color="0.4")
            ax.set_ylabel(label)
            ax.grid(True, linewidth=0.3)
        axes[0].set_title("Probe motion and haptic force (cf. seed 001 Fig. 4.21)")
        axes[-1].set_xlabel("time (s)")
        if contact.any():
            axes[0].legend(loc="upper right", fontsize=8)
        fig.tight_layout()
        return _save(fig, path)


def plot_path(path: str | os.PathLike, heights, dx: float, dy: float, probe_position, in_contact=None,
              title: str = "Probe path over the scan") -> Path:
    """The probe's (x, y) path over the height map, axes and colour bar in nm.

    Parameters
    ----------
    path : path-like
    heights : (ny, nx) float, metres
        The processed height map (``heights[iy, ix]``, pixel centres at ``ix dx``, ``iy dy``).
    dx, dy : float, metres
    probe_position : (n, 3) float, metres
    in_contact : (n,) bool, optional
        Contact ticks are drawn as red dots over the white path.
    title : str

    Returns
    -------
    Path
    """
    style, fig = _figure(7.0, 6.0)
    z = np.asarray(heights, dtype=np.float64)
    ny, nx = z.shape
    p = np.asarray(probe_position, dtype=np.float64)
    contact = np.zeros(p.shape[0], bool) if in_contact is None else np.asarray(in_contact, dtype=bool)
    extent = (-0.5 * dx * 1e9, (nx - 0.5) * dx * 1e9, -0.5 * dy * 1e9, (ny - 0.5) * dy * 1e9)
    with style.context("default"):
        ax = fig.subplots()
        im = ax.imshow(z * 1e9, origin="lower", extent=extent, cmap="afmhot", interpolation="nearest",
                       aspect="equal")
        fig.colorbar(im, ax=ax, label="height (nm)")
        if p.shape[0]:
            ax.plot(p[:, 0] * 1e9, p[:, 1] * 1e9, color="w", linewidth=1.0, label="probe path")
            if contact.any():
                ax.plot(p[contact, 0] * 1e9, p[contact, 1] * 1e9, ".", color="tab:red", markersize=2,
                        label="in contact")
            ax.plot(p[0, 0] * 1e9, p[0, 1] * 1e9, "o", color="tab:green", markersize=5, label="start")
            ax.plot(p[-1, 0] * 1e9, p[-1, 1] * 1e9, "s", color="tab:blue", markersize=5, label="end")
            ax.legend(loc="upper right", fontsize=8)
        ax.set_xlim(extent[0], extent[1])
        ax.set_ylim(extent[2], extent[3])
        ax.set_xlabel("x (nm)")
        ax.set_ylabel("y (nm)")
        ax.set_title(title)
        fig.tight_layout()
        return _save(fig, path)
