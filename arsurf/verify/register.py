r"""Registration of the scan after to the scan before: the drift between them, on the substrate.

Thermal drift moves the sample under the tip slowly while a frame is scanned and differently in
the next frame; linear in time, it makes each image an affine view of the sample, so the map
from the scan after's pixels to the scan before's is affine (six numbers). It is found on the
substrate only - the objects, which the session moved, are masked in both images (pixels higher
than the substrate's robust spread, dilated) - in three steps:

1. each image levelled by a plane fitted to its substrate pixels (z drift is a plane);
2. the global shift by phase correlation (Kuglin & Hines 1975; the normalised cross-power
   spectrum's inverse transform peaks at the shift), refined to sub-pixel by the upsampled DFT
   of Guizar-Sicairos, Thurman & Fienup (Opt. Lett. 33, 156, 2008), then the same on a grid of
   tiles: local shifts at the tile centres, fitted by an affine map with Huber weights (a
   tile on an edge or a moved object does not pull the fit);
3. the affine map refined on every substrate pixel by Gauss-Newton on the heights (Lucas &
   Kanade 1981), with a plane of height difference as nuisance, and Huber weights again.

:func:`register` returns the map, the drift at the frame's centre in metres and the fraction of
the scan after that the scan before covers; it refuses scans of different pixel spacing,
channel or size, and scans that do not overlap (one line each).

Examples
--------
>>> rng = np.random.default_rng(0)
>>> from scipy.ndimage import gaussian_filter, shift as nd_shift
>>> a = gaussian_filter(rng.standard_normal((96, 96)), 2.0) * 1e-9
>>> b = nd_shift(a, (1.3, -2.6), order=3, mode="nearest")      # the sample moved +1.3 px in y, -2.6 in x
>>> r = register(Scan(a, 5e-9, 5e-9), Scan(b, 5e-9, 5e-9))
>>> np.round(r.shift_px, 2).tolist()                         # after -> before at the centre: (x, y) px
[2.6, -1.3]
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from arsurf.errors import VerifyError
from arsurf.scan.scan import Scan

__all__ = ["Registration", "register", "check_pair", "level_substrate", "object_mask", "phase_shift"]

#: minimum fraction of the scan after that must lie inside the scan before
MIN_OVERLAP = 0.5
#: least correlation of the substrate heights after the fit: two scans of one substrate of
#: variance s^2 with pixel noise n^2 correlate s^2 / (s^2 + n^2) (0.8 for the benchmark's 0.4 nm
#: roughness and 0.2 nm noise), two unrelated areas about 0 (0.07 measured)
MIN_CORRELATION = 0.3
#: Gaussian width (pixels) of the low pass both scans get before the refinement
SMOOTH_PX = 0.8
#: Huber threshold in robust standard deviations
_HUBER = 1.5


@dataclass(frozen=True)
class Registration:
    """The map from the scan after's pixels to the scan before's.

    Attributes
    ----------
    affine : (2, 3) float
        ``[fx, fy] = affine @ [ix, iy, 1]``: where pixel (ix, iy) of the scan after is in the
        scan before's pixel indexes.
    drift : (2,) float, metres
        How far the sample seen at the after scan's centre pixel is from where the before scan
        saw it: ``(affine @ centre - centre) * (dx, dy)`` (x, y).
    shift_px : (2,) float
        The same in pixels.
    overlap : float
        Fraction of the scan after's pixels inside the scan before.
    substrate_fraction : float
        Fraction of pixels used (substrate in both).
    residual_rms : float, metres
        Rms height difference over the substrate after the fit.
    """

    affine: np.ndarray
    drift: np.ndarray
    shift_px: np.ndarray
    overlap: float
    substrate_fraction: float
    residual_rms: float

    def map(self, ix, iy) -> tuple[np.ndarray, np.ndarray]:
        """Pixel indexes of the scan after -> the scan before's."""
        ix, iy = np.asarray(ix, dtype=np.float64), np.asarray(iy, dtype=np.float64)
        a = self.affine
        return a[0, 0] * ix + a[0, 1] * iy + a[0, 2], a[1, 0] * ix + a[1, 1] * iy + a[1, 2]

    def to_json(self, dx: float, dy: float) -> dict:
        return {"affine_px": self.affine.tolist(), "drift_x_nm": float(self.drift[0] * 1e9),
                "drift_y_nm": float(self.drift[1] * 1e9), "drift_x_px": float(self.shift_px[0]),
                "drift_y_px": float(self.shift_px[1]), "overlap_fraction": self.overlap,
                "substrate_fraction": self.substrate_fraction, "residual_rms_nm": self.residual_rms * 1e9,
                "pixel_dx_nm": dx * 1e9, "pixel_dy_nm": dy * 1e9}


def check_pair(before: Scan, after: Scan) -> None:
    """Refuse two scans that cannot be compared pixel for pixel (one line each)."""
    for name, s in (("before", before), ("after", after)):
        if not isinstance(s, Scan):
            raise VerifyError(f"the scan {name} must be an arsurf Scan (got {type(s).__name__})")
    if before.channel != after.channel:
        raise VerifyError(f"the scans show different channels ({before.channel!r} before, {after.channel!r} after); "
                          "compare the same height channel (pass the after scan's channel name)")
    for unit in (before.metadata.get("z_unit"), after.metadata.get("z_unit")):
        if unit not in (None, "m"):
            raise VerifyError(f"a scan's channel is in {unit!r}, not metres: registration compares heights")
    if before.shape != after.shape:
        raise VerifyError(f"the scans have different sizes ({before.shape[1]}x{before.shape[0]} px before, "
                          f"{after.shape[1]}x{after.shape[0]} after); scan the same frame at the same pixels")
    if not (math.isclose(before.dx, after.dx, rel_tol=1e-3) and math.isclose(before.dy, after.dy, rel_tol=1e-3)):
        raise VerifyError(f"the scans have different pixel spacings ({before.dx * 1e9:.4g} x {before.dy * 1e9:.4g} nm "
                          f"before, {after.dx * 1e9:.4g} x {after.dy * 1e9:.4g} nm after); scan at the same pixel size")
    if min(before.shape) < 16:
        raise VerifyError(f"the scans are {before.shape[1]}x{before.shape[0]} px; registration needs at least 16 a side")


def _plane_fit(h: np.ndarray, use: np.ndarray) -> np.ndarray:
    ny, nx = h.shape
    yy, xx = np.mgrid[0:ny, 0:nx]
    a = np.c_[xx[use], yy[use], np.ones(int(use.sum()))]
    coef, *_ = np.linalg.lstsq(a, h[use], rcond=None)
    return coef[0] * xx + coef[1] * yy + coef[2]


def object_mask(h: np.ndarray, dilate_px: int = 3, min_height: float = 2e-9) -> np.ndarray:
    """Pixels of objects on a levelled substrate: higher than the substrate's median by more than
    6 robust standard deviations (1.4826 MAD) and ``min_height`` (m), dilated by ``dilate_px``."""
    valid = np.isfinite(h)
    med = float(np.median(h[valid]))
    mad = 1.4826 * float(np.median(np.abs(h[valid] - med)))
    high = valid & (h > med + max(6.0 * mad, min_height))
    if dilate_px > 0:
        high = ndimage.binary_dilation(high, iterations=int(dilate_px))
    return high | ~valid


def level_substrate(scan: Scan, dilate_px: int = 3, min_height: float = 2e-9) -> tuple[np.ndarray, np.ndarray]:
    """(heights levelled by a plane through the substrate, object mask); three passes, the
    objects found on the levelled heights each time."""
    h = np.array(scan.heights, dtype=np.float64)
    mask = ~np.isfinite(h)
    for _ in range(3):
        use = ~mask
        if use.sum() < 16:
            raise VerifyError(f"the scan {scan.source or ''} has almost no substrate (objects cover it all)")
        h = h - _plane_fit(np.nan_to_num(h), use)
        mask = object_mask(h, dilate_px, min_height)
    return h, mask


def _upsampled_dft(data: np.ndarray, size: int, factor: int, offset: np.ndarray) -> np.ndarray:
    """The inverse DFT of ``data`` on a ``size`` x ``size`` grid of step 1/``factor`` pixels around
    ``offset`` (Guizar-Sicairos et al. 2008: two matrix products instead of a padded FFT)."""
    ny, nx = data.shape
    ky = np.fft.ifftshift(np.arange(ny)) - ny // 2
    kx = np.fft.ifftshift(np.arange(nx)) - nx // 2
    ry = (np.arange(size) - offset[0])[:, None]
    rx = (np.arange(size) - offset[1])[None, :]
    ey = np.exp(-2j * np.pi * ry * ky[None, :] / (ny * factor))
    ex = np.exp(-2j * np.pi * kx[:, None] * rx / (nx * factor))
    return ey @ data @ ex


def phase_shift(a: np.ndarray, b: np.ndarray, upsample: int = 50) -> tuple[np.ndarray, float]:
    """Shift (sy, sx) in pixels with ``b(p) ~ a(p - s)`` (the content of ``a`` moved by s in ``b``),
    and the correlation peak's height (1 for identical content, ~0 for unrelated images).

    Both are windowed (Hann) after removing their mean; the peak of the inverse transform of the
    normalised cross-power spectrum is refined by the upsampled DFT (``upsample`` steps a pixel).
    """
    ny, nx = a.shape
    win = np.outer(np.hanning(ny), np.hanning(nx))
    fa = np.fft.fft2((a - a.mean()) * win)
    fb = np.fft.fft2((b - b.mean()) * win)
    cross = fb * np.conj(fa)
    cross /= np.maximum(np.abs(cross), 1e-30)
    corr = np.fft.ifft2(cross).real
    iy, ix = np.unravel_index(int(np.argmax(corr)), corr.shape)
    peak = float(corr[iy, ix])
    s = np.array([iy, ix], dtype=np.float64)
    s[0] -= ny if s[0] > ny // 2 else 0
    s[1] -= nx if s[1] > nx // 2 else 0
    size = int(math.ceil(upsample * 1.5))
    centre = size // 2
    up = _upsampled_dft(np.conj(cross), size, upsample, centre - s * upsample).conj()
    j = np.unravel_index(int(np.argmax(np.abs(up))), up.shape)
    s = s + (np.array(j, dtype=np.float64) - centre) / upsample
    return s, peak


def _huber_weights(r: np.ndarray) -> np.ndarray:
    s = 1.4826 * float(np.median(np.abs(r))) + 1e-30
    a = np.abs(r) / (_HUBER * s)
    return np.where(a <= 1.0, 1.0, 1.0 / np.maximum(a, 1e-30))


def _tile_affine(hb, ha, mb, ma, s0: np.ndarray, tiles: int) -> np.ndarray:
    """Affine map from tile shifts: each tile of the scan after correlated with the scan before
    at the global shift; (2, 3) fitted with Huber weights."""
    ny, nx = ha.shape
    th, tw = ny // tiles * 2, nx // tiles * 2  # half-overlapping tiles
    pts, shifts = [], []
    for cy in np.linspace(th / 2, ny - th / 2, 2 * tiles - 1):
        for cx in np.linspace(tw / 2, nx - tw / 2, 2 * tiles - 1):
            y0, x0 = int(round(cy - th / 2)), int(round(cx - tw / 2))
            yb, xb = int(round(y0 - s0[0])), int(round(x0 - s0[1]))  # the same sample in the scan before
            if yb < 0 or xb < 0 or yb + th > ny or xb + tw > nx:
                continue
            sa, sb = (slice(y0, y0 + th), slice(x0, x0 + tw)), (slice(yb, yb + th), slice(xb, xb + tw))
            if ma[sa].mean() > 0.3 or mb[sb].mean() > 0.3:
                continue
            ta = np.where(ma[sa], np.median(ha[sa][~ma[sa]]), ha[sa])
            tb = np.where(mb[sb], np.median(hb[sb][~mb[sb]]), hb[sb])
            s, peak = phase_shift(tb, ta, upsample=10)  # 0.1 px: the refinement below does the rest
            if peak < 0.05 or np.abs(s).max() > 2.0:
                continue
            pts.append((cx - 0.5, cy - 0.5))  # the tile's centre in the after scan's pixel indexes
            shifts.append((yb - y0 - s[0], xb - x0 - s[1]))  # before - after, (y, x)
    if len(pts) < 4:
        return np.array([[1.0, 0.0, -s0[1]], [0.0, 1.0, -s0[0]]])
    p = np.array(pts)
    d = np.array(shifts)
    a = np.c_[p, np.ones(len(p))]
    w = np.ones(len(p))
    for _ in range(5):
        cx_, *_ = np.linalg.lstsq(a * w[:, None], d[:, 1] * w, rcond=None)
        cy_, *_ = np.linalg.lstsq(a * w[:, None], d[:, 0] * w, rcond=None)
        r = np.hypot(a @ cx_ - d[:, 1], a @ cy_ - d[:, 0])
        w = np.sqrt(_huber_weights(r))
    return np.array([[1.0 + cx_[0], cx_[1], cx_[2]], [cy_[0], 1.0 + cy_[1], cy_[2]]])


def _refine(hb, ha, mb, ma, affine: np.ndarray, iterations: int = 12, smooth: float = 0.0):
    """Gauss-Newton on the heights: min sum w (B(A p) + c0 + c1 x + c2 y - H_a(p))^2 over the
    substrate pixels p of the scan after whose image lies on the scan before's substrate."""
    ny, nx = ha.shape
    scale = float(np.std(ha[~ma])) or 1.0  # heights in units of the substrate's spread: a well-scaled solve
    hb, ha = hb / scale, ha / scale
    if smooth > 0.0:  # the same low pass on both: less noise in the gradients, the same geometry
        hb, ha = ndimage.gaussian_filter(hb, smooth), ndimage.gaussian_filter(ha, smooth)
    yy, xx = np.mgrid[0:ny, 0:nx]
    xx, yy = xx.ravel().astype(np.float64), yy.ravel().astype(np.float64)
    hav = ha.ravel()
    keep_a = ~ma.ravel()
    coef = ndimage.spline_filter(hb, order=3, mode="nearest")
    mbf = mb.astype(np.float64)
    a = affine.copy()
    plane = np.zeros(3)
    w = None
    rms = math.nan
    for _ in range(iterations):
        fx = a[0, 0] * xx + a[0, 1] * yy + a[0, 2]
        fy = a[1, 0] * xx + a[1, 1] * yy + a[1, 2]
        inside = (fx >= 1) & (fx <= nx - 2) & (fy >= 1) & (fy <= ny - 2)
        coords = np.vstack([fy, fx])
        on_sub = ndimage.map_coordinates(mbf, coords, order=1, mode="nearest") < 0.01
        use = keep_a & inside & on_sub
        if use.sum() < 64:
            raise VerifyError("the scans share too little substrate to register (objects or the frame's edges cover "
                              "it); rescan with more of the same area")
        c = coords[:, use]
        b = ndimage.map_coordinates(coef, c, order=3, mode="nearest", prefilter=False)
        # the interpolant's own gradient (central differences of the cubic spline, 0.1 px): the
        # Gauss-Newton fixed point is then the least-squares optimum
        e = np.array([[0.1], [0.0]])
        by = (ndimage.map_coordinates(coef, c + e, order=3, mode="nearest", prefilter=False)
              - ndimage.map_coordinates(coef, c - e, order=3, mode="nearest", prefilter=False)) / 0.2
        bx = (ndimage.map_coordinates(coef, c + e[::-1], order=3, mode="nearest", prefilter=False)
              - ndimage.map_coordinates(coef, c - e[::-1], order=3, mode="nearest", prefilter=False)) / 0.2
        x, y = xx[use], yy[use]
        r = b + plane[0] + plane[1] * x + plane[2] * y - hav[use]
        w = _huber_weights(r)
        j = np.c_[bx * x, bx * y, bx, by * x, by * y, by, np.ones_like(x), x, y]
        jw = j * np.sqrt(w)[:, None]
        norms = np.linalg.norm(jw, axis=0) + 1e-30  # columns scaled to one: a well-conditioned 9 x 9 solve
        jn = jw / norms
        delta = np.linalg.solve(jn.T @ jn, -(jn.T @ (r * np.sqrt(w)))) / norms
        a += delta[:6].reshape(2, 3)
        plane += delta[6:]
        rms = float(np.sqrt(np.mean(r**2))) * scale
        ncc = float(np.corrcoef(b + plane[0] + plane[1] * x + plane[2] * y, hav[use])[0, 1])
        if np.abs(delta[[2, 5]]).max() < 1e-4 and np.abs(delta[[0, 1, 3, 4]]).max() < 1e-6:
            break
    return a, float(use.mean()), rms, ncc


def register(before: Scan, after: Scan, *, tiles: int = 4, min_height: float = 2e-9) -> Registration:
    """The affine map from the scan after's pixels to the scan before's, on the substrate.

    Parameters
    ----------
    before, after : Scan
        The same frame (size, pixels, channel) scanned before and after the manipulation.
    tiles : int
        Tiles per side of the local phase correlations (half-overlapping: 2 tiles - 1 per side).
    min_height : float, metres
        Objects are at least this high above the substrate (and 6 robust sigmas).

    Raises
    ------
    VerifyError
        Different sizes, spacings or channels; no overlap (the correlation peak is noise or the
        scans share less than half their area).
    """
    check_pair(before, after)
    hb, mb = level_substrate(before, min_height=min_height)
    ha, ma = level_substrate(after, min_height=min_height)
    fb = np.where(mb, np.median(hb[~mb]), hb)
    fa = np.where(ma, np.median(ha[~ma]), ha)
    s0, peak = phase_shift(fb, fa)
    ny, nx = ha.shape
    if peak < 0.03 or abs(s0[0]) > (1 - MIN_OVERLAP) * ny or abs(s0[1]) > (1 - MIN_OVERLAP) * nx:
        raise VerifyError(f"the scans do not overlap: the best shift ({s0[1]:+.1f}, {s0[0]:+.1f}) px has a correlation "
                          f"peak of {peak:.3f} (need > 0.03 and half the frame shared); scan the same area again")
    affine = _tile_affine(hb, ha, mb, ma, s0, int(tiles))
    affine, used, rms, ncc = _refine(hb, ha, mb, ma, affine, smooth=SMOOTH_PX)
    if not ncc >= MIN_CORRELATION:
        raise VerifyError(f"the scans do not show the same substrate: after the best affine fit their heights correlate "
                          f"{ncc:.2f} (need {MIN_CORRELATION}); scan the same area again, or pass the right --before")
    yy, xx = np.mgrid[0:ny:4, 0:nx:4]
    fx = affine[0, 0] * xx + affine[0, 1] * yy + affine[0, 2]
    fy = affine[1, 0] * xx + affine[1, 1] * yy + affine[1, 2]
    overlap = float(np.mean((fx >= 0) & (fx <= nx - 1) & (fy >= 0) & (fy <= ny - 1)))
    if overlap < MIN_OVERLAP:
        raise VerifyError(f"the scans share only {overlap:.0%} of the frame (need {MIN_OVERLAP:.0%}); scan the same "
                          "area again")
    c = np.array([(nx - 1) / 2, (ny - 1) / 2, 1.0])
    shift = affine @ c - c[:2]
    return Registration(affine, shift * np.array([after.dx, after.dy]), shift, overlap, used, rms)
