r"""The virtual AFM images its sample: raster lines, the tip's dilation, feedback lag, noise, drift.

An image is what the Z feedback reads while the tip rasters the sample (contact mode): the sample
seen through the tip (a grey-scale dilation), sampled where the drifting stage really was, lagged
by the feedback loop, plus the photodiode's noise.

Sample (:class:`Sample`): the substrate (a :class:`~arsurf.scan.scan.Scan`), the dent a session
left in it (heights added, metres; negative is pressed in) and nano-objects at their poses - any
object with ``height_map(x, y)`` giving its top surface and NaN off it (a
:class:`~arsurf.manipulation.nanotube.Nanotube`); the surface is ``fmax(substrate + dent,
objects)``.

Tip (:class:`TipShape`): a sphere of radius :math:`R` on a cone of half-angle :math:`\theta`,
its height above the apex at horizontal distance :math:`\rho`

.. math::

    t(\rho) = R - \sqrt{R^2 - \rho^2} \quad (\rho \le R\cos\theta), \qquad
    t(\rho) = R(1 - \sin\theta) + (\rho - R\cos\theta)/\tan\theta \quad \text{otherwise}.

Image (Villarrubia 1997, J. Res. NIST 102, 425, Eq. 5: the image is the surface dilated by the
reflected tip): the apex height where the tip first touches,

.. math:: I(\mathbf x) = \max_{\mathbf u}\,\big[S(\mathbf x + \mathbf u) - t(|\mathbf u|)\big],

computed on a grid finer than the image (:func:`dilate`, a compiled kernel over the tip's
footprint), then sampled bilinearly.

Raster (:class:`ScanSettings`): lines along x (the fast axis) at ``line_speed``, trace then
retrace, the slow axis up (row 0 first) or down; pixel (ix, iy) of the trace is taken at
:math:`t = t_0 + k_y T_{line} + (i_x + \tfrac12) \Delta x / v`, with :math:`T_{line} = 2 n_x
\Delta x / v` and :math:`k_y` the line's rank in time.

Thermal drift (:class:`ThermalDrift`): the stage creeps at a slow velocity that changes between
scans; the tip is at the commanded point plus :math:`\mathbf d(t) = \mathbf d_0 + \mathbf v t`
(x, y, z). Linear in time, it makes the image an *affine* view of the sample (a shift, a shear
along x and a stretch along y); :attr:`ScanTruth.pixel_to_sample` is that map, which the virtual
instrument knows exactly. z drift adds a plane.

Feedback (:class:`ScanSettings` ``feedback_bandwidth``): the Z loop follows the surface as a
first-order low pass of corner :math:`f_c`; the image is the loop's output along each line,
sampled ``oversample`` times per pixel and averaged over the pixel (the lag is a shift of
about :math:`v / (2\pi f_c)` along the scan direction and a softened trailing edge).

Noise: the photodiode's noise (:class:`~arsurf.instrument.instrument.PhotodiodeNoise`) read as
height through the deflection sensitivity, averaged over a pixel's samples at the noise's rate:
:math:`\sigma_z = \sigma |S_n| / \sqrt{\max(1, \tau_{px} f_s)}`.

Examples
--------
>>> import numpy as np
>>> from arsurf.scan.scan import Scan
>>> flat = Scan(np.zeros((40, 40)), dx=5e-9, dy=5e-9)
>>> tip = TipShape(radius=10e-9, half_angle=np.radians(20))
>>> round(float(tip.height(10e-9 * np.cos(np.radians(20)))) * 1e9, 3)   # where the sphere meets the cone, nm
6.58
>>> img, truth = acquire(Sample(flat), ScanSettings((32, 32), (160e-9, 160e-9), origin=(20e-9, 20e-9)), tip,
...                      seed=1, noise_sigma=0.0)
>>> img.shape, float(abs(img.heights).max()) < 1e-15
((32, 32), True)
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
from numba import njit

from arsurf._validation import real
from arsurf.errors import InstrumentError
from arsurf.scan.scan import Scan

__all__ = ["Sample", "TipShape", "ScanSettings", "ThermalDrift", "ScanTruth", "Imaging", "dilate", "acquire",
           "pixel_noise"]


def _real(name: str, value, what: str, *, positive: bool = False, nonneg: bool = False) -> float:
    return real(value, name, what, InstrumentError, positive=positive, nonneg=nonneg)


def _pair(name: str, value, what: str, *, positive: bool = False) -> tuple[float, float]:
    try:
        a, b = value
    except (TypeError, ValueError):
        raise InstrumentError(f"{name} must be two numbers ({what}) (got {value!r})") from None
    return (_real(name, a, what, positive=positive), _real(name, b, what, positive=positive))


# ------------------------------------------------------------------------------------------------
# the sample and the tip
# ------------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Sample:
    """What lies under the tip: substrate + dent, and the objects on it.

    Parameters
    ----------
    substrate : Scan
        Heights in metres; pixel (ix, iy) at x = ix dx, y = iy dy (the sample frame).
    dent : (ny, nx) float array, metres, optional
        Added to the substrate (the dent a session left; negative is pressed in).
    objects : sequence
        Each with ``height_map(x, y)`` (metres, NaN off the object), e.g. Nanotube at its pose.
    """

    substrate: Scan
    dent: np.ndarray | None = None
    objects: tuple = ()

    def __post_init__(self) -> None:
        if not isinstance(self.substrate, Scan):
            raise InstrumentError(f"the sample's substrate must be an arsurf Scan (got {type(self.substrate).__name__})")
        if self.substrate.nan_count:
            raise InstrumentError(f"the substrate has {self.substrate.nan_count} missing (NaN) pixels; inpaint it "
                                  "(arsurf.inpaint) before the virtual AFM images it")
        if self.dent is not None:
            d = np.array(self.dent, dtype=np.float64)
            if d.shape != self.substrate.shape or not np.isfinite(d).all():
                raise InstrumentError(f"the dent must be finite heights (m) of the substrate's shape "
                                      f"{self.substrate.shape} (got shape {d.shape})")
            d.setflags(write=False)
            object.__setattr__(self, "dent", d)
        objs = tuple(self.objects)
        for o in objs:
            if not callable(getattr(o, "height_map", None)):
                raise InstrumentError(f"a sample object needs height_map(x, y) (got {type(o).__name__})")
        object.__setattr__(self, "objects", objs)

    def heights(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """True surface height (metres) at the points (x, y) (broadcast), substrate bilinear,
        clamped at its border."""
        s = self.substrate
        z = s.heights if self.dent is None else s.heights + self.dent
        x, y = np.broadcast_arrays(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))
        out = _bilinear(z, x / s.dx, y / s.dy)
        for o in self.objects:
            out = np.fmax(out, o.height_map(x, y))
        return out


def _bilinear(z: np.ndarray, fx: np.ndarray, fy: np.ndarray) -> np.ndarray:
    """Bilinear interpolation of z[iy, ix] at fractional pixel indexes, clamped to the grid."""
    ny, nx = z.shape
    fx = np.clip(fx, 0.0, nx - 1.0)
    fy = np.clip(fy, 0.0, ny - 1.0)
    ix = np.minimum(fx.astype(np.int64), max(nx - 2, 0))
    iy = np.minimum(fy.astype(np.int64), max(ny - 2, 0))
    tx, ty = fx - ix, fy - iy
    ix1, iy1 = np.minimum(ix + 1, nx - 1), np.minimum(iy + 1, ny - 1)
    return ((1 - tx) * (1 - ty) * z[iy, ix] + tx * (1 - ty) * z[iy, ix1]
            + (1 - tx) * ty * z[iy1, ix] + tx * ty * z[iy1, ix1])


@dataclass(frozen=True)
class TipShape:
    """A sphere of radius ``radius`` (m) on a cone of half-angle ``half_angle`` (rad, in (0, pi/2))."""

    radius: float
    half_angle: float = math.radians(20.0)

    def __post_init__(self) -> None:
        object.__setattr__(self, "radius", _real("radius", self.radius, "the tip radius in metres", positive=True))
        a = _real("half_angle", self.half_angle, "the cone half-angle in radians", positive=True)
        if not a < 0.5 * math.pi:
            raise InstrumentError(f"half_angle must be below pi/2 rad (got {a!r}); a cone of 90 deg is a plane")
        object.__setattr__(self, "half_angle", a)

    def height(self, rho) -> np.ndarray:
        """t(rho): the tip surface's height above its apex at horizontal distance ``rho`` (m)."""
        rho = np.abs(np.asarray(rho, dtype=np.float64))
        R, th = self.radius, self.half_angle
        r_t = R * math.cos(th)
        sphere = R - np.sqrt(np.maximum(R * R - np.minimum(rho, r_t) ** 2, 0.0))
        return np.where(rho <= r_t, sphere, R * (1.0 - math.sin(th)) + (rho - r_t) / math.tan(th))

    def reach(self, depth: float) -> float:
        """Horizontal distance (m) at which the tip rises ``depth`` above its apex."""
        R, th = self.radius, self.half_angle
        r_t = R * math.cos(th)
        t_t = R * (1.0 - math.sin(th))
        if depth <= t_t:
            return math.sqrt(max(R * R - (R - depth) ** 2, 0.0))
        return r_t + (depth - t_t) * math.tan(th)

    def footprint(self, dx: float, dy: float, depth: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(oy, ox, t): pixel offsets of the tip's footprint on a (dx, dy) grid where it rises less
        than ``depth``, and its height there (m)."""
        r = self.reach(depth)
        kx, ky = int(math.ceil(r / dx)), int(math.ceil(r / dy))
        oy, ox = np.mgrid[-ky:ky + 1, -kx:kx + 1]
        t = self.height(np.hypot(ox * dx, oy * dy))
        keep = t <= depth
        return oy[keep].astype(np.int64), ox[keep].astype(np.int64), t[keep]


@njit(cache=True)
def _dilate_kernel(z, oy, ox, t, out):
    """out[i, j] = max_k z[i + oy_k, j + ox_k] - t_k over the offsets inside the grid (one pass
    per offset over the rows and columns it keeps inside: contiguous inner loops)."""
    ny, nx = z.shape
    out[:, :] = -np.inf
    for k in range(oy.size):
        dy, dx, tk = oy[k], ox[k], t[k]
        i0, i1 = max(0, -dy), min(ny, ny - dy)
        j0, j1 = max(0, -dx), min(nx, nx - dx)
        for i in range(i0, i1):
            zr = z[i + dy]
            orow = out[i]
            for j in range(j0, j1):
                orow[j] = max(orow[j], zr[j + dx] - tk)


def dilate(heights: np.ndarray, dx: float, dy: float, tip: TipShape) -> np.ndarray:
    r"""The image a tip records of ``heights`` (metres, spacing dx, dy): Villarrubia's dilation
    :math:`I = \max_u [S(x + u) - t(u)]` over the tip's footprint within the height range.

    Examples
    --------
    >>> z = np.zeros((21, 21)); z[10, 10] = 5e-9          # a 5 nm spike images as the tip itself
    >>> img = dilate(z, 1e-9, 1e-9, TipShape(4e-9))
    >>> round(float(img[10, 13]) * 1e9, 4), round(float(5e-9 - TipShape(4e-9).height(3e-9)) * 1e9, 4)
    (3.6458, 3.6458)
    """
    z = np.ascontiguousarray(heights, dtype=np.float64)
    depth = float(np.ptp(z)) if z.size else 0.0
    oy, ox, t = tip.footprint(float(dx), float(dy), depth + 1e-15)
    out = np.empty_like(z)
    _dilate_kernel(z, oy, ox, t, out)
    return out


# ------------------------------------------------------------------------------------------------
# the raster and the drift
# ------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ScanSettings:
    """The raster the controller runs.

    Parameters
    ----------
    pixels : (nx, ny)
        Pixels per line and lines.
    size : (width, height), metres
        Scan size as pixels x spacing (the Scan's :attr:`~arsurf.scan.scan.Scan.extent`).
    origin : (x, y), metres
        Centre of the first pixel in the sample frame.
    line_speed : float, m/s
        Tip speed along a line (trace and retrace).
    direction : "up" or "down"
        Slow axis: up acquires row 0 (bottom) first.
    feedback_bandwidth : float, Hz
        Corner frequency of the Z loop (first-order).
    oversample : int
        Loop samples per pixel (the lag filter's time step is a pixel time over this).
    """

    pixels: tuple
    size: tuple
    origin: tuple = (0.0, 0.0)
    line_speed: float = 2e-6
    direction: str = "up"
    feedback_bandwidth: float = 2e3
    oversample: int = 4

    def __post_init__(self) -> None:
        try:
            nx, ny = (int(v) for v in self.pixels)
            ok = all(int(v) == v for v in self.pixels)
        except (TypeError, ValueError):
            raise InstrumentError(f"pixels must be (nx, ny) integers (got {self.pixels!r})") from None
        if not ok or not (8 <= nx <= 4096 and 8 <= ny <= 4096):
            raise InstrumentError(f"pixels must be (nx, ny) integers in 8..4096 (got {self.pixels!r})")
        object.__setattr__(self, "pixels", (nx, ny))
        object.__setattr__(self, "size", _pair("size", self.size, "scan width and height in metres", positive=True))
        object.__setattr__(self, "origin", _pair("origin", self.origin, "first pixel centre in metres"))
        object.__setattr__(self, "line_speed", _real("line_speed", self.line_speed, "m/s", positive=True))
        object.__setattr__(self, "feedback_bandwidth",
                           _real("feedback_bandwidth", self.feedback_bandwidth, "Hz", positive=True))
        if self.direction not in ("up", "down"):
            raise InstrumentError(f"direction must be 'up' or 'down' (got {self.direction!r})")
        if isinstance(self.oversample, bool) or int(self.oversample) != self.oversample or not 1 <= self.oversample <= 64:
            raise InstrumentError(f"oversample must be an integer in 1..64 (got {self.oversample!r})")

    @property
    def spacing(self) -> tuple[float, float]:
        """(dx, dy), metres."""
        return (self.size[0] / self.pixels[0], self.size[1] / self.pixels[1])

    @property
    def pixel_time(self) -> float:
        """Seconds the tip spends over one pixel of a line."""
        return self.spacing[0] / self.line_speed

    @property
    def line_time(self) -> float:
        """Seconds per line, trace and retrace."""
        return 2.0 * self.size[0] / self.line_speed

    @property
    def duration(self) -> float:
        """Seconds per frame."""
        return self.pixels[1] * self.line_time


@dataclass
class ThermalDrift:
    """Slow thermal drift of the stage: position offset (m) and velocity (m/s), x, y, z.

    Each scan draws a new velocity (:meth:`new_scan`): normal with standard deviations
    ``rate_xy`` (x and y) and ``rate_z`` (m/s), from a seeded generator; the offset carries over
    in time (:meth:`advance`).
    """

    rate_xy: float = 0.0
    rate_z: float = 0.0
    seed: int = 0
    offset: np.ndarray = field(default_factory=lambda: np.zeros(3))
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        self.rate_xy = _real("rate_xy", self.rate_xy, "drift speed in m/s", nonneg=True)
        self.rate_z = _real("rate_z", self.rate_z, "drift speed in m/s", nonneg=True)
        self.offset = np.array(self.offset, dtype=np.float64).reshape(3)
        self.velocity = np.array(self.velocity, dtype=np.float64).reshape(3)
        self._rng = np.random.default_rng([int(self.seed), 31])

    def new_scan(self) -> None:
        """A new velocity for the next scan (the drift differs between scans)."""
        self.velocity = self._rng.standard_normal(3) * np.array([self.rate_xy, self.rate_xy, self.rate_z])

    def advance(self, seconds: float) -> None:
        """Let ``seconds`` pass at the current velocity."""
        self.offset = self.offset + self.velocity * float(seconds)


@dataclass(frozen=True)
class ScanTruth:
    """What the virtual instrument knows about an image it took.

    Attributes
    ----------
    pixel_to_sample : (2, 3) float
        Affine map of pixel indexes (ix, iy, 1) to the sample point the trace pixel saw, metres
        (drift included; exact for a linear drift).
    drift_start, drift_velocity : (3,) float
        Drift offset (m) at the frame's first pixel and its velocity (m/s).
    start_time : float, s
    noise_sigma : float, m
        Height noise per pixel.
    """

    pixel_to_sample: np.ndarray
    drift_start: np.ndarray
    drift_velocity: np.ndarray
    start_time: float
    noise_sigma: float
    duration: float

    def to_metadata(self) -> dict:
        return {"pixel_to_sample_m": self.pixel_to_sample.tolist(), "drift_start_m": self.drift_start.tolist(),
                "drift_velocity_m_per_s": self.drift_velocity.tolist(), "start_time_s": self.start_time,
                "noise_sigma_m": self.noise_sigma, "duration_s": self.duration}

    @classmethod
    def from_metadata(cls, meta) -> "ScanTruth":
        """The truth :meth:`to_metadata` wrote (an image of the virtual AFM)."""
        try:
            return cls(np.array(meta["pixel_to_sample_m"], dtype=np.float64).reshape(2, 3),
                       np.array(meta["drift_start_m"], dtype=np.float64).reshape(3),
                       np.array(meta["drift_velocity_m_per_s"], dtype=np.float64).reshape(3),
                       float(meta["start_time_s"]), float(meta["noise_sigma_m"]), float(meta["duration_s"]))
        except (KeyError, TypeError, ValueError) as exc:
            raise InstrumentError(f"not a virtual-AFM truth record ({exc})") from None


@njit(cache=True)
def _feedback_kernel(z, alpha, oversample, reverse, out):
    """First-order lag along each row of sub-samples z[row, n*oversample], averaged per pixel."""
    ny, m = z.shape
    n = m // oversample
    for i in range(ny):
        first = m - 1 if reverse else 0
        y = z[i, first]
        for p in range(n):
            acc = 0.0
            for s in range(oversample):
                k = p * oversample + s
                if reverse:
                    k = m - 1 - k
                y += alpha * (z[i, k] - y)
                acc += y
            j = n - 1 - p if reverse else p
            out[i, j] = acc / oversample


def acquire(sample: Sample, settings: ScanSettings, tip: TipShape, *, drift: ThermalDrift | None = None,
            start_time: float = 0.0, noise_sigma: float = 0.0, seed: int = 0, render_oversample: int = 2,
            metadata: dict | None = None) -> tuple[Scan, ScanTruth]:
    """Image ``sample`` with ``tip`` over the raster ``settings`` (the trace, Z channel).

    Parameters
    ----------
    sample : Sample
    settings : ScanSettings
    tip : TipShape
    drift : ThermalDrift, optional
        Its current offset and velocity apply (advanced here by the frame's duration).
    start_time : float, s
        The instrument's clock at the frame's start (recorded).
    noise_sigma : float, m
        Height noise per pixel (the caller's photodiode noise seen through the sensitivity).
    seed : int
        Seed of the noise.
    render_oversample : int
        The dilation's grid is this many times finer than the image.
    metadata : dict, optional
        Merged into the Scan's metadata (instrument description).

    Returns
    -------
    (Scan, ScanTruth)
        The image (row 0 = bottom, as every reader gives it) and what the instrument knows.
    """
    if not isinstance(sample, Sample):
        raise InstrumentError(f"acquire needs a Sample (got {type(sample).__name__})")
    if not isinstance(settings, ScanSettings) or not isinstance(tip, TipShape):
        raise InstrumentError("acquire needs ScanSettings and a TipShape")
    noise_sigma = _real("noise_sigma", noise_sigma, "height noise per pixel in metres", nonneg=True)
    drift = drift if drift is not None else ThermalDrift()
    nx, ny = settings.pixels
    dx, dy = settings.spacing
    x0, y0 = settings.origin
    v = settings.line_speed
    os_ = int(settings.oversample)
    # times of the sub-samples of the trace: row iy is acquired k_y-th
    ky = np.arange(ny) if settings.direction == "up" else (ny - 1 - np.arange(ny))
    sub = (np.arange(nx * os_) + 0.5) / os_ - 0.5  # sub-sample positions in pixels along x
    t = ky[:, None] * settings.line_time + (sub[None, :] + 0.5) * dx / v  # (ny, nx*os)
    d0, vel = drift.offset.copy(), drift.velocity.copy()
    px = x0 + sub[None, :] * dx + d0[0] + vel[0] * t
    py = y0 + np.arange(ny)[:, None] * dy + d0[1] + vel[1] * t
    # the dilated surface on a fine grid covering every point visited
    g = float(render_oversample)
    gdx, gdy = dx / g, dy / g
    reach = tip.reach(float(np.ptp(sample.substrate.heights)) + _objects_height(sample) + 1e-9)
    gx0, gx1 = px.min() - reach - 2 * gdx, px.max() + reach + 2 * gdx
    gy0, gy1 = py.min() - reach - 2 * gdy, py.max() + reach + 2 * gdy
    gx = gx0 + np.arange(int(math.ceil((gx1 - gx0) / gdx)) + 1) * gdx
    gy = gy0 + np.arange(int(math.ceil((gy1 - gy0) / gdy)) + 1) * gdy
    if gx.size * gy.size > 64e6:
        raise InstrumentError(f"the imaging grid would have {gx.size} x {gy.size} points; scan a smaller area or "
                              "use fewer pixels")
    surf = sample.heights(gx[None, :], gy[:, None])
    img = dilate(surf, gdx, gdy, tip)
    z = _bilinear(img, (px - gx0) / gdx, (py - gy0) / gdy) + d0[2] + vel[2] * t
    alpha = 1.0 - math.exp(-2.0 * math.pi * settings.feedback_bandwidth * settings.pixel_time / os_)
    h = np.empty((ny, nx))
    _feedback_kernel(np.ascontiguousarray(z), alpha, os_, False, h)
    if noise_sigma > 0.0:
        h += np.random.default_rng([int(seed), 7]).standard_normal(h.shape) * noise_sigma
    # the exact affine map of the trace pixel (ix, iy) to the sample (drift linear in time)
    tp = settings.pixel_time
    a = np.array([[dx + vel[0] * tp, vel[0] * settings.line_time * (1 if settings.direction == "up" else -1),
                   x0 + d0[0] + vel[0] * (0.5 * tp + (0 if settings.direction == "up" else (ny - 1) * settings.line_time))],
                  [vel[1] * tp, dy + vel[1] * settings.line_time * (1 if settings.direction == "up" else -1),
                   y0 + d0[1] + vel[1] * (0.5 * tp + (0 if settings.direction == "up" else (ny - 1) * settings.line_time))]])
    drift.advance(settings.duration)
    truth = ScanTruth(a, d0, vel, float(start_time), noise_sigma, settings.duration)
    meta = {"format": "virtual-afm", "channels": ["Z"], "channel_units": {"Z": "m"}, "direction": "forward",
            "z_unit": "m", "height": True, "file_z_unit": "m", "row0": "bottom", "rows_flipped": False,
            "nan_count": 0, "inf_count": 0,
            "instrument": {"software": "arsurf virtual AFM", "format": "virtual-afm", "scan_dir": settings.direction,
                           "line_speed_m_per_s": v, "feedback_bandwidth_Hz": settings.feedback_bandwidth,
                           "tip_radius_m": tip.radius, "tip_half_angle_rad": tip.half_angle,
                           "origin_m": list(settings.origin)},
            "virtual_afm": truth.to_metadata()}
    if metadata:
        meta.update(metadata)
    scan = Scan(h, dx=dx, dy=dy, channel="Z", metadata=meta, source="virtual-afm")
    return scan, truth


def _objects_height(sample: Sample) -> float:
    """An upper bound of the objects' height above the substrate's lowest point (m); a micrometre
    for an object that does not state its axis height and radius."""
    top = 0.0
    low = float(sample.substrate.heights.min())
    for o in sample.objects:
        h, r = getattr(o, "axis_height", None), getattr(o, "radius", None)
        top = max(top, float(h) + float(r) - low if h is not None and r is not None else 1e-6)
    return top


def pixel_noise(noise, sensitivity: float, pixel_time: float) -> float:
    r"""Height noise per pixel (m): the photodiode's rms noise ``noise.sigma`` (signal units) times
    the deflection sensitivity (m per unit), averaged over the pixel's samples at ``noise.rate``:
    :math:`\sigma |S_n| / \sqrt{\max(1, \tau f_s)}`."""
    return float(noise.sigma) * abs(float(sensitivity)) / math.sqrt(max(1.0, float(pixel_time) * float(noise.rate)))


class Imaging:
    """The virtual AFM's imaging state: its sample, tip, drift, default raster and frame count.

    Parameters
    ----------
    sample : Sample or Scan or None
        A Scan is a bare substrate; None (or a number/function surface): no image can be taken.
    tip : TipShape, optional
        Default a 10 nm sphere on a 20 deg cone.
    drift : ThermalDrift, optional
        Default no drift.
    settings : ScanSettings, optional
        Default: the whole substrate at its own pixels (at most 512 a side).
    seed : int
        Seeds each frame's noise (with the frame count).
    """

    def __init__(self, sample=None, tip: TipShape | None = None, drift: ThermalDrift | None = None,
                 settings: ScanSettings | None = None, seed: int = 0) -> None:
        if isinstance(sample, Scan):
            sample = Sample(sample)
        self.sample = sample if isinstance(sample, Sample) else None
        self.tip = TipShape(10e-9) if tip is None else tip
        if not isinstance(self.tip, TipShape):
            raise InstrumentError(f"imaging_tip must be a TipShape (got {type(self.tip).__name__})")
        self.drift = ThermalDrift() if drift is None else drift
        if not isinstance(self.drift, ThermalDrift):
            raise InstrumentError(f"drift must be a ThermalDrift (got {type(self.drift).__name__})")
        if settings is not None and not isinstance(settings, ScanSettings):
            raise InstrumentError(f"scan_settings must be ScanSettings (got {type(settings).__name__})")
        self.settings = settings
        self.seed = int(seed)
        self.frames = 0
        self._last_time: float | None = None

    def default_settings(self) -> ScanSettings:
        """The whole substrate at its own pixel spacing (at most 512 pixels a side)."""
        s = self._need_sample().substrate
        ny, nx = s.shape
        nx_, ny_ = min(max(nx, 8), 512), min(max(ny, 8), 512)
        w, h = s.size
        return ScanSettings((nx_, ny_), (w * nx_ / max(nx_ - 1, 1), h * ny_ / max(ny_ - 1, 1)))

    def _need_sample(self) -> Sample:
        if self.sample is None:
            raise InstrumentError("the virtual AFM has no sample to image: give it a Scan surface or sample=Sample(...)")
        return self.sample

    def acquire(self, settings: ScanSettings | None, time: float, noise, sensitivity: float) -> Scan:
        """One frame (:func:`acquire`) with a new drift velocity, the photodiode noise as height."""
        sample = self._need_sample()
        st = settings if settings is not None else (self.settings or self.default_settings())
        if not isinstance(st, ScanSettings):
            raise InstrumentError(f"scan settings must be ScanSettings (got {type(st).__name__})")
        if self._last_time is not None:  # the drift went on between frames, at the last velocity
            self.drift.advance(max(0.0, float(time) - self._last_time))
        self.drift.new_scan()
        self.frames += 1
        self._last_time = float(time) + st.duration
        scan, _ = acquire(sample, st, self.tip, drift=self.drift, start_time=time,
                          noise_sigma=pixel_noise(noise, sensitivity, st.pixel_time), seed=self.seed * 1000 + self.frames)
        return scan
