r"""Nanotubes found in a scan: ridges fitted as segments, the tip's broadening removed.

A tube lying on the substrate is a capsule of radius :math:`r` around an axis segment; a tip of
radius :math:`R` images it as the capsule of radius :math:`r + R` lowered by :math:`R`
(the dilation of :mod:`arsurf.instrument.imaging`, its sphere part):

.. math:: z(d) = b + r + \sqrt{(r + R)^2 - d^2} - R, \qquad d < 2\sqrt{rR},

with :math:`d` the distance to the axis segment and :math:`b` the substrate: :math:`2\sqrt{rR}`
wider on each side than the tube, never higher. :func:`find_tubes` takes the pixels higher than
the substrate's robust spread (:func:`~arsurf.verify.register.object_mask`), one connected group
per tube, starts from the group's principal axis and fits this image to the group's pixels
(``scipy.optimize.least_squares``, soft-L1 loss) for the centre, angle, length, radius and
substrate level. The tube's diameter is then the fitted :math:`2r` - its width with the tip's
broadening removed - and its height the ridge's measured top above the substrate.

The tip radius is the known one (the session's) or, with ``tip_radius=None``, estimated from
the scan itself: for a rigid tube the ridge's height gives :math:`r` and its width
:math:`2\sqrt{rR}` gives :math:`R`, fitted per tube (``R`` free) and their median kept - a blind
estimate on the tubes' known shape, not Villarrubia's general blind reconstruction (Villarrubia
1997, Sec. 4.3), which needs sharp features the tubes do not have.

The cone above the sphere is not modelled (the image's foot, where the tip's flank touches,
is a little wider for a tube thicker than :math:`R \tan^2`-terms; the soft-L1 loss lowers its
weight).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage, optimize

from arsurf.errors import VerifyError
from arsurf.scan.scan import Scan
from arsurf.verify.register import level_substrate

__all__ = ["FoundTube", "find_tubes", "tube_image"]


@dataclass(frozen=True)
class FoundTube:
    """A tube found in a scan (its own pixel frame: x = ix dx, y = iy dy).

    Attributes
    ----------
    x, y : float, metres
        Axis centre.
    angle : float, radians
        Axis direction, in (-pi/2, pi/2] (a tube has no head).
    length : float, metres
        Axis length (caps excluded).
    diameter : float, metres
        Width with the tip's broadening removed (2 r of the fit).
    height : float, metres
        Top of the ridge above the substrate (measured).
    apparent_width : float, metres
        Width of the image at the substrate, :math:`4\\sqrt{rR}` with the fitted r.
    tip_radius : float, metres
        The R the fit used (known or estimated).
    pixels : int
        Pixels of its group.
    rms : float, metres
        Rms residual of the fit.
    touches_edge : bool
        The group reaches the frame's border (the tube may continue outside).
    """

    x: float
    y: float
    angle: float
    length: float
    diameter: float
    height: float
    apparent_width: float
    tip_radius: float
    pixels: int
    rms: float
    touches_edge: bool

    def to_json(self) -> dict:
        return {"x_nm": self.x * 1e9, "y_nm": self.y * 1e9, "angle_deg": math.degrees(self.angle),
                "length_nm": self.length * 1e9, "diameter_nm": self.diameter * 1e9, "height_nm": self.height * 1e9,
                "apparent_width_nm": self.apparent_width * 1e9, "tip_radius_nm": self.tip_radius * 1e9,
                "n_pixels": self.pixels, "fit_rms_nm": self.rms * 1e9, "touches_edge": self.touches_edge}


def _wrap_half(angle: float) -> float:
    """Angle in (-pi/2, pi/2]."""
    a = math.fmod(angle, math.pi)
    if a <= -0.5 * math.pi:
        a += math.pi
    elif a > 0.5 * math.pi:
        a -= math.pi
    return a


def tube_image(x: np.ndarray, y: np.ndarray, cx: float, cy: float, angle: float, length: float, r: float,
               tip_radius: float, base: float) -> np.ndarray:
    """The image (m) a sphere of radius ``tip_radius`` records of a tube on a flat substrate at
    ``base``: :math:`b + \\max(0, r + \\sqrt{(r+R)^2 - d^2} - R)` (module docstring)."""
    ux, uy = math.cos(angle), math.sin(angle)
    ax, ay = cx - 0.5 * length * ux, cy - 0.5 * length * uy
    t = np.clip((x - ax) * ux + (y - ay) * uy, 0.0, length)
    d2 = (x - ax - t * ux) ** 2 + (y - ay - t * uy) ** 2
    reach2 = (r + tip_radius) ** 2
    z = r + np.sqrt(np.maximum(reach2 - d2, 0.0)) - tip_radius
    return base + np.maximum(z, 0.0)


def _fit_one(h, xs, ys, sel, dx, dy, tip_radius, noise):
    """Fit one group: (params, rms, top) with params cx, cy, angle, L, r, base[, R] (SI).

    Solved in nanometres (all parameters of order 1-1000) from the group's principal axis; the
    start's length is the half-height extent along the axis less the half-height width across
    (the caps are round)."""
    nm = 1e9
    x, y, z = xs[sel] * nm, ys[sel] * nm, h[sel] * nm
    top = float(np.percentile(z, 99))
    w = np.clip(z, 0.0, None)
    cx, cy = float(np.sum(w * x) / np.sum(w)), float(np.sum(w * y) / np.sum(w))
    cov = np.cov(np.vstack([x - cx, y - cy]), aweights=w + 1e-30)
    u = np.linalg.eigh(cov)[1][:, 1]
    angle = math.atan2(u[1], u[0])
    half = z > 0.5 * top
    along = (x[half] - cx) * u[0] + (y[half] - cy) * u[1]
    across = -(x[half] - cx) * u[1] + (y[half] - cy) * u[0]
    cx += 0.5 * float(along.max() + along.min()) * u[0]
    cy += 0.5 * float(along.max() + along.min()) * u[1]
    width = float(across.max() - across.min()) + max(dx, dy) * nm
    length0 = max(float(along.max() - along.min()) - width + max(dx, dy) * nm, 2.0 * max(dx, dy) * nm)
    r0 = max(0.5 * top, 0.5)
    fixed = tip_radius is not None
    p0 = [cx, cy, angle, length0, r0, 0.0] + ([] if fixed else [max(width ** 2 / (16.0 * r0), 1.0)])
    lo = [-np.inf, -np.inf, -np.inf, 0.5 * dx * nm, 0.1, -np.inf] + ([] if fixed else [0.1])
    hi = [np.inf] * len(p0)
    zn = noise * nm

    def residual(p):
        R = tip_radius * nm if fixed else p[6]
        return (tube_image(x, y, p[0], p[1], p[2], p[3], p[4], R, p[5]) - z) / zn

    res = optimize.least_squares(residual, p0, bounds=(lo, hi), x_scale=[dx * nm, dy * nm, 0.02, dx * nm, 1.0, 1.0]
                                 + ([] if fixed else [1.0]), diff_step=1e-6, max_nfev=600)
    rms = float(np.sqrt(np.mean((res.fun * zn) ** 2))) / nm
    q = np.array(res.x, dtype=np.float64)
    q[[0, 1, 3, 4, 5]] /= nm
    if not fixed:
        q[6] /= nm
    return q, rms, top / nm


def find_tubes(scan: Scan, tip_radius: float | None, *, min_height: float = 2e-9, min_pixels: int = 12,
               margin_px: int = 4) -> list[FoundTube]:
    """The tubes of ``scan``: one fitted segment per group of raised pixels (module docstring).

    Parameters
    ----------
    scan : Scan
        Heights in metres.
    tip_radius : float or None, metres
        The imaging tip's radius; None: estimated from the tubes (their median).
    min_height : float, metres
        A tube stands at least this high (and 6 robust sigmas) above the substrate.
    min_pixels : int
        Smaller groups are noise or debris.
    margin_px : int
        Pixels around a group that the fit also sees (the image's foot and the substrate).

    Raises
    ------
    VerifyError
        No tube in the scan.
    """
    if tip_radius is not None and not (math.isfinite(tip_radius) and tip_radius > 0.0):
        raise VerifyError(f"tip_radius must be positive metres or None for an estimate (got {tip_radius!r})")
    h, _ = level_substrate(scan, dilate_px=0, min_height=min_height)
    sub = np.isfinite(h)
    med = float(np.median(h[sub]))
    noise = max(1.4826 * float(np.median(np.abs(h[sub] - med))), 1e-11)
    h = h - med
    high = sub & (h > max(6.0 * noise, min_height))
    labels, n = ndimage.label(high)
    ny, nx = h.shape
    yy, xx = np.mgrid[0:ny, 0:nx]
    xs, ys = xx * scan.dx, yy * scan.dy
    groups = []
    for k, sl in enumerate(ndimage.find_objects(labels), start=1):
        if sl is None:
            continue
        own = labels == k
        count = int(own.sum())
        if count < min_pixels:
            continue
        near = ndimage.binary_dilation(own, iterations=int(margin_px)) & sub & ((labels == 0) | own)
        edge = bool(own[0].any() or own[-1].any() or own[:, 0].any() or own[:, -1].any())
        groups.append((near, count, edge))
    if not groups:
        raise VerifyError(f"no objects found in {scan.source or 'the scan'}: nothing stands {min_height * 1e9:.3g} nm "
                          "above the substrate; check the channel and the scan area")
    fits = [(_fit_one(h, xs, ys, near, scan.dx, scan.dy, tip_radius, noise), count, edge)
            for near, count, edge in groups]
    R = tip_radius if tip_radius is not None else float(np.median([f[0][0][6] for f in fits]))
    if tip_radius is None:  # refit every tube with the common estimate
        fits = [(_fit_one(h, xs, ys, near, scan.dx, scan.dy, R, noise), count, edge) for near, count, edge in groups]
    out = []
    for (p, rms, top), count, edge in fits:
        cx, cy, angle, length, r, base = p[:6]
        out.append(FoundTube(float(cx), float(cy), _wrap_half(float(angle)), float(length), float(2 * r),
                             float(top - base), float(4 * math.sqrt(r * R)), float(R), count, rms, edge))
    return out
