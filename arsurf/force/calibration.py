"""Calibration of the force sensor: sensitivities, lateral gain, friction and spring constant.

Each function returns a :class:`CalibrationResult` (value, one-sigma uncertainty, fit residuals,
95 % confidence interval, and the fit details):

* :func:`vertical_sensitivity_from_steps` - k_v from calibration-grating steps ([MWCNT], 2.3.1).
* :func:`lateral_sensitivity_from_vertical` - k_h from k_v and the lever length ([MWCNT], 2.3.2).
* :func:`normal_sensitivity_from_curve` - S_n from an approach(-retract) curve with automatic
  contact-point detection ([Alabdulmuhsin], 4.1.1).
* :func:`wedge_calibration` / :func:`wedge_from_slopes` - lateral gain G_l and friction mu from
  sliding up and down a tilted surface ([Alabdulmuhsin], 4.1.2; derived from the force balance Eq. 15-18,
  not from the thesis' Eq. 23-24, which invert the signal ratio - docs/design.rst, "Known errors in the sources").
* :func:`thermal_spring_constant` - k from the thermal noise spectrum (Hutter & Bechhoefer 1993,
  with the Butt & Jaschke 1995 correction).
* :func:`torsional_stiffness_from_geometry` (re-exported from :mod:`arsurf.force.cantilever`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from arsurf.errors import ForceError
from arsurf.force.cantilever import torsional_stiffness_from_geometry
from arsurf.force.simulate import BOLTZMANN

__all__ = [
    "BOLTZMANN",
    "CalibrationResult",
    "OPTICAL_LEVER_FIRST_MODE",
    "POINT_MASS",
    "TRUE_DEFLECTION_FIRST_MODE",
    "WedgeCalibration",
    "lateral_sensitivity_from_vertical",
    "normal_sensitivity_from_curve",
    "sho_psd",
    "thermal_spring_constant",
    "torsional_stiffness_from_geometry",
    "vertical_sensitivity_from_steps",
    "wedge_calibration",
    "wedge_from_slopes",
]

# ---- thermal-noise correction factors: k = factor * k_B T / <z^2> of the first mode ------------
#: Optical-lever detection of a rectangular lever, first mode only (Butt & Jaschke 1995,
#: Nanotechnology 6, 1-7): the end slope of mode 1 is 0.918x that of a static end load.
OPTICAL_LEVER_FIRST_MODE = 0.817
#: True end deflection (interferometric detection), first mode only: 12 / alpha_1^4 (Butt & Jaschke).
TRUE_DEFLECTION_FIRST_MODE = 0.971
#: Point-mass harmonic oscillator, plain equipartition (Hutter & Bechhoefer 1993, RSI 64, 1868).
POINT_MASS = 1.0

_Z95 = 1.959963984540054  # two-sided 95 % normal quantile


@dataclass(frozen=True)
class CalibrationResult:
    """A calibrated quantity and how well the data determine it.

    Attributes
    ----------
    value : float
        The estimate, SI units (stated by the function).
    uncertainty : float
        One standard deviation of ``value`` (from the fit covariance / residual scatter).
    residuals : ndarray
        Residuals of the underlying fit (data minus model, units stated by the function).
    confidence_interval : (float, float)
        95 % interval for ``value``.
    method : str
    details : dict
        Other fit outputs (contact point, resonance, slopes...).
    """

    value: float
    uncertainty: float
    residuals: np.ndarray
    confidence_interval: tuple[float, float]
    method: str
    details: dict = field(default_factory=dict)


def _vector(name: str, values, min_size: int = 1) -> np.ndarray:
    a = np.asarray(values, dtype=np.float64)
    if a.ndim != 1:
        raise ForceError(f"{name} must be a 1-D array (got shape {a.shape})")
    if a.size < min_size:
        raise ForceError(f"{name} needs at least {min_size} samples (got {a.size})")
    if not np.all(np.isfinite(a)):
        raise ForceError(f"{name} contains NaN or infinite values; drop or interpolate those samples")
    return a


def _t95(dof: int) -> float:
    from scipy import stats

    return float(stats.t.ppf(0.975, dof))


def _line_fit(x: np.ndarray, y: np.ndarray):
    """OLS y = a + b x; returns a, b, sigma_b, residuals."""
    xm = x.mean()
    dx = x - xm
    sxx = float(dx @ dx)
    b = float(dx @ (y - y.mean())) / sxx
    a = float(y.mean() - b * xm)
    res = y - (a + b * x)
    dof = x.size - 2
    s2 = float(res @ res) / dof if dof > 0 else 0.0
    return a, b, math.sqrt(s2 / sxx), res


# ---- k_v and k_h from grating steps ([MWCNT]) ---------------------------------------------------
def vertical_sensitivity_from_steps(step_heights, signal_changes, *, through_origin: bool = True) -> CalibrationResult:
    """Deflection sensitivity k_v (m per signal unit) from calibration-grating steps ([MWCNT]).

    Crossing a step of height h with the feedback off deflects the lever by h; the signal jumps by
    dS. k_v is the slope of h against dS, by least squares through the origin (a zero step gives
    a zero jump):

    .. math:: k_v = \\frac{\\sum h_i\\,\\Delta S_i}{\\sum \\Delta S_i^2}, \\qquad
              \\sigma_{k_v}^2 = \\frac{\\sum (h_i - k_v \\Delta S_i)^2}{(n-1)\\sum \\Delta S_i^2}

    With ``through_origin=False`` an intercept is fitted too (n >= 3).

    Parameters
    ----------
    step_heights : (n,) float, metres
    signal_changes : (n,) float, signal units (volts)

    Returns
    -------
    CalibrationResult
        ``value`` k_v (m/V); residuals in metres.

    Examples
    --------
    >>> r = vertical_sensitivity_from_steps([20e-9, 101.8e-9, 500e-9], [0.032, 0.156, 0.710])
    >>> round(r.value * 1e9)  # [MWCNT] quotes 706 nm/V
    702
    """
    h = _vector("step_heights", step_heights, 2)
    s = _vector("signal_changes", signal_changes, 2)
    if h.shape != s.shape:
        raise ForceError(f"step_heights and signal_changes must have the same length (got {h.size} and {s.size})")
    if np.any(s == 0.0):
        raise ForceError("a signal change is zero; each step must move the signal (check the channel)")
    if through_origin:
        sss = float(s @ s)
        kv = float(s @ h) / sss
        res = h - kv * s
        dof = h.size - 1
        sigma = math.sqrt(float(res @ res) / (dof * sss)) if dof > 0 else 0.0
        intercept = 0.0
    else:
        if h.size < 3:
            raise ForceError("a fit with intercept needs at least 3 steps; use through_origin=True")
        intercept, kv, sigma, res = _line_fit(s, h)
        dof = h.size - 2
    half = _t95(dof) * sigma if dof > 0 else float("inf")
    return CalibrationResult(
        kv, sigma, res, (kv - half, kv + half), "grating_steps",
        {"intercept": intercept, "dof": dof},
    )


def lateral_sensitivity_from_vertical(vertical_sensitivity: float, length: float, *, model: str = "end_load") -> float:
    """Torsion sensitivity k_h (rad per signal unit) from the deflection sensitivity ([MWCNT]).

    The quadrant cell has one angular sensitivity in both directions, so k_h equals the bending
    angle per unit vertical signal:

    .. math:: k_h = \\frac{3}{2}\\frac{k_v}{l_c} \\;(\\text{end load}), \\qquad
              k_h = \\frac{k_v}{l_c} \\;(\\text{chord, [MWCNT] Eq. 7})

    ``"end_load"`` uses the end slope 3 delta / (2 l) of a beam deflected by a force at its tip
    (how k_v is calibrated); ``"chord"`` is [MWCNT]'s small-angle chord delta / l, which gives its
    0.00565 rad/V from 706 nm/V (l_c = 125 um) and underestimates the slope by a third.

    **Why the default is not the seed's figure.** ``model="end_load"`` gives 0.00848 rad/V for
    [MWCNT]'s 706 nm/V and 125 um, 1.5x its printed 0.00565 rad/V. The default is kept on purpose:
    the bending angle that the rest of arsurf reads from the same deflection sensitivity
    (:meth:`arsurf.force.photodiode.Photodiode.from_deflection_sensitivity`, the cantilever model)
    is the end slope of the end-loaded lever, and [MWCNT]'s own premise is that torsion and
    bending share one angular sensitivity; with the chord here and the end slope there they would
    differ by 1.5 and every decoupled lateral force would be off by that factor. To reproduce the
    seed's number, pass ``model="chord"`` (tested).

    Parameters
    ----------
    vertical_sensitivity : float, m per signal unit
    length : float, metres
    model : {"end_load", "chord"}
        Default ``"end_load"`` (see above); ``"chord"`` is [MWCNT]'s definition.

    Examples
    --------
    >>> round(lateral_sensitivity_from_vertical(706e-9, 125e-6, model="chord"), 5)
    0.00565
    """
    if not (isinstance(vertical_sensitivity, (int, float)) and math.isfinite(vertical_sensitivity)
            and vertical_sensitivity != 0.0):
        raise ForceError(f"vertical_sensitivity must be finite and non-zero (got {vertical_sensitivity!r} m/V)")
    if not (isinstance(length, (int, float)) and math.isfinite(length) and length > 0.0):
        raise ForceError(f"length must be positive (got {length!r} m)")
    if model == "end_load":
        return 1.5 * vertical_sensitivity / length
    if model == "chord":
        return vertical_sensitivity / length
    raise ForceError(f"model must be 'end_load' or 'chord' (got {model!r})")


# ---- normal sensitivity from an approach-retract curve ([Alabdulmuhsin]) --------------------------------
def _hinge_sse(z: np.ndarray, s: np.ndarray, zc: float) -> float:
    h = np.maximum(z - zc, 0.0)
    a = np.column_stack([np.ones_like(z), h])
    coef, *_ = np.linalg.lstsq(a, s, rcond=None)
    r = s - a @ coef
    return float(r @ r)


def _detect_contact(z: np.ndarray, s: np.ndarray, min_points: int):
    """Best hinge s = b0 + b1 max(0, z - zc) over breakpoints at the samples (O(n) via cumulative sums)."""
    order = np.argsort(z, kind="stable")
    zs = z[order]
    ss = s[order]
    n = zs.size
    # suffix sums over the contact set {i > j}
    def suffix(a):
        c = np.cumsum(a[::-1])[::-1]
        return np.append(c[1:], 0.0)

    m = (n - 1 - np.arange(n)).astype(np.float64)
    sz = suffix(zs)
    szz = suffix(zs * zs)
    szs = suffix(zs * ss)
    s_s = suffix(ss)
    zc = zs
    sh = sz - m * zc
    shh = szz - 2.0 * zc * sz + m * zc * zc
    shs = szs - zc * s_s
    s_all = ss.sum()
    sst = float(((ss - ss.mean()) ** 2).sum())
    var_h = shh - sh * sh / n
    cov = shs - sh * s_all / n
    valid = (m >= min_points) & (np.arange(n) + 1 >= min_points) & (var_h > 0)
    if not valid.any():
        raise ForceError(f"the curve is too short to find a contact point (need at least {2 * min_points} samples)")
    sse = np.full(n, np.inf)
    sse[valid] = sst - cov[valid] ** 2 / var_h[valid]
    j = int(np.argmin(sse))
    # refine the breakpoint between the neighbouring samples
    from scipy.optimize import minimize_scalar

    lo = zs[max(j - 1, 0)]
    hi = zs[min(j + 1, n - 1)]
    best = zs[j]
    if hi > lo:
        opt = minimize_scalar(lambda c: _hinge_sse(zs, ss, c), bounds=(lo, hi), method="bounded",
                              options={"xatol": 1e-6 * (hi - lo)})
        if opt.fun <= sse[j]:
            best = float(opt.x)
    return best, float(min(sse[j], _hinge_sse(zs, ss, best))), sst


def normal_sensitivity_from_curve(
    z, signal, *, branch: str = "approach", exclude: float = 0.05, min_points: int = 5,
) -> CalibrationResult:
    """Normal (deflection) sensitivity S_n from a force curve on a hard sample ([Alabdulmuhsin], Eq. 11).

    1. Branch: z is the piezo position, increasing towards the sample. If z turns back, the part
       up to the turning point is the approach, the rest the retract (``branch``). The approach
       is the default: the retract is distorted by adhesion.
    2. Contact point: the hinge model :math:`V = b_0 + b_1\\max(0, z - z_c)` (flat baseline, then
       a line) is fitted for every breakpoint z_c at a sample (cumulative sums, O(n)) and refined
       between the neighbouring samples; z_c minimises the squared residuals. The fit must beat a
       constant (F-test, p < 1e-3), otherwise there is no contact in the data.
    3. The contact region beyond :math:`z_c + \\mathrm{exclude}\\,(z_{max} - z_c)` is fitted by
       ordinary least squares, :math:`V = a + b z`, and

    .. math:: S_n = \\frac{dz}{dV} = \\frac{1}{b}, \\qquad \\sigma_{S_n} = \\frac{\\sigma_b}{b^2},

    with the 95 % interval :math:`1/(b \\pm t_{0.975,\\,n-2}\\,\\sigma_b)` (Student t).
    The signal is regressed on z because z (closed-loop piezo) is the precise variable.

    Parameters
    ----------
    z : (n,) float, metres
    signal : (n,) float, signal units
    branch : {"approach", "retract"}
    exclude : float in [0, 0.9]
        Fraction of the contact region next to z_c left out of the line fit.
    min_points : int
        Fewest samples on either side of the contact point.

    Returns
    -------
    CalibrationResult
        ``value`` S_n (m per signal unit, signed); residuals of the line fit (signal units);
        ``details``: contact_point (m), baseline, slope (1/m), intercept, n_fit.

    Examples
    --------
    >>> z = np.linspace(0.0, 400e-9, 400)
    >>> v = np.maximum(z - 150e-9, 0.0) / 1117e-9
    >>> r = normal_sensitivity_from_curve(z, v)
    >>> round(r.value * 1e9), round(r.details["contact_point"] * 1e9)
    (1117, 150)
    """
    zz = _vector("z", z, 2 * min_points)
    vv = _vector("signal", signal, 2 * min_points)
    if zz.shape != vv.shape:
        raise ForceError(f"z and signal must have the same length (got {zz.size} and {vv.size})")
    if not (0.0 <= exclude <= 0.9):
        raise ForceError(f"exclude must be in [0, 0.9] (got {exclude!r})")
    turn = int(np.argmax(zz))
    if branch == "approach":
        zb, vb = zz[: turn + 1], vv[: turn + 1]
    elif branch == "retract":
        zb, vb = zz[turn:], vv[turn:]
    else:
        raise ForceError(f"branch must be 'approach' or 'retract' (got {branch!r})")
    if zb.size < 2 * min_points:
        raise ForceError(
            f"the {branch} branch has {zb.size} samples (z turns at index {turn}); need at least "
            f"{2 * min_points}. z must increase towards the sample: pass -z if it decreases"
        )
    zc, sse, sst = _detect_contact(zb, vb, min_points)
    from scipy import stats

    dof = zb.size - 3
    f_stat = (sst - sse) / 2.0 / (sse / dof) if sse > 0 else math.inf
    if not f_stat > stats.f.ppf(1 - 1e-3, 2, dof):
        raise ForceError(
            "no contact found: a baseline plus a contact line does not fit the curve better than a constant; "
            "extend the approach into contact or check the signal channel"
        )
    zmax = float(zb.max())
    start = zc + exclude * (zmax - zc)
    sel = zb > start
    if int(sel.sum()) < max(min_points, 3):
        raise ForceError(
            f"only {int(sel.sum())} samples lie in the contact region beyond z = {start:.4g} m; "
            "push further into contact or lower `exclude`"
        )
    a, b, sigma_b, res = _line_fit(zb[sel], vb[sel])
    t = _t95(int(sel.sum()) - 2)
    lo_b, hi_b = b - t * sigma_b, b + t * sigma_b
    if lo_b <= 0.0 <= hi_b:
        raise ForceError("the contact slope is not distinguishable from zero (95 % interval contains 0); "
                         "the data show no deflection in contact")
    value = 1.0 / b
    ci = tuple(sorted((1.0 / lo_b, 1.0 / hi_b)))
    baseline = float(np.mean(vb[zb <= zc])) if np.any(zb <= zc) else float("nan")
    return CalibrationResult(
        value, sigma_b / b**2, res, ci, "approach_curve",
        {"contact_point": zc, "baseline": baseline, "slope": b, "intercept": a, "n_fit": int(sel.sum()),
         "branch": branch},
    )


# ---- wedge (tilted surface) calibration of G_l and mu ([Alabdulmuhsin]) ----------------------------------
def _wedge_roots(slope_up: float, slope_down: float, tilt: float):
    """Both (mu, g) solutions of g s_up = -tan(theta + phi), g s_down = -tan(theta - phi), mu = tan(phi)."""
    tt = math.tan(tilt)
    q = slope_up / slope_down
    if not math.isfinite(q) or q == -1.0:
        raise ForceError(
            f"slopes {slope_up!r} and {slope_down!r} are opposite and equal: the tilt is invisible; "
            "use a steeper calibration wedge"
        )
    u = 2.0 * tt * (1.0 - q) / ((1.0 + tt * tt) * (1.0 + q))  # u m^2 + 2 m + u = 0, roots m and 1/m
    if u > 0.0:
        raise ForceError(
            f"the slopes give a negative friction coefficient (u = {u:.4g} > 0): the up and down data or the "
            "tilt sign are swapped; 'up' means moving towards higher ground, tilt > 0"
        )
    if u < -1.0:
        raise ForceError(
            f"the slopes admit no real friction coefficient (u = {u:.4g} < -1); they are inconsistent with "
            "the wedge model for this tilt (check the tilt and that both fits are load sweeps)"
        )
    root = math.sqrt(max(0.0, 1.0 - u * u))
    mu_low = -u / (1.0 + root)
    mu_high = math.inf if mu_low == 0.0 else 1.0 / mu_low
    out = []
    for mu in (mu_low, mu_high):
        if math.isinf(mu):
            out.append((mu, math.nan, False))
            continue
        den_up = 1.0 - tt * mu
        g = -(tt + mu) / den_up / slope_up if den_up != 0.0 else math.nan
        # admissible: sliding up must press the tip (cos - mu sin > 0) and g must be finite
        out.append((mu, g, den_up > 0.0 and math.isfinite(g)))
    return out


def wedge_from_slopes(
    slope_up: float, slope_down: float, tilt: float, normal_gain: float, *, friction_branch: str | None = None,
):
    """Lateral gain G_l and friction mu from the two sliding slopes, in closed form.

    Derivation ([Alabdulmuhsin] Eq. 15-18, lab frame of :func:`arsurf.force.simulate.wedge_forces`):
    with f = mu N + A and mu = tan(phi), varying the load N at fixed mu, A, theta gives

    .. math::

        \\frac{\\partial F_l}{\\partial F_n}\\Big|_{up} = -\\tan(\\theta + \\varphi), \\qquad
        \\frac{\\partial F_l}{\\partial F_n}\\Big|_{down} = -\\tan(\\theta - \\varphi).

    The detector gives :math:`F_l = G_l V_h` and :math:`F_n = K V_v` (K = k S_n), so the measured
    ratio is :math:`\\partial F_l/\\partial F_n = (G_l/K)\\,\\partial V_h/\\partial V_v` (the thesis'
    Eq. 23-24 use the inverse, dV_v/dV_h). With g = G_l / K, s = dV_h/dV_v, q = s_up / s_down and
    T = tan(theta), eliminating g leaves a quadratic in mu whose roots are mu and 1/mu:

    .. math::

        u\\,\\mu^2 + 2\\mu + u = 0,\\quad u = \\frac{2T(1-q)}{(1+T^2)(1+q)},\\quad
        \\mu_{low} = \\frac{-u}{1 + \\sqrt{1-u^2}},\\; \\mu_{high} = 1/\\mu_{low},\\quad
        G_l = -K\\,\\frac{T + \\mu}{(1 - T\\mu)\\,s_{up}} .

    Both roots fit the two slopes exactly; a root is admissible if sliding up still presses the
    tip (1 - T mu > 0). If both are admissible the data cannot tell them apart: pass
    ``friction_branch="low"`` (mu <= 1, usual for AFM tips) or ``"high"`` (mu >= 1; [Alabdulmuhsin]'s
    mu = 1.861 is a high root, whose partner is 1/1.861 = 0.537).

    Parameters
    ----------
    slope_up, slope_down : float
        dV_h/dV_v while sliding up (towards higher ground) and down.
    tilt : float, radians in (0, pi/2): inclination of the wedge face.
    normal_gain : float, N per signal unit: K = k S_n.
    friction_branch : {None, "low", "high"}

    Returns
    -------
    lateral_gain : float, N per signal unit
    friction : float
    other : (float, float) or None
        The other root (friction, lateral_gain) if it is admissible, else None.

    Examples
    --------
    >>> import math
    >>> th, mu, gl, k = math.radians(12.0), 0.4, -63.78e-9, 335.1e-9
    >>> s_up = -math.tan(th + math.atan(mu)) * k / gl
    >>> s_dn = -math.tan(th - math.atan(mu)) * k / gl
    >>> g, m, other = wedge_from_slopes(s_up, s_dn, th, k, friction_branch="low")
    >>> round(g * 1e9, 2), round(m, 3)
    (-63.78, 0.4)
    """
    for name, value in (("slope_up", slope_up), ("slope_down", slope_down), ("normal_gain", normal_gain)):
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value != 0.0):
            raise ForceError(f"{name} must be finite and non-zero (got {value!r})")
    if not (isinstance(tilt, (int, float)) and 0.0 < tilt < math.pi / 2):
        raise ForceError(f"tilt must be in (0, pi/2) radians (got {tilt!r}); a flat sample cannot calibrate G_l")
    if friction_branch not in (None, "low", "high"):
        raise ForceError(f"friction_branch must be None, 'low' or 'high' (got {friction_branch!r})")
    roots = _wedge_roots(float(slope_up), float(slope_down), float(tilt))
    admissible = [(mu, g) for mu, g, ok in roots if ok]
    if not admissible:
        raise ForceError("neither friction root keeps the tip pressed when sliding up (1 - tan(tilt) mu <= 0); "
                         "the tilt is too steep for this friction")
    if friction_branch is None:
        if len(admissible) == 2:
            (m1, g1), (m2, g2) = admissible
            raise ForceError(
                f"the two slopes fit mu = {m1:.6g} (G_l = {g1 * normal_gain:.6g} N/V) and mu = {m2:.6g} "
                f"(G_l = {g2 * normal_gain:.6g} N/V) equally well; pass friction_branch='low' or 'high'"
            )
        mu, g = admissible[0]
        other = None
    else:
        want = roots[0] if friction_branch == "low" else roots[1]
        if not want[2]:
            raise ForceError(
                f"the {friction_branch} root mu = {want[0]:.6g} is not admissible for this tilt "
                "(sliding up would lift the tip); use the other branch"
            )
        mu, g = want[0], want[1]
        rest = roots[1] if friction_branch == "low" else roots[0]
        other = (rest[0], rest[1] * normal_gain) if rest[2] else None
    return g * normal_gain, mu, other


@dataclass(frozen=True)
class WedgeCalibration:
    """Result of :func:`wedge_calibration`: lateral gain and friction coefficient.

    Attributes
    ----------
    lateral_gain : CalibrationResult
        G_l, N per lateral signal unit; residuals are those of the up fit then the down fit.
    friction : CalibrationResult
        mu (dimensionless).
    slopes : (float, float)
        dV_h/dV_v sliding up and down.
    other : (float, float) or None
        The other admissible root (mu, G_l), when the branch was chosen explicitly.
    """

    lateral_gain: CalibrationResult
    friction: CalibrationResult
    slopes: tuple[float, float]
    other: tuple[float, float] | None


def wedge_calibration(
    vertical_up, lateral_up, vertical_down, lateral_down, tilt: float, normal_gain: float, *,
    friction_branch: str | None = None, tilt_uncertainty: float = 0.0, normal_gain_uncertainty: float = 0.0,
) -> WedgeCalibration:
    """G_l and mu from sliding data on a tilted surface ([Alabdulmuhsin] sec. 4.1.2, corrected).

    Each direction's lateral signal is fitted against its vertical signal by ordinary least
    squares, V_h = c + s V_v (s is the load-sweep slope; the intercept absorbs adhesion and the
    lateral offset), then :func:`wedge_from_slopes` solves for (G_l, mu). Uncertainties propagate
    the slope standard errors and the optional tilt / normal-gain uncertainties linearly
    (central-difference Jacobian of the closed form). Noise on V_v biases s towards zero by the
    factor var(V_v) / (var(V_v) + sigma_v^2): sweep the load over many times the vertical noise.

    Parameters
    ----------
    vertical_up, lateral_up, vertical_down, lateral_down : (n,) float, signal units
    tilt : float, radians
    normal_gain : float, N per vertical signal unit (k S_n)
    friction_branch : {None, "low", "high"}, see :func:`wedge_from_slopes`
    tilt_uncertainty : float, radians (one sigma)
    normal_gain_uncertainty : float, N per signal unit (one sigma)

    Returns
    -------
    WedgeCalibration
    """
    vu = _vector("vertical_up", vertical_up, 3)
    hu = _vector("lateral_up", lateral_up, 3)
    vd = _vector("vertical_down", vertical_down, 3)
    hd = _vector("lateral_down", lateral_down, 3)
    if vu.shape != hu.shape or vd.shape != hd.shape:
        raise ForceError("each direction needs vertical and lateral arrays of the same length")
    if np.ptp(vu) == 0.0 or np.ptp(vd) == 0.0:
        raise ForceError("the vertical signal does not vary along a sweep: the load must change while sliding")
    _, s_up, sig_up, res_up = _line_fit(vu, hu)
    _, s_dn, sig_dn, res_dn = _line_fit(vd, hd)
    gl, mu, other = wedge_from_slopes(s_up, s_dn, tilt, normal_gain, friction_branch=friction_branch)
    branch = "low" if mu <= 1.0 else "high"

    def solve(p):
        g, m, _ = wedge_from_slopes(p[0], p[1], p[2], p[3], friction_branch=branch)
        return np.array([g, m])

    p0 = np.array([s_up, s_dn, float(tilt), float(normal_gain)])
    sig = np.array([sig_up, sig_dn, float(tilt_uncertainty), float(normal_gain_uncertainty)])
    jac = np.zeros((2, 4))
    for i in range(4):
        if sig[i] == 0.0:
            continue
        h = 1e-6 * max(abs(p0[i]), sig[i])
        hi = p0.copy()
        lo = p0.copy()
        hi[i] += h
        lo[i] -= h
        jac[:, i] = (solve(hi) - solve(lo)) / (2.0 * h)
    cov = jac @ np.diag(sig**2) @ jac.T
    s_g, s_m = math.sqrt(cov[0, 0]), math.sqrt(cov[1, 1])
    res = np.concatenate([res_up, res_dn])
    details = {"slope_up": s_up, "slope_down": s_dn, "slope_up_sigma": sig_up, "slope_down_sigma": sig_dn,
               "correlation": float(cov[0, 1] / (s_g * s_m)) if s_g > 0 and s_m > 0 else 0.0}
    return WedgeCalibration(
        CalibrationResult(gl, s_g, res, (gl - _Z95 * s_g, gl + _Z95 * s_g), "wedge", details),
        CalibrationResult(mu, s_m, res, (mu - _Z95 * s_m, mu + _Z95 * s_m), "wedge", details),
        (s_up, s_dn),
        other,
    )


# ---- thermal-noise spring constant -----------------------------------------------------------------
def sho_psd(f, white, plateau, resonance, quality):
    """One-sided PSD of a thermally driven harmonic oscillator plus white detector noise (m^2/Hz).

    .. math:: P(f) = W + \\frac{P_0 f_0^4}{(f^2 - f_0^2)^2 + (f f_0 / Q)^2},
              \\qquad \\int_0^\\infty (P - W)\\,df = \\frac{\\pi}{2} P_0 f_0 Q
    """
    f = np.asarray(f, dtype=np.float64)
    return white + plateau * resonance**4 / ((f * f - resonance**2) ** 2 + (f * resonance / quality) ** 2)


def thermal_spring_constant(
    deflection, sample_rate: float, *, temperature: float = 298.15, correction: float = OPTICAL_LEVER_FIRST_MODE,
    band: tuple[float, float] | None = None, segment_length: int | None = None,
) -> CalibrationResult:
    """Spring constant from the thermal noise of the free cantilever (Hutter & Bechhoefer 1993).

    The one-sided PSD of the deflection (Welch, Hann window, non-overlapping segments) is fitted
    with :func:`sho_psd` around the first resonance (log-space least squares for a start, then
    weighted least squares with sigma = P_model / sqrt(K) for K averaged segments). The
    first-mode mean square and the spring constant are

    .. math:: \\langle z_1^2\\rangle = \\frac{\\pi}{2} P_0 f_0 Q, \\qquad
              k = \\chi\\,\\frac{k_B T}{\\langle z_1^2\\rangle},

    with chi = ``correction``: 0.817 for optical-lever detection of a rectangular lever, first mode
    (Butt & Jaschke 1995, Nanotechnology 6, 1); 0.971 for the true end deflection; 1 for the
    point-mass oscillator of Hutter & Bechhoefer.

    Parameters
    ----------
    deflection : (n,) float, metres
        Free-lever deflection trace (signal times the deflection sensitivity), n >= 4096.
    sample_rate : float, Hz
    temperature : float, kelvin
    correction : float in (0, 1]
    band : (float, float), Hz, optional
        Fit band; default [f_peak / 4, min(3 f_peak, 0.95 f_Nyquist)].
    segment_length : int, optional
        Welch segment length (default: about n / 64, a power of two in [256, 65536]).

    Returns
    -------
    CalibrationResult
        ``value`` k (N/m); residuals are (P - model) / model in the band; ``details``: resonance
        (Hz), quality, plateau (m^2/Hz), white (m^2/Hz), mean_square (m^2), segments.
    """
    z = _vector("deflection", deflection, 4096)
    for name, value in (("sample_rate", sample_rate), ("temperature", temperature)):
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0.0):
            raise ForceError(f"{name} must be positive (got {value!r})")
    if not (isinstance(correction, (int, float)) and 0.0 < correction <= 1.0):
        raise ForceError(f"correction must be in (0, 1] (got {correction!r}); 0.817 for an optical lever")
    from scipy import optimize, signal

    n = z.size
    if segment_length is None:
        seg = int(2 ** round(math.log2(max(n / 64.0, 256.0))))
        seg = min(max(seg, 256), 65536, n)
    else:
        seg = int(segment_length)
        if not 64 <= seg <= n:
            raise ForceError(f"segment_length must be in [64, {n}] (got {segment_length!r})")
    f, p = signal.welch(z - z.mean(), fs=sample_rate, window="hann", nperseg=seg, noverlap=0,
                        detrend="constant", scaling="density")
    k_seg = n // seg
    nyq = sample_rate / 2.0
    keep = f > 2.0 * f[1]
    if band is None:
        fp = float(f[keep][np.argmax(p[keep])])
        lo, hi = fp / 4.0, min(3.0 * fp, 0.95 * nyq)
    else:
        lo, hi = float(band[0]), float(band[1])
        if not (0.0 <= lo < hi <= nyq):
            raise ForceError(f"band must satisfy 0 <= low < high <= Nyquist = {nyq:g} Hz (got {band!r})")
    sel = (f >= lo) & (f <= hi) & keep
    if int(sel.sum()) < 8:
        raise ForceError(f"only {int(sel.sum())} PSD bins in the fit band; record longer or widen the band")
    fb, pb = f[sel], p[sel]
    # starting values: peak, half-power width, low-frequency plateau, floor
    ipk = int(np.argmax(pb))
    f0 = float(fb[ipk])
    above = pb >= pb[ipk] / 2.0
    width = max(float(fb[above].max() - fb[above].min()), f[1])
    q0 = max(f0 / width, 0.6)
    white0 = float(np.min(pb))
    plateau0 = max(float(pb[ipk]) / q0**2, 1e-300)

    def log_resid(x):
        w, p0, fr, qq = np.exp(x)
        return np.log(sho_psd(fb, w, p0, fr, qq)) - np.log(pb)

    x0 = np.log([max(white0 * 0.5, 1e-300), plateau0, f0, q0])
    sol = optimize.least_squares(log_resid, x0, method="lm", max_nfev=2000)
    params = np.exp(sol.x)
    # weighted least squares with the chi-square variance of the averaged periodogram, in scaled
    # variables (the parameters span ~60 orders of magnitude in SI); white >= 0
    scale = np.array([max(params[0], 1e-9 * params[1]), params[1], params[2], params[3]])
    sqk = math.sqrt(k_seg)
    for _ in range(2):
        sigma = sho_psd(fb, *params) / sqk

        def wresid(x, sigma=sigma):
            return (sho_psd(fb, *(x * scale)) - pb) / sigma

        x0 = params / scale
        sol = optimize.least_squares(wresid, x0, bounds=([0.0, 0.0, 0.0, 0.0], np.inf), method="trf",
                                     x_scale="jac", max_nfev=2000)
        params = sol.x * scale
    jac = sol.jac
    cov = np.linalg.pinv(jac.T @ jac) * np.outer(scale, scale)
    white, plateau, f0, qual = (float(x) for x in params)
    if not (sol.success and plateau > 0 and f0 > 0 and qual > 0):
        raise ForceError("the harmonic-oscillator fit failed (non-positive parameters); check the band and the trace")
    # Hann-windowed bins are correlated over ~1.5 bins (equivalent noise bandwidth): inflate the covariance
    cov = cov * 1.5
    ms = 0.5 * math.pi * plateau * f0 * qual
    grad = np.array([0.0, ms / plateau, ms / f0, ms / qual])
    var_ms = float(grad @ cov @ grad)
    k = correction * BOLTZMANN * temperature / ms
    s_k = k * math.sqrt(max(var_ms, 0.0)) / ms
    model = sho_psd(fb, *params)
    return CalibrationResult(
        k, s_k, (pb - model) / model, (k - _Z95 * s_k, k + _Z95 * s_k), "thermal_noise",
        {"resonance": f0, "quality": qual, "plateau": plateau, "white": white, "mean_square": ms,
         "segments": k_seg, "band": (lo, hi), "correction": correction, "temperature": temperature},
    )
