"""The model meets the scan after, in the manner of [MWCNT] Fig. 9 (live display beside the scan
after each push): (a) the model's prediction - the substrate the session fitted with every tube
at the pose the model left it, (b) the scan after carried into the same frame by the
registration (grey where it did not reach), (c) the two overlaid - the scan after with the predicted outlines (dashed) and the
measured ones (solid), each moved tube labelled with its errors.

The conventions of :mod:`arsurf.replay.plots`: nm axes with a scale bar, :data:`HEIGHT_CMAP`,
one pair of robust colour limits for the compared panels, a colour bar naming the unit, no
pyplot, deterministic files (:func:`~arsurf.replay.plots.save_figure`).
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np
from scipy import ndimage

from arsurf.replay.plots import _AFTER, _BEFORE, _extent, _figure, _map, _outline, robust_limits
from arsurf.verify.compare import ObjectCheck
from arsurf.verify.register import Registration

__all__ = ["verify_figure", "after_in_before_frame"]


def after_in_before_frame(after: np.ndarray, reg: Registration) -> np.ndarray:
    """The scan after's heights resampled on the scan before's pixels (inverse of the registration's
    map; NaN outside the scan after)."""
    ny, nx = after.shape
    lin, off = reg.affine[:, :2], reg.affine[:, 2]
    inv = np.linalg.inv(lin)
    yy, xx = np.mgrid[0:ny, 0:nx]
    q = np.vstack([xx.ravel() - off[0], yy.ravel() - off[1]])
    p = inv @ q  # the after scan's pixel (x, y) that shows each before pixel
    z = ndimage.map_coordinates(np.asarray(after, dtype=np.float64), [p[1], p[0]], order=1, mode="constant",
                                cval=np.nan)
    return z.reshape(ny, nx)


def verify_figure(substrate: np.ndarray, after_registered: np.ndarray, dx: float, dy: float, tubes: Sequence,
                  checks: Sequence[ObjectCheck], wrong: bool, tip_radius: float = 0.0):
    """Prediction, scan after, overlay (module docstring).

    Parameters
    ----------
    substrate : (ny, nx) float, m
        The model's substrate (tubes masked and inpainted), the scan before's frame.
    after_registered : (ny, nx) float, m
        The scan after in the same frame (:func:`after_in_before_frame`).
    dx, dy : float, m
    tubes : sequence of Nanotube
        The session's tubes at the model's final poses.
    checks : sequence of ObjectCheck
    wrong : bool
        The model was flagged (said in the title of (c)).
    tip_radius : float, m
        The model's tubes are drawn as this tip images them (comparable with the scan after).
    """
    from arsurf.manipulation.nanotube import Nanotube

    style, fig = _figure(13.5, 4.6)
    ny, nx = substrate.shape
    yy, xx = np.mgrid[0:ny, 0:nx]
    model = np.array(substrate, dtype=np.float64)
    for t in tubes:
        model = np.fmax(model, t.height_map(xx * dx, yy * dy, tip_radius=tip_radius))
    after = np.asarray(after_registered, dtype=np.float64)
    lo = np.nanmedian(after) - np.nanmedian(model)
    after_z = (after - lo) * 1e9  # the same substrate level as the model's (the scans are levelled apart)
    model_z = model * 1e9
    clim = robust_limits(model_z, after_z, percentiles=(1.0, 99.9))
    extent = _extent(model.shape, dx, dy)
    with style.context("default"):
        axes = fig.subplots(1, 3, sharex=True, sharey=True)
        _map(axes[0], fig, model_z, extent, clim, colorbar=False)
        axes[0].set_title("(a) model: predicted poses (as the tip images them)", loc="left", fontsize=9)
        _map(axes[1], fig, after_z, extent, clim, colorbar=False)
        axes[1].set_title("(b) scan after (registered)", loc="left", fontsize=9)
        im = _map(axes[2], fig, after_z, extent, clim, colorbar=False)
        axes[2].set_title("(c) overlay: model wrong" if wrong else "(c) overlay: model agrees", loc="left",
                          fontsize=9, color="tab:red" if wrong else "black")
        for k, (t, c) in enumerate(zip(tubes, checks)):
            o = _outline(t)
            axes[2].plot(o[:, 0], o[:, 1], color=_BEFORE, linestyle="--", linewidth=1.0,
                         label="model" if k == 0 else None)
            if c.found is not None:
                f = c.found
                m = _outline(Nanotube(max(f.length, 1e-12), f.diameter, x=f.x, y=f.y, angle=f.angle))
                axes[2].plot(m[:, 0], m[:, 1], color=_AFTER, linewidth=1.2, label="measured" if k == 0 else None)
                if c.moved:
                    axes[2].annotate(f"{c.index}: {c.position_error * 1e9:.1f} nm, {math.degrees(c.angle_error):+.1f}°",
                                     (f.x * 1e9, f.y * 1e9), xytext=(10, -18), textcoords="offset points", fontsize=7,
                                     color="white", bbox={"boxstyle": "round,pad=0.2", "facecolor": "black",
                                                          "alpha": 0.6, "edgecolor": "none"})
        for ax in axes[1:]:
            ax.set_ylabel("")
            ax.set_facecolor("0.45")  # outside the scan after (drift): grey, so the white scale bar shows
        axes[2].legend(loc="upper right", fontsize=7, framealpha=0.7)
        fig.colorbar(im, ax=list(axes), label="height (nm)", shrink=0.9, pad=0.01, fraction=0.02)
    return fig
