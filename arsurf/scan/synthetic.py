"""Synthetic AFM height maps with known geometry, for tests, demos and calibration.

Every generator returns a :class:`~arsurf.scan.scan.Scan` in SI units whose heights are
analytic (or, for :func:`rough`, a seeded Gaussian random field with known statistics), with
optional white noise and a tilt so that levelling and smoothing have work to do:

- :func:`calibration_grating` - rectangular (or trapezoidal) steps, as the MikroMasch TGZ
  gratings [MWCNT] uses to calibrate k_v with 20, 101.8 and 500 nm steps;
- :func:`sinusoid` - a sinusoidal grating;
- :func:`nanotubes` - cylinders (MWCNTs, [MWCNT]) lying on a flat substrate;
- :func:`nanoparticles` - spherical caps (or whole spheres) on a flat substrate;
- :func:`rough` - Gaussian random roughness with a given rms and correlation length.

:func:`write_demo_scans` writes the demo set (``arsurf synth --out scans``) as ``.npz`` files.
Heights are the surface seen from above by an ideal needle (no tip convolution): where a
sphere or cylinder is undercut, the map shows a vertical wall at its equator.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from arsurf import _validation
from arsurf.errors import SyntheticError
from arsurf.scan.scan import Scan

__all__ = [
    "SyntheticError",
    "SEED000_STEPS",
    "calibration_grating",
    "sinusoid",
    "nanotubes",
    "nanoparticles",
    "rough",
    "write_demo_scans",
]


#: Step heights (m) of the three Z calibration gratings of [MWCNT] (section 2.3.1, Fig. 3),
#: which gave 32, 156 and 710 mV of vertical PSD signal and k_v = 706 nm/V.
SEED000_STEPS = (20e-9, 101.8e-9, 500e-9)
#: Pitch of the MikroMasch TGZ01-03 step gratings (manufacturer's datasheet: 3.0 um).
TGZ_PITCH = 3e-6
# Random placement tries this many candidate positions per object before giving up.
_PLACEMENT_TRIES = 500


# ---------------------------------------------------------------------------------------------
# generators


def calibration_grating(
    step: float = SEED000_STEPS[1],
    *,
    shape: tuple[int, int] = (64, 256),
    pixel: float | tuple[float, float] = 25e-9,
    pitch: float = TGZ_PITCH,
    duty: float = 0.5,
    edge_width: float = 0.0,
    axis: str = "x",
    center: float | None = None,
    noise: float = 0.0,
    tilt: tuple[float, float] = (0.0, 0.0),
    seed: int | np.random.Generator | None = 0,
) -> Scan:
    r"""A step grating: plateaus of height ``step`` on a base at 0, periodic along ``axis``.

    With :math:`c = ((s - s_0) \bmod p) - p/2` the position within a period relative to the
    centre of a plateau (:math:`s` is x or y),

    .. math::

        z = h\, \mathrm{clip}\!\left(\frac{\eta p/2 - |c|}{e} + \tfrac12,\, 0,\, 1\right)
        \quad (e > 0), \qquad z = h\,[\,|c| < \eta p / 2\,] \quad (e = 0),

    where :math:`h` is the step, :math:`p` the pitch, :math:`\eta` the duty cycle (plateau
    width at half height over pitch) and :math:`e` the horizontal run of each linear edge.

    Parameters
    ----------
    step : float, metres
        Step height ([MWCNT] uses 20e-9, 101.8e-9 and 500e-9: :data:`SEED000_STEPS`).
    shape : (ny, nx) int
        Pixels.
    pixel : float or (dx, dy), metres
        Pixel spacing.
    pitch : float, metres
        Period of the grating (default 3 um, MikroMasch TGZ).
    duty : float
        Plateau width at half height divided by the pitch, in (0, 1).
    edge_width : float, metres
        Horizontal run of each edge (0 for vertical steps); below ``min(duty, 1-duty)*pitch``.
    axis : {"x", "y"}
        Direction along which the height changes (``"x"``: steps cross the fast scan axis).
    center : float, metres, optional
        Coordinate of the centre of one plateau; default: the middle of the scan plus a
        quarter pixel, so that no vertical edge falls exactly on a pixel centre.
    noise : float, metres
        Rms of added white Gaussian noise.
    tilt : (float, float)
        Plane slopes (dz/dx, dz/dy) added to the heights.
    seed : int, Generator or None
        Random seed of the noise.

    Returns
    -------
    Scan
        ``metadata["synthetic"]`` records the generator and its parameters.

    Examples
    --------
    >>> s = calibration_grating(20e-9, shape=(8, 240), pixel=25e-9)
    >>> float(s.heights.max() - s.heights.min())
    2e-08
    """
    h = _nonneg("step", step)
    ny, nx = _shape(shape)
    dx, dy = _pixel(pixel)
    p = _positive("pitch", pitch)
    eta = _finite("duty", duty)
    if not (0.0 < eta < 1.0):
        raise SyntheticError(f"`duty` must be in (0, 1) (got {duty!r}); it is plateau width / pitch")
    e = _nonneg("edge_width", edge_width)
    if e >= min(eta, 1.0 - eta) * p:
        raise SyntheticError(
            f"`edge_width` ({e:g} m) must be below min(duty, 1 - duty) * pitch = "
            f"{min(eta, 1.0 - eta) * p:g} m, or the plateaus vanish"
        )
    if axis not in ("x", "y"):
        raise SyntheticError(f"`axis` must be 'x' or 'y' (got {axis!r})")
    d, n = (dx, nx) if axis == "x" else (dy, ny)
    s0 = 0.5 * (n - 1) * d + 0.25 * d if center is None else _finite("center", center)
    s = np.arange(n) * d
    c = np.mod(s - s0 + 0.5 * p, p) - 0.5 * p
    half = 0.5 * eta * p
    if e > 0.0:
        prof = h * np.clip((half - np.abs(c)) / e + 0.5, 0.0, 1.0)
    else:
        prof = np.where(np.abs(c) < half, h, 0.0)
    z = np.broadcast_to(prof[None, :] if axis == "x" else prof[:, None], (ny, nx)).copy()
    params = dict(step=h, pitch=p, duty=eta, edge_width=e, axis=axis, center=s0)
    return _finish("calibration_grating", z, dx, dy, params, noise, tilt, seed, rng=None)


def sinusoid(
    shape: tuple[int, int] = (64, 64),
    pixel: float | tuple[float, float] = 10e-9,
    amplitude: float = 5e-9,
    period: float = 160e-9,
    *,
    angle: float = 0.0,
    phase: float = 0.0,
    noise: float = 0.0,
    tilt: tuple[float, float] = (0.0, 0.0),
    seed: int | np.random.Generator | None = 0,
) -> Scan:
    r"""A sinusoidal grating.

    .. math::

        z = A \sin\!\left(\frac{2\pi}{L}(x\cos\theta + y\sin\theta) + \varphi\right)

    Parameters
    ----------
    shape : (ny, nx) int
        Pixels.
    pixel : float or (dx, dy), metres
        Pixel spacing.
    amplitude : float, metres
        A, half the peak-to-peak height.
    period : float, metres
        Wavelength L.
    angle : float, radians
        Direction :math:`\theta` of the wave vector from the x axis.
    phase : float, radians
        :math:`\varphi`.
    noise, tilt, seed
        As in :func:`calibration_grating`.

    Examples
    --------
    >>> s = sinusoid(shape=(32, 32), pixel=10e-9, amplitude=5e-9, period=160e-9)
    >>> s.shape, round(float(s.heights.max()) * 1e9, 6)
    ((32, 32), 5.0)
    """
    ny, nx = _shape(shape)
    dx, dy = _pixel(pixel)
    a = _nonneg("amplitude", amplitude)
    L = _positive("period", period)
    th = _finite("angle", angle)
    ph = _finite("phase", phase)
    x = np.arange(nx) * dx
    y = np.arange(ny) * dy
    z = a * np.sin(2.0 * np.pi / L * (x[None, :] * math.cos(th) + y[:, None] * math.sin(th)) + ph)
    params = dict(amplitude=a, period=L, angle=th, phase=ph)
    return _finish("sinusoid", z, dx, dy, params, noise, tilt, seed, rng=None)


def nanotubes(
    shape: tuple[int, int] = (256, 256),
    pixel: float | tuple[float, float] = 4e-9,
    *,
    diameter: float | Sequence[float] = 15e-9,
    count: int = 3,
    length: float | tuple[float, float] = (300e-9, 600e-9),
    tubes: Sequence[tuple[float, float, float, float]] | None = None,
    noise: float = 0.0,
    tilt: tuple[float, float] = (0.0, 0.0),
    seed: int | np.random.Generator | None = 0,
) -> Scan:
    r"""Straight tubes (MWCNTs) of given diameter lying on a flat substrate at z = 0.

    A tube of radius r with axis from A to B (in the xy plane, at height r) is a capsule: a
    cylinder with hemispherical caps. With :math:`d` the distance from a pixel to the segment AB,

    .. math::

        z = r + \sqrt{r^2 - d^2} \quad (d \le r), \qquad z = 0 \quad (d > r),

    so the top is at the diameter 2r and the undercut lower half shows as a wall of height r at
    :math:`d = r`. Where tubes overlap the higher surface is kept.

    Parameters
    ----------
    shape : (ny, nx) int
        Pixels.
    pixel : float or (dx, dy), metres
        Pixel spacing.
    diameter : float or sequence of float, metres
        Tube diameter(s), one per tube or one for all.
    count : int
        Number of randomly placed tubes (ignored when ``tubes`` is given).
    length : float or (min, max), metres
        Length of the random tubes (axis end to end, caps excluded), fixed or uniform in a range.
    tubes : sequence of (x0, y0, x1, y1), metres, optional
        Explicit axis end points instead of random placement.
    noise, tilt, seed
        As in :func:`calibration_grating`; the seed also drives the placement.

    Returns
    -------
    Scan
        ``metadata["synthetic"]["tubes"]`` lists each tube's end points and diameter.

    Examples
    --------
    >>> s = nanotubes((64, 64), 2e-9, diameter=10e-9, tubes=[(20e-9, 60e-9, 100e-9, 70e-9)])
    >>> round(float(s.heights.max()) * 1e9, 2)
    10.0
    """
    ny, nx = _shape(shape)
    dx, dy = _pixel(pixel)
    rng = _rng(seed)
    X = np.arange(nx)[None, :] * dx
    Y = np.arange(ny)[:, None] * dy
    z = np.zeros((ny, nx))
    if tubes is not None:
        segs = [tuple(_finite("tubes", v) for v in t) for t in _seq_of_tuples("tubes", tubes, 4)]
        diams = _per_object("diameter", diameter, len(segs))
    else:
        n = _count("count", count)
        diams = _per_object("diameter", diameter, n)
        lo, hi = _range("length", length)
        segs = []
        w, hgt = (nx - 1) * dx, (ny - 1) * dy
        for i in range(n):
            r = 0.5 * diams[i]
            for _ in range(_PLACEMENT_TRIES):
                L = rng.uniform(lo, hi)
                th = rng.uniform(0.0, np.pi)
                hx, hy = 0.5 * L * math.cos(th), 0.5 * L * math.sin(th)
                mx, my = abs(hx) + r, abs(hy) + r
                if 2 * mx > w or 2 * my > hgt:
                    continue
                cx, cy = rng.uniform(mx, w - mx), rng.uniform(my, hgt - my)
                seg = (cx - hx, cy - hy, cx + hx, cy + hy)
                if all(_segment_distance(seg, s) > r + 0.5 * d + 2 * max(dx, dy) for s, d in zip(segs, diams)):
                    segs.append(seg)
                    break
            else:
                raise SyntheticError(
                    f"could not place tube {i + 1} of {n} (length {lo:g}-{hi:g} m, diameter {diams[i]:g} m) "
                    f"without touching the others in a {w:g} x {hgt:g} m scan; ask for fewer or shorter tubes "
                    "or a larger scan"
                )
    for (x0, y0, x1, y1), dia in zip(segs, diams):
        r = 0.5 * dia
        ux, uy = x1 - x0, y1 - y0
        ll = ux * ux + uy * uy
        t = np.clip(((X - x0) * ux + (Y - y0) * uy) / ll, 0.0, 1.0) if ll > 0 else np.zeros((1, 1))
        d2 = (X - (x0 + t * ux)) ** 2 + (Y - (y0 + t * uy)) ** 2
        inside = d2 <= r * r
        np.maximum(z, np.where(inside, r + np.sqrt(np.clip(r * r - d2, 0.0, None)), 0.0), out=z)
    params = dict(
        tubes=[{"start": [s[0], s[1]], "end": [s[2], s[3]], "diameter": d} for s, d in zip(segs, diams)],
    )
    return _finish("nanotubes", z, dx, dy, params, noise, tilt, seed, rng=rng)


def nanoparticles(
    shape: tuple[int, int] = (256, 256),
    pixel: float | tuple[float, float] = 4e-9,
    *,
    radius: float | Sequence[float] = 10e-9,
    height: float | Sequence[float] | None = None,
    count: int = 12,
    centers: Sequence[tuple[float, float]] | None = None,
    noise: float = 0.0,
    tilt: tuple[float, float] = (0.0, 0.0),
    seed: int | np.random.Generator | None = 0,
) -> Scan:
    r"""Spherical particles (caps of spheres) on a flat substrate at z = 0.

    A sphere of radius R whose top is at height h (0 < h <= 2R; centre at :math:`h - R`):

    .. math::

        z = \max\!\left(0,\; h - R + \sqrt{R^2 - \rho^2}\right) \quad (\rho \le R),
        \qquad z = 0 \quad (\rho > R),

    with :math:`\rho` the horizontal distance to the centre. ``h = 2R`` is a whole sphere
    resting on the substrate; ``h <= R`` a cap of base radius :math:`\sqrt{h(2R - h)}`.

    Parameters
    ----------
    shape : (ny, nx) int
        Pixels.
    pixel : float or (dx, dy), metres
        Pixel spacing.
    radius : float or sequence, metres
        Sphere radius R, one per particle or one for all.
    height : float or sequence, metres, optional
        Cap height h (default 2R, a whole sphere).
    count : int
        Number of randomly placed, non-touching particles (ignored when ``centers`` is given).
    centers : sequence of (x, y), metres, optional
        Explicit particle centres.
    noise, tilt, seed
        As in :func:`calibration_grating`; the seed also drives the placement.

    Returns
    -------
    Scan
        ``metadata["synthetic"]["particles"]`` lists each centre, radius and height.

    Examples
    --------
    >>> s = nanoparticles((64, 64), 1e-9, radius=8e-9, height=5e-9, centers=[(30e-9, 30e-9)])
    >>> round(float(s.heights.max()) * 1e9, 6)
    5.0
    """
    ny, nx = _shape(shape)
    dx, dy = _pixel(pixel)
    rng = _rng(seed)
    n = len(_seq_of_tuples("centers", centers, 2)) if centers is not None else _count("count", count)
    radii = _per_object("radius", radius, n)
    heights = [2.0 * r for r in radii] if height is None else _per_object("height", height, n)
    for r, h in zip(radii, heights):
        if h > 2.0 * r * (1.0 + 1e-12):
            raise SyntheticError(
                f"particle `height` ({h:g} m) cannot exceed the sphere diameter 2*radius ({2 * r:g} m)"
            )
    if centers is not None:
        pts = [tuple(_finite("centers", v) for v in c) for c in _seq_of_tuples("centers", centers, 2)]
    else:
        pts = []
        w, hgt = (nx - 1) * dx, (ny - 1) * dy
        gap = 2.0 * max(dx, dy)
        for i, r in enumerate(radii):
            tries = _PLACEMENT_TRIES if (2 * r <= w and 2 * r <= hgt) else 0
            for _ in range(tries):
                c = (rng.uniform(r, w - r), rng.uniform(r, hgt - r))
                if all(math.hypot(c[0] - q[0], c[1] - q[1]) > r + rq + gap for q, rq in zip(pts, radii)):
                    pts.append(c)
                    break
            if len(pts) != i + 1:
                raise SyntheticError(
                    f"could not place particle {i + 1} of {n} (radius {r:g} m) without touching the others "
                    f"in a {w:g} x {hgt:g} m scan; ask for fewer or smaller particles or a larger scan"
                )
    X = np.arange(nx)[None, :] * dx
    Y = np.arange(ny)[:, None] * dy
    z = np.zeros((ny, nx))
    for (cx, cy), R, h in zip(pts, radii, heights):
        rho2 = (X - cx) ** 2 + (Y - cy) ** 2
        cap = np.where(rho2 <= R * R, np.maximum(0.0, h - R + np.sqrt(np.clip(R * R - rho2, 0.0, None))), 0.0)
        np.maximum(z, cap, out=z)
    params = dict(
        particles=[{"center": [c[0], c[1]], "radius": r, "height": h} for c, r, h in zip(pts, radii, heights)],
    )
    return _finish("nanoparticles", z, dx, dy, params, noise, tilt, seed, rng=rng)


def rough(
    shape: tuple[int, int] = (256, 256),
    pixel: float | tuple[float, float] = 4e-9,
    *,
    rms: float = 1e-9,
    correlation_length: float = 20e-9,
    spectrum: str = "gaussian",
    hurst: float = 0.8,
    noise: float = 0.0,
    tilt: tuple[float, float] = (0.0, 0.0),
    seed: int | np.random.Generator | None = 0,
) -> Scan:
    r"""Periodic Gaussian random roughness with a Gaussian autocorrelation (or a power-law spectrum).

    White unit-variance noise :math:`w` is convolved (periodically, by FFT) with the sampled
    kernel :math:`g(\mathbf r) \propto \exp(-2|\mathbf r|^2/\xi^2)` normalised to
    :math:`\sum g^2 = 1`, then scaled by :math:`\sigma`:

    .. math::

        z = \sigma\, (g \circledast w), \qquad \mathrm{E}[z^2] = \sigma^2, \qquad
        \mathrm{E}[z(\mathbf r) z(\mathbf r + \boldsymbol\tau)] \approx \sigma^2
        \exp(-|\boldsymbol\tau|^2/\xi^2)

    (the autocorrelation is exact up to sampling when :math:`\xi` spans two pixels or more).
    The sample rms fluctuates around :math:`\sigma` by about :math:`\sigma\,\xi/\sqrt{2\,A}`
    for a scan of area A; the surface is periodic (it tiles).

    Parameters
    ----------
    shape : (ny, nx) int
        Pixels.
    pixel : float or (dx, dy), metres
        Pixel spacing.
    rms : float, metres
        Ensemble rms height :math:`\sigma`.
    correlation_length : float, metres
        :math:`\xi`, where the autocorrelation falls to 1/e; at least one pixel and at most a
        quarter of the scan side along each axis of more than one pixel.
    spectrum : ``"gaussian"`` or ``"power-law"``
        ``"power-law"``: the self-affine spectrum rolled off at :math:`q_0 = 1/\xi`,
        :math:`C(q) \propto (1 + q^2\xi^2)^{-(1 + H)}` (Persson et al. 2005, J. Phys.: Condens.
        Matter 17 R1: the power spectrum of most rough surfaces, flat below the roll-off and
        :math:`q^{-2(1+H)}` above it, down to the pixel), the same white noise filtered by
        :math:`\sqrt{C}` normalised to the ensemble rms :math:`\sigma`.
    hurst : float
        The Hurst exponent H of the power-law spectrum, in (0, 1].
    noise, tilt, seed
        As in :func:`calibration_grating`; the seed also drives the roughness.

    Examples
    --------
    >>> s = rough((128, 128), 2e-9, rms=1e-9, correlation_length=10e-9, seed=3)
    >>> bool(0.8e-9 < np.sqrt(np.mean(s.heights**2)) < 1.2e-9)
    True
    >>> p = rough((128, 128), 2e-9, rms=1e-9, correlation_length=10e-9, spectrum="power-law", seed=3)
    >>> bool(0.7e-9 < np.sqrt(np.mean(p.heights**2)) < 1.3e-9)
    True
    """
    ny, nx = _shape(shape)
    dx, dy = _pixel(pixel)
    sig = _nonneg("rms", rms)
    xi = _positive("correlation_length", correlation_length)
    for name, n, d in (("x", nx, dx), ("y", ny, dy)):
        if n > 1 and xi < d:
            raise SyntheticError(
                f"`correlation_length` ({xi:g} m) is shorter than the pixel along {name} ({d:g} m): the "
                "surface would be white noise; use `noise=` for that, or a finer pixel"
            )
        if n > 1 and xi > 0.25 * n * d:
            raise SyntheticError(
                f"`correlation_length` ({xi:g} m) exceeds a quarter of the scan side along {name} "
                f"({0.25 * n * d:g} m): the periodic surface would not be random at that scale; use a "
                "larger scan or a shorter length"
            )
    if spectrum not in ("gaussian", "power-law"):
        raise SyntheticError(f"`spectrum` must be 'gaussian' or 'power-law' (got {spectrum!r})")
    H = _finite("hurst", hurst)
    if not 0.0 < H <= 1.0:
        raise SyntheticError(f"`hurst` must be in (0, 1] (got {H!r}): the Hurst exponent of a self-affine surface")
    rng = _rng(seed)
    white = rng.standard_normal((ny, nx))
    if spectrum == "power-law":
        qx = 2.0 * np.pi * np.fft.fftfreq(nx, dx)
        qy = 2.0 * np.pi * np.fft.fftfreq(ny, dy)
        amp = (1.0 + (qx[None, :] ** 2 + qy[:, None] ** 2) * xi * xi) ** (-0.5 * (1.0 + H))
        amp /= math.sqrt(float(np.mean(amp * amp)))  # (1/N) sum |G|^2 = 1: ensemble rms sigma
        z = sig * np.real(np.fft.ifft2(np.fft.fft2(white) * amp))
        params = dict(rms=sig, correlation_length=xi, spectrum="power-law (1 + q^2 xi^2)^-(1+H)", hurst=H,
                      periodic=True)
        return _finish("rough", z, dx, dy, params, noise, tilt, seed, rng=rng)
    # periodic (minimum image) coordinates of the kernel
    kx = np.minimum(np.arange(nx), nx - np.arange(nx)) * dx
    ky = np.minimum(np.arange(ny), ny - np.arange(ny)) * dy
    g = np.exp(-2.0 * (kx[None, :] ** 2 + ky[:, None] ** 2) / (xi * xi))
    g /= math.sqrt(float(np.sum(g * g)))
    z = sig * np.fft.irfft2(np.fft.rfft2(white) * np.fft.rfft2(g), s=(ny, nx))
    params = dict(rms=sig, correlation_length=xi, acf="gaussian exp(-tau^2/xi^2)", periodic=True)
    return _finish("rough", z, dx, dy, params, noise, tilt, seed, rng=rng)


# ---------------------------------------------------------------------------------------------
# demo set


def _demo_specs() -> list[tuple[str, Any]]:
    tilt = (1.5e-3, -0.8e-3)
    specs: list[tuple[str, Any]] = []
    for h, name, nz in zip(SEED000_STEPS, ("20nm", "101p8nm", "500nm"), (0.5e-9, 1e-9, 2e-9)):
        specs.append(
            (
                f"grating_{name}",
                lambda h=h, nz=nz: calibration_grating(
                    h, shape=(64, 256), pixel=25e-9, edge_width=100e-9, noise=nz, tilt=tilt, seed=1
                ),
            )
        )
    specs += [
        ("sinusoid", lambda: sinusoid((64, 64), 10e-9, 5e-9, 160e-9, angle=0.3, noise=0.2e-9, seed=2)),
        ("nanotubes", lambda: nanotubes((256, 256), 4e-9, diameter=15e-9, count=3, noise=0.3e-9, tilt=tilt, seed=3)),
        (
            "nanoparticles",
            lambda: nanoparticles((256, 256), 4e-9, radius=15e-9, count=15, noise=0.3e-9, tilt=tilt, seed=4),
        ),
        ("rough", lambda: rough((256, 256), 4e-9, rms=1e-9, correlation_length=20e-9, noise=0.1e-9, seed=5)),
    ]
    return specs


#: Names of the demo scans :func:`write_demo_scans` writes (``<name>.npz``).
DEMO_SCANS = tuple(name for name, _ in _demo_specs())


def write_demo_scans(out_dir: str | Path) -> list[Path]:
    """Write the demo scans to ``out_dir`` as ``<name>.npz``; return their paths.

    Each file is written by :func:`arsurf.save_scan` (``.npz``, bit-exact, metadata as JSON
    with the generator and its parameters under ``"synthetic"``) and reads back with
    :func:`arsurf.load_scan`. The set: the three seed
    000 calibration gratings (20, 101.8 and 500 nm steps), a sinusoid, nanotubes, nanoparticles
    and a rough surface, with noise and tilt; about 2 MB in total.

    Examples
    --------
    >>> import tempfile
    >>> paths = write_demo_scans(tempfile.mkdtemp())
    >>> sorted(p.stem for p in paths)[:2]
    ['grating_101p8nm', 'grating_20nm']
    """
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SyntheticError(f"cannot create the output folder {str(out)!r}: {exc}; choose another --out") from exc
    from arsurf.scan.io import save_scan

    paths = []
    for name, make in _demo_specs():
        paths.append(save_scan(make(), out / f"{name}.npz"))
    return paths


# ---------------------------------------------------------------------------------------------
# helpers


def _finish(name, z, dx, dy, params, noise, tilt, seed, rng) -> Scan:
    """Add tilt and noise, build the Scan with the generator's record in the metadata."""
    nz = _nonneg("noise", noise)
    t = _seq_of_floats("tilt", tilt, 2)
    if rng is None:
        rng = _rng(seed)
    ny, nx = z.shape
    if t[0] or t[1]:
        z = z + t[0] * (np.arange(nx)[None, :] * dx) + t[1] * (np.arange(ny)[:, None] * dy)
    if nz > 0.0:
        z = z + nz * rng.standard_normal(z.shape)
    record = {
        "generator": name,
        **params,
        "noise": nz,
        "tilt": list(t),
        "seed": seed if isinstance(seed, (int, np.integer)) or seed is None else "Generator",
    }
    meta = {"synthetic": _jsonable(record), "history": []}
    return Scan(z, dx=dx, dy=dy, channel="Height", metadata=meta, source=f"synthetic:{name}")


def _jsonable(obj):
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    if isinstance(obj, (np.bool_, bool)):
        return bool(obj)
    if isinstance(obj, (np.integer, int)):
        return int(obj)
    if isinstance(obj, (np.floating, float)):
        return float(obj)
    if obj is None or isinstance(obj, str):
        return obj
    return str(obj)


def _rng(seed) -> np.random.Generator:
    if isinstance(seed, np.random.Generator):
        return seed
    if seed is None or (isinstance(seed, (int, np.integer)) and not isinstance(seed, bool) and seed >= 0):
        return np.random.default_rng(seed)
    raise SyntheticError(f"`seed` must be a non-negative int, a numpy Generator or None (got {seed!r})")


def _finite(name: str, value) -> float:
    return _validation.finite(value, name, SyntheticError)


def _positive(name: str, value) -> float:
    return _validation.positive(value, name, SyntheticError, unit="m", hint="lengths are in metres")


def _nonneg(name: str, value) -> float:
    return _validation.non_negative(value, name, SyntheticError, unit="m", hint="lengths are in metres")


def _shape(shape) -> tuple[int, int]:
    try:
        ny, nx = (int(v) for v in shape)
        ok = all(float(v) == int(v) for v in shape)
    except (TypeError, ValueError):
        raise SyntheticError(f"`shape` must be a pair of pixel counts (ny, nx) (got {shape!r})") from None
    if not ok or ny < 1 or nx < 1:
        raise SyntheticError(f"`shape` must be two positive integers (ny, nx) (got {shape!r})")
    return ny, nx


def _pixel(pixel) -> tuple[float, float]:
    if np.ndim(pixel) == 0:
        d = _positive("pixel", pixel)
        return d, d
    vals = _seq_of_floats("pixel", pixel, 2)
    return _positive("pixel (dx)", vals[0]), _positive("pixel (dy)", vals[1])


def _seq_of_floats(name: str, value, n: int) -> tuple[float, ...]:
    try:
        vals = tuple(value)
    except TypeError:
        raise SyntheticError(f"`{name}` must be a sequence of {n} numbers (got {value!r})") from None
    if len(vals) != n:
        raise SyntheticError(f"`{name}` must have {n} values (got {len(vals)}: {value!r})")
    return tuple(_finite(name, v) for v in vals)


def _seq_of_tuples(name: str, value, n: int) -> list[tuple]:
    try:
        items = [tuple(v) for v in value]
    except TypeError:
        raise SyntheticError(f"`{name}` must be a sequence of {n}-tuples in metres (got {value!r})") from None
    for it in items:
        if len(it) != n:
            raise SyntheticError(f"each entry of `{name}` must have {n} values (got {it!r})")
    return items


def _per_object(name: str, value, n: int) -> list[float]:
    if np.ndim(value) == 0:
        return [_positive(name, value)] * n
    vals = [_positive(name, v) for v in value]
    if len(vals) != n:
        raise SyntheticError(f"`{name}` has {len(vals)} values for {n} objects; give one value or one per object")
    return vals


def _count(name: str, value) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
        raise SyntheticError(f"`{name}` must be a non-negative integer (got {value!r})")
    return int(value)


def _range(name: str, value) -> tuple[float, float]:
    if np.ndim(value) == 0:
        v = _positive(name, value)
        return v, v
    lo, hi = _seq_of_floats(name, value, 2)
    if not (0.0 < lo <= hi):
        raise SyntheticError(f"`{name}` range must satisfy 0 < min <= max (got {value!r})")
    return lo, hi


def _segment_distance(a, b) -> float:
    """Shortest distance between two segments (x0, y0, x1, y1) in the plane."""
    p1, p2 = np.array(a[:2]), np.array(a[2:])
    q1, q2 = np.array(b[:2]), np.array(b[2:])

    def cross(o, u, v):
        return (u[0] - o[0]) * (v[1] - o[1]) - (u[1] - o[1]) * (v[0] - o[0])

    d1, d2 = cross(q1, q2, p1), cross(q1, q2, p2)
    d3, d4 = cross(p1, p2, q1), cross(p1, p2, q2)
    if d1 * d2 < 0 and d3 * d4 < 0:
        return 0.0

    def point_seg(p, s1, s2):
        u = s2 - s1
        ll = float(u @ u)
        t = 0.0 if ll == 0 else min(1.0, max(0.0, float((p - s1) @ u) / ll))
        return float(np.hypot(*(p - (s1 + t * u))))

    return min(point_seg(p1, q1, q2), point_seg(p2, q1, q2), point_seg(q1, p1, p2), point_seg(q2, p1, p2))
