r"""Material maps: a reduced modulus E* and a work of adhesion w that vary across the sample.

A :class:`MaterialMap` holds per-location contact parameters built from a scan's mechanical
channels (PeakForce QNM ``DMTModulus`` and ``Adhesion``, or any modulus / pull-off pair) with
the conversions of :mod:`arsurf.contact.material_conversion`, plus - where measured - the
``Deformation`` and ``Dissipation`` maps for the viewer. The model tick looks E* and w up at
the contact point and solves Maugis-Dugdale with them (:func:`local_contact_kernel`).

How a map is built (:func:`build_material_map`), per channel
    1. **SI units** (:func:`~arsurf.contact.material_conversion.channel_to_si`): an uncalibrated
       channel needs its stated conversion, never a guess.
    2. **Mask** the pixels the instrument's fit failed on: not finite, exactly zero, saturated
       (at the channel's full scale, from the file's Z scale: NanoScope writes the clipped fits
       there), a modulus <= 0, the pixels where the linear and the log modulus channels disagree
       (:func:`channel_disagreement`; the conversion's ``cross_check``), and outliers (beyond
       ``outlier_mads`` robust scales of the median, in log E for the modulus, linearly for the
       pull-off; the scale is 1.4826 MAD but never below :data:`OUTLIER_SCALE_FLOOR` or the
       channel's quantum, so a uniform map still masks an absurd pixel). The masked fraction of
       each reason is reported (``masked``). The sample Poisson ratio is resolved here (stated,
       else the file's header, else 0.3; ``processing["sample_poisson_source"]``).
    3. **Fill** the masked pixels by Laplace inpainting (:func:`arsurf.inpaint`), in log E for
       the modulus; optional Gaussian **smoothing** (``sigma``, :func:`arsurf.smooth`), like the
       height. Pull-offs below the adhesion floor are then raised to it (counted): by default the
       rms of the field's negative values, its own noise (a pull-off cannot be compressive).
    4. **Convert**: :math:`E^*` from the sample modulus, *w* from the pull-off at the local
       :math:`E^*` (the conversion's regime).
    5. **Fit** a bicubic B-spline (:func:`arsurf.fit_surface`, the height's fit) to
       :math:`\ln(E^*/E^*_{ref})` and :math:`\ln(w/w_{ref})`, the references being the medians:
       the values between pixels are continuous, always positive, and a uniform map is the
       zero spline exactly. The kernel clamps the spline to the range of the pixel values, so
       the cubic's overshoot at a sharp step never leaves the measured range; between the pixels
       next to a step the interpolating cubic still ripples by a few per cent of the step (as the
       height's fit does): ``sigma`` (or ``smoothing``) removes it.

Registration to the height image
    The map's pixel (ix, iy) sits at (x0 + ix dx, y0 + iy dy) in the height image's frame
    (``offset`` = (x0, y0), 0 for channels of the same file). The same grid is used as it is;
    a channel of another size or pixel pitch is accepted when it covers the height image
    (within half a pixel) and is resampled by its own spline; anything else is refused with
    both extents in the message (:class:`~arsurf.errors.MaterialMapError`).

In the tick (:func:`local_contact_kernel`)
    Two 4x4 spline contractions at the contact point, then the contact law's kernel arguments
    scaled from the reference law (R fixed, the Dugdale range :math:`h_0 = w/\sigma_0` fixed):
    with :math:`r_E = E^*/E^*_{ref}`, :math:`r_w = w/w_{ref}`, the radius scale goes as
    :math:`(r_w/r_E)^{1/3}`, the depth scale and :math:`\lambda` as :math:`(r_w/r_E)^{2/3}`, the load
    scale as :math:`r_w`. The fold of the depth curve (:math:`\lambda > \lambda_t`) and the depth at
    zero load come from a table of their exact values over the map's range of :math:`\lambda`
    (built with the model, 64 rows per unit of :math:`\ln\lambda`).
    Where both ratios are exactly 1 (a uniform map, or the reference point) the reference law's
    own arguments are used: a uniform map reproduces the constant model bit for bit.

With the energy of the whole tip (:mod:`arsurf.contact.zone_energy`)
    Each lattice sample reads the two ratios where it lies (:func:`local_ratios_kernel`) once,
    when its tile is sampled, and sums the reference law's repulsion scaled by :math:`r_E` and
    its adhesion by :math:`r_w`; the tick's friction takes the local :math:`2\pi R w` at the
    closest point.

Examples
--------
>>> import numpy as np
>>> from arsurf.scan.scan import Scan
>>> from arsurf.contact.material_conversion import MaterialConversion
>>> h = Scan(np.zeros((16, 16)), dx=2e-9, dy=2e-9)
>>> E = Scan(np.where(np.arange(16) < 8, 1e9, 4e9) * np.ones((16, 1)), 2e-9, 2e-9, "DMTModulus",
...          {"z_unit": "Pa"})
>>> F = Scan(np.full((16, 16), 2e-9), 2e-9, 2e-9, "Adhesion", {"z_unit": "N"})
>>> m = build_material_map(h, {"modulus": E, "adhesion": F}, MaterialConversion(10e-9, regime="dmt"))
>>> [round(float(m.reduced_modulus(x, 15e-9)) / 1e9, 3) for x in (2e-9, 28e-9)]   # GPa: E_s / (1 - 0.3^2)
[1.099, 4.396]
"""
from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Mapping

import numpy as np
from numba import njit

from arsurf.contact.material_conversion import (LEGACY, MaterialConversion, channel_to_si, reduced_modulus,
                                                work_of_adhesion_from_pull_off)
from arsurf._layout import Layout
from arsurf.contact.maugis_dugdale import (A_DELTA_FOLD, A_DEPTH_SCALE, A_LAMBDA, A_LOAD_SCALE, A_RADIUS_SCALE,
                                           A_T_FOLD, LAMBDA_TRANSITION, MD_ARGS, md_critical_point_kernel,
                                           md_zero_radius_limit)
from arsurf.errors import MaterialMapError
from arsurf.scan.scan import Scan
from arsurf.spline.basis import basis_at

__all__ = [
    "CHANNEL_NAMES",
    "MapField",
    "MaterialMap",
    "build_material_map",
    "critical_point_table",
    "field_values",
    "contact_vector",
    "local_contact_kernel",
    "local_law_kernel",
    "local_ratios_kernel",
    "material_map_from_file",
    "mechanical_channels",
]

#: default channel of each quantity (the PeakForce QNM names; case-insensitive, direction optional)
CHANNEL_NAMES = MappingProxyType({"modulus": "DMTModulus", "log_modulus": "LogDMTModulus", "adhesion": "Adhesion",
                                  "deformation": "Deformation", "dissipation": "Dissipation"})
#: the cross-check's tolerance: the linear and the log modulus channels agree where they differ by
#: at most one LSB of the linear channel plus this fraction of the value (measured on sample_0.spm:
#: 0.5 %...3 % and 1...2 LSB flag the same pixels to 0.005 % of the image)
CROSS_CHECK_RELATIVE = 0.01
#: the robust scale of the outlier test never drops below this: one e-fold of E for the modulus (in
#: ln E), the median magnitude for the pull-off. A map whose MAD vanishes (more than half its pixels
#: equal) still masks a pixel e^6 = 403x (6 scales) away from the median, and a second phase nearer
#: than that is never called an outlier; real maps are wider (sample_0.spm: 1.38 in ln E, 1.3
#: median magnitudes of the pull-off), so there the MAD rules as before
OUTLIER_SCALE_FLOOR = 1.0
#: words that mark a channel as mechanical (``arsurf info --material``)
_MECHANICAL = ("modulus", "adhesion", "deformation", "dissipation", "stiffness", "pull", "elastic", "young")
#: the fields a map holds, their unit and whether the spline is fitted to the log of the value
_FIELDS = {"reduced_modulus": "Pa", "work_of_adhesion": "J/m^2"}
#: upper bound of the zero-load depth / depth scale over all lambda (1.1006 JKR ... 1.5859 DMT):
#: the coupled-depth solver's bracket where the table does not reach (tested over [1e-6, 1e6])
ZERO_LOAD_BOUND = 1.6
#: lower bound of the fold depth / depth scale for lambda > lambda_t (-0.9957 at lambda_t ... -0.9086 JKR)
FOLD_LOWER_BOUND = -1.0
#: the critical-point table of a map: rows per unit of ln(lambda) over the map's lambda range
TABLE_PER_UNIT = 64
#: linear interpolation in the table errs by < 1e-5 in the zero-load depth (tested): this margin
#: keeps the interpolated value an upper bound, as the coupled-depth solver's bracket needs
ZERO_LOAD_MARGIN = 1e-4
#: a fold beyond this ln s (A < 1e-6 at lambda just above lambda_t) is not interpolated: found on
#: demand instead (md_solve_depth with t_fold = NaN)
T_FOLD_TABLE_MAX = 9.0

#: the head of the contact vector (one float64 array, so that the compiled tick's callers pass one
#: argument): the reference law's kernel arguments, the local law's (scratch), then scalars - the
#: map's on flag, origin (m), log-ratio offsets and clamps of the two fields, the critical-point
#: table's first ln lambda and step, the spline's and the table's sizes - and the offsets of the
#: sections that follow the head (scratch for the model's friction vector, the dent the tick records,
#: the knots, the critical-point table, the two fields' spline coefficients)
CONTACT_HEAD = Layout("contact vector head", [
    ("reference", MD_ARGS.size), ("local", MD_ARGS.size), ("on", 1), ("x0", 1), ("y0", 1), ("offset_e", 1),
    ("offset_w", 1), ("lo_e", 1), ("hi_e", 1), ("lo_w", 1), ("hi_w", 1), ("ln_lambda0", 1), ("table_step", 1),
    ("nu", 1), ("nv", 1), ("ntable", 1), ("friction", 1), ("dent", 1), ("ku", 1), ("kv", 1), ("table", 1),
    ("coef", 1)])
# the offsets as the kernels use them
C_REF, C_LOCAL, C_HEAD = CONTACT_HEAD.offset("reference"), CONTACT_HEAD.offset("local"), CONTACT_HEAD.offset("on")
(H_ON, H_X0, H_Y0, H_OFF_E, H_OFF_W, H_LO_E, H_HI_E, H_LO_W, H_HI_W, H_LNLAM0, H_TABLE_STEP, H_NU, H_NV, H_NTABLE,
 H_FRICTION, H_DENT, H_KU, H_KV, H_TABLE, H_COEF) = (CONTACT_HEAD.offset(f) for f in CONTACT_HEAD.fields[2:])
C_BODY = CONTACT_HEAD.size
_MD_SIZE = MD_ARGS.size
#: a row of the critical-point table: ln s and depth of the fold (inf and Delta0 without one),
#: depth at zero load, pull-off load under load control (all in the law's own units)
TABLE_ROW = Layout("critical-point table row", [("t_fold", 1), ("delta_fold", 1), ("zero_load_depth", 1),
                                                ("pull_off", 1)])
T_TFOLD, T_DFOLD = TABLE_ROW.offset("t_fold"), TABLE_ROW.offset("delta_fold")
T_DZERO, T_PULL = TABLE_ROW.offset("zero_load_depth"), TABLE_ROW.offset("pull_off")
T_COLS = TABLE_ROW.size


@njit(cache=True)
def _field_pair(cv, x, y):
    """The two spline fields of the contact vector ``cv`` at (x, y) (map frame, clamped to the domain)."""
    nu = int(cv[H_NU])
    nv = int(cv[H_NV])
    k0 = int(cv[H_KU])
    k1 = int(cv[H_KV])
    i0, bu = basis_at(cv[k0:k0 + nu + 4], x)
    j0, bv = basis_at(cv[k1:k1 + nv + 4], y)
    base = int(cv[H_COEF])
    e = 0.0
    w = 0.0
    for a in range(4):
        row = base + 2 * (i0 + a) * nv
        for b in range(4):
            wt = bu[a] * bv[b]
            at = row + 2 * (j0 + b)
            e += wt * cv[at]
            w += wt * cv[at + 1]
    return e, w


@njit(cache=True)
def field_values(coef, ku, kv, xs, ys, lo, hi, out):
    """Scalar spline ``coef`` (nu, nv) at the points (xs, ys) (map frame, m), clamped to [lo, hi]."""
    for k in range(xs.size):
        i0, bu = basis_at(ku, xs[k])
        j0, bv = basis_at(kv, ys[k])
        s = 0.0
        for a in range(4):
            for b in range(4):
                s += bu[a] * bv[b] * coef[i0 + a, j0 + b]
        out[k] = min(max(s, lo), hi)


@njit(cache=True)
def _table_rows(cv, lam):
    """(offset of the row below lambda, of the row above, fraction between) in the contact vector's
    critical-point table."""
    n = int(cv[H_NTABLE])
    pos = (math.log(lam) - cv[H_LNLAM0]) / cv[H_TABLE_STEP]
    k = min(max(int(pos), 0), n - 2)
    r0 = int(cv[H_TABLE]) + T_COLS * k
    return r0, r0 + T_COLS, min(max(pos - k, 0.0), 1.0)


@njit(cache=True)
def local_pull_off_kernel(cv, md):
    """Magnitude (N) of the pull-off force :math:`|P_c|` (load control) of a local law ``md``
    (:func:`local_contact_kernel`'s answer where ``here``): the critical-point table's
    :math:`\bar P_c`, interpolated linearly in ln lambda, times the law's load scale pi w R."""
    r0, r1, f = _table_rows(cv, md[A_LAMBDA])
    return abs(cv[r0 + T_PULL] + f * (cv[r1 + T_PULL] - cv[r0 + T_PULL])) * md[A_LOAD_SCALE]


@njit(cache=True)
def deepest_well_kernel(cv, x0, y0, hx, hy, nx, ny, coupling_stiffness, dugdale_range):
    r"""Largest adhesive energy bound :math:`E_0` (J) of the local laws at the grid points
    (x0 + i hx, y0 + j hy), i < nx, j < ny (m, the height's frame); 0 where the law is the
    reference's (``here`` False: that law's own bound is the caller's).

    Per point, as :meth:`arsurf.model.ARModel.adhesion_energy` for one law:
    :math:`E_0 = |P_c|\,(\delta_0 - \min(\delta_{out}, -h_0) + |P_c|/k_c)`, from the tick's own
    local law (:func:`local_contact_kernel`: the zero-load depth with its upper margin, the fold
    or its lower bound) and the larger :math:`|\bar P_c|` of the two table rows around
    :math:`\lambda` (:math:`\bar P_c` is monotone in :math:`\lambda`): an upper bound of the exact law's."""
    best = 0.0
    for j in range(ny):
        for i in range(nx):
            md, ratio, jump, zero, here = local_contact_kernel(cv, x0 + i * hx, y0 + j * hy)
            if not here:
                continue
            r0, r1, f = _table_rows(cv, md[A_LAMBDA])
            pc = max(abs(cv[r0 + T_PULL]), abs(cv[r1 + T_PULL])) * md[A_LOAD_SCALE]
            e0 = pc * (zero - min(jump, -dugdale_range) + pc / coupling_stiffness)
            if e0 > best:
                best = e0
    return best


@njit(cache=True)
def local_contact_kernel(cv, u, v):
    """The Maugis-Dugdale kernel arguments at the contact point (u, v) (m, the height's frame).

    ``cv`` the contact vector of :func:`contact_vector`. Returns ``(md, stiffness_ratio,
    jump_out_depth, zero_load_depth, here)``: ``md`` (6,) is the reference law's arguments
    (``here`` False) without a map or where both ratios are 1, else the local law's; the ratio
    :math:`E^*/E^*_{ref}`; the two depths (m) bound the coupled-depth solver's bracket.

    The fold (:math:`\\lambda > \\lambda_t`) and the zero-load depth are interpolated linearly in
    the map's critical-point table (exact values every 1/64 of ln lambda: the fold's depth to
    1e-5; its ln s, the branch's end, errs by up to ~0.2 next to lambda_t, where the depth is flat:
    the depth there is the fold's to 1e-6); just above :math:`\\lambda_t`, where the fold runs off
    to a = 0, the fold is left to :func:`~arsurf.contact.maugis_dugdale.md_solve_depth` (found when
    a depth needs it) and the jump-out depth is bounded by ``FOLD_LOWER_BOUND``.
    """
    at, ratio, jump, zero, here = local_law_kernel(cv, u, v)
    return cv[at:at + _MD_SIZE], ratio, jump, zero, here


@njit(cache=True, _nrt=False)
def local_ratios_kernel(cv, x, y):
    """``(ln(E*/E*_ref), ln(w/w_ref))`` at (x, y) (m, the height's frame) against the reference
    law of the contact vector ``cv`` (:func:`contact_vector`): the map's two fields clamped to the
    range of their pixels; ``(0, 0)`` without a map."""
    if cv[H_ON] == 0.0:
        return 0.0, 0.0
    le, lw = _field_pair(cv, x - cv[H_X0], y - cv[H_Y0])
    return min(max(le, cv[H_LO_E]), cv[H_HI_E]) + cv[H_OFF_E], min(max(lw, cv[H_LO_W]), cv[H_HI_W]) + cv[H_OFF_W]


@njit(cache=True, _nrt=False)
def local_law_kernel(cv, u, v):
    """:func:`local_contact_kernel` with the law's offset in ``cv`` in place of the law itself
    (:data:`C_REF` or :data:`C_LOCAL`): no array returned, so a caller compiled without reference
    counts (the tick, docs/kernels.rst) can call it."""
    ref = cv[C_REF:C_REF + _MD_SIZE]
    le, lw = local_ratios_kernel(cv, u, v)
    if le == 0.0 and lw == 0.0:
        return C_REF, 1.0, 0.0, 0.0, False
    local = cv[C_LOCAL:C_LOCAL + _MD_SIZE]
    c1 = math.exp((lw - le) / 3.0)   # (r_w / r_E)^(1/3)
    c2 = c1 * c1
    local[A_DEPTH_SCALE] = ref[A_DEPTH_SCALE] * c2
    local[A_RADIUS_SCALE] = ref[A_RADIUS_SCALE] * c1
    local[A_LOAD_SCALE] = ref[A_LOAD_SCALE] * math.exp(lw)  # pi w R
    lam = ref[A_LAMBDA] * c2  # 2 (w/h0) (R / pi w K^2)^(1/3) ~ (w / E*)^(2/3)
    local[A_LAMBDA] = lam
    r0, r1, f = _table_rows(cv, lam)
    zero = cv[r0 + T_DZERO] + f * (cv[r1 + T_DZERO] - cv[r0 + T_DZERO]) + ZERO_LOAD_MARGIN
    if lam <= LAMBDA_TRANSITION:
        c0, d0, p0 = md_zero_radius_limit(lam)
        local[A_T_FOLD] = math.inf
        local[A_DELTA_FOLD] = d0
        cs = 8.0 * lam / (3.0 * math.pi)
        jump = -2.0 / (lam * math.pi) - 0.5 * cs * cs if cs < c0 else d0
    elif cv[r0 + T_TFOLD] <= T_FOLD_TABLE_MAX and cv[r1 + T_TFOLD] <= T_FOLD_TABLE_MAX:
        local[A_T_FOLD] = cv[r0 + T_TFOLD] + f * (cv[r1 + T_TFOLD] - cv[r0 + T_TFOLD])
        jump = cv[r0 + T_DFOLD] + f * (cv[r1 + T_DFOLD] - cv[r0 + T_DFOLD])
        local[A_DELTA_FOLD] = jump
    else:
        c0, d0, p0 = md_zero_radius_limit(lam)
        local[A_T_FOLD] = math.nan  # the fold, found by md_solve_depth if a depth below Delta0 needs it
        local[A_DELTA_FOLD] = d0
        jump = FOLD_LOWER_BOUND
    return C_LOCAL, math.exp(le), jump * local[A_DEPTH_SCALE], zero * local[A_DEPTH_SCALE], True


def critical_point_table(lam_lo: float, lam_hi: float) -> tuple[np.ndarray, float, float]:
    """``(table, ln lambda of row 0, row step)``: fold (ln s, depth), zero-load depth and pull-off at
    :data:`TABLE_PER_UNIT` rows per unit of ln lambda over [lam_lo, lam_hi] (one row of margin
    each side), exact (:func:`~arsurf.contact.maugis_dugdale.md_critical_point_kernel`,
    :func:`~arsurf.contact.maugis_dugdale.md_solve_load`)."""
    from arsurf.contact.maugis_dugdale import md_solve_load

    h = 1.0 / TABLE_PER_UNIT
    x0 = math.log(lam_lo) - h
    n = max(int(math.ceil((math.log(lam_hi) + h - x0) / h)) + 1, 2)
    table = np.empty((n, T_COLS))
    for i in range(n):
        lam = math.exp(x0 + i * h)
        table[i, T_TFOLD], table[i, T_DFOLD] = md_critical_point_kernel(lam, 0)
        tp, pp = md_critical_point_kernel(lam, 1)
        table[i, T_DZERO] = md_solve_load(0.0, lam, tp, pp)[2]
        table[i, T_PULL] = pp
    return table, x0, h


@dataclass(frozen=True, eq=False)
class MapField:
    """One quantity of a map as a bicubic spline on the map's grid.

    ``value = reference * exp(spline)`` when ``log`` (E*, w: always positive), else ``spline``;
    the spline is clamped to [``lo``, ``hi``], the range of its pixel values. ``pixels`` (ny, nx)
    are the values after masking, filling and smoothing; ``unit`` their unit (SI, or the
    channel's own for a viewer map without a stated scale).
    """

    name: str
    unit: str
    channel: str
    log: bool
    reference: float
    coef: np.ndarray
    knots_u: np.ndarray
    knots_v: np.ndarray
    lo: float
    hi: float
    pixels: np.ndarray

    def evaluate(self, x, y) -> np.ndarray:
        """Values at map-frame points (m), any broadcastable shapes; clamped to the data range."""
        xs, ys = np.broadcast_arrays(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))
        out = np.empty(xs.size)
        field_values(self.coef, self.knots_u, self.knots_v, np.ascontiguousarray(xs.ravel()),
                     np.ascontiguousarray(ys.ravel()), self.lo, self.hi, out)
        out = self.reference * np.exp(out) if self.log else out
        return out.reshape(xs.shape) if xs.ndim else float(out[0])


@dataclass(frozen=True, eq=False)
class MaterialMap:
    """Per-location contact parameters of a sample (see the module docstring).

    Attributes
    ----------
    fields : mapping
        ``"reduced_modulus"`` (Pa) and ``"work_of_adhesion"`` (J/m^2), and ``"deformation"``,
        ``"dissipation"`` when measured (:class:`MapField`).
    offset : (float, float), m
        Position of the map's first pixel in the height image's frame.
    spacing : (float, float), m
    conversion : MaterialConversion
    channels : mapping
        Quantity -> the channel it was read from.
    masked : mapping
        Quantity -> fractions of pixels masked per reason and in total, and ``floored`` (adhesion).
    statistics : mapping
        ``reduced_modulus`` and ``work_of_adhesion``: median, p5, p95 over the unmasked pixels
        (the channel values through the conversion, before filling and smoothing).
    registration : str
        ``"same grid"`` or how the channel grid was resampled.
    processing : mapping
        ``sigma`` (m), ``smoothing``, ``control_shape``.
    sha256 : str
        Hash of the conversion, the channels, the offset and every field's spline.
    """

    fields: Mapping[str, MapField]
    offset: tuple[float, float]
    spacing: tuple[float, float]
    conversion: MaterialConversion
    channels: Mapping[str, str]
    masked: Mapping[str, Mapping[str, float]]
    statistics: Mapping[str, Mapping[str, float]]
    registration: str
    processing: Mapping[str, object]
    source: str = ""
    sha256: str = field(default="", init=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "sha256", _digest(self))

    # -- lookups ----------------------------------------------------------------------------
    def values(self, name: str, x, y):
        """The field ``name`` at (x, y) in the height image's frame (m)."""
        if name not in self.fields:
            raise MaterialMapError(f"this map has no {name!r} field; it has {sorted(self.fields)}")
        return self.fields[name].evaluate(np.asarray(x, float) - self.offset[0], np.asarray(y, float) - self.offset[1])

    def reduced_modulus(self, x, y):
        """:math:`E^*` (Pa) at (x, y) (m, the height image's frame), as the tick sees it."""
        return self.values("reduced_modulus", x, y)

    def work_of_adhesion(self, x, y):
        """*w* (J/m^2) at (x, y) (m), as the tick sees it."""
        return self.values("work_of_adhesion", x, y)

    @property
    def reference_modulus(self) -> float:
        """:math:`E^*_{ref}` (Pa): the median of the map's pixels."""
        return self.fields["reduced_modulus"].reference

    @property
    def reference_work(self) -> float:
        """:math:`w_{ref}` (J/m^2): the median of the map's pixels."""
        return self.fields["work_of_adhesion"].reference

    def contact_law(self):
        """The Maugis-Dugdale law at the reference values (the model's ``contact`` with this map):
        tip radius and Dugdale range of the conversion."""
        from arsurf.contact.maugis_dugdale import MaugisDugdale

        c = self.conversion
        return MaugisDugdale(c.tip_radius, self.reference_modulus, self.reference_work,
                             self.reference_work / c.dugdale_range)

    def to_metadata(self) -> dict:
        """What a session records to rebuild the map: channel names (and units given for a file
        that does not state them), the conversion, the offset, the processing and the hash."""
        p = self.processing
        conv = self.conversion.to_metadata()
        if p.get("sample_poisson_source", "stated") != "stated":
            conv["sample_poisson"] = None  # from the file (or its default): a rebuild reads it there again
        return {"channels": dict(self.channels), "units": dict(p.get("units") or {}),
                "conversion": conv, "offset": list(self.offset),
                "processing": {"sigma": p["sigma"], "smoothing": p["smoothing"], "control_shape": p["control_shape"]},
                "sha256": self.sha256}

    @property
    def convention(self) -> str:
        """What E* means: the fit's own (the probe that measured the map) or another tip's."""
        c = self.conversion
        if c.probe == "same":
            return "rigid-tip DMT fit, same probe: E* = E_s/(1 - nu_s^2)"
        return (f"rigid-tip DMT fit, other probe: 1/E* = (1 - nu_s^2)/E_s + (1 - nu_t^2)/E_t "
                f"(E_t {c.tip_modulus / 1e9:.4g} GPa, nu_t {c.tip_poisson:.3g})")

    def describe(self) -> list[str]:
        """What the map means, one short line each (``arsurf info --material``, the view's legend):
        the convention, the sample Poisson ratio and its source, the channel cross-check, the
        masked fractions by reason."""
        p = self.processing
        cross = p.get("cross_check") or {}
        if cross.get("channel") is None:
            check = ("channel cross-check off" if cross.get("policy") == "off"
                     else "channel cross-check: no log channel to compare")
        else:
            what = {"mask": "masked", "log": "log channel used"}[cross["policy"]]
            check = (f"{self.channels['modulus']} vs {cross['channel']}: {cross['disagreeing_fraction']:.2%} "
                     f"disagree ({what})")
        lines = [self.convention,
                 f"nu_s {self.conversion.sample_poisson:g} ({p.get('sample_poisson_source', 'stated')})", check]
        for role in ("modulus", "adhesion"):
            m = self.masked.get(role, {})
            parts = ", ".join(f"{k.replace('_', ' ')} {v:.2%}" for k, v in m.items()
                              if k not in ("masked", "floored", "floor_N") and v > 0.0)
            lines.append(f"{role} masked {m.get('masked', 0.0):.2%}" + (f" ({parts})" if parts else ""))
        return lines

    def summary(self) -> dict:
        """Statistics, masked fractions, the convention and the conversion, JSON-ready: every key
        that holds a dimensional value names its SI unit."""
        units = {"reduced_modulus": "Pa", "sample_modulus": "Pa", "work_of_adhesion": "J_per_m2",
                 "pull_off_force": "N"}
        stats = {k: {(f"{q}_{units[k]}" if q != "pixels" else "n_pixels"): v for q, v in st.items()}
                 for k, st in self.statistics.items()}
        masked = {role: {(k if k.endswith("_N") else f"{k}_fraction"): v for k, v in m.items()}
                  for role, m in self.masked.items()}
        p = self.processing
        cross = dict(p.get("cross_check") or {})
        return {"channels": dict(self.channels), "convention": self.convention,
                "sample_poisson": self.conversion.sample_poisson,
                "sample_poisson_source": p.get("sample_poisson_source", "stated"), "cross_check": cross,
                "statistics": stats, "masked": masked,
                "registration": self.registration,
                "reference": {"reduced_modulus_Pa": self.reference_modulus,
                              "work_of_adhesion_J_per_m2": self.reference_work},
                "conversion": self.conversion.summary(), "sha256": self.sha256}

    def __repr__(self) -> str:
        s = self.statistics
        return (f"MaterialMap({self.fields['reduced_modulus'].pixels.shape[1]}x"
                f"{self.fields['reduced_modulus'].pixels.shape[0]} px, E* median "
                f"{s['reduced_modulus']['median'] / 1e9:.4g} GPa, w median "
                f"{s['work_of_adhesion']['median'] * 1e3:.4g} mJ/m^2, source={self.source!r})")


def _digest(m: MaterialMap) -> str:
    h = hashlib.sha256()
    conv = m.conversion.to_metadata()
    for key, old in LEGACY.items():  # a map converted as before these parameters existed keeps its hash
        if conv[key] == old:
            del conv[key]
    head = {"conversion": conv, "channels": dict(m.channels), "offset": list(m.offset), "spacing": list(m.spacing)}
    h.update(json.dumps(head, sort_keys=True).encode())
    for name in sorted(m.fields):
        f = m.fields[name]
        h.update(json.dumps([name, f.unit, f.log, f.reference, f.lo, f.hi]).encode())
        for a in (f.coef, f.knots_u, f.knots_v):
            h.update(np.ascontiguousarray(a, dtype="<f8").tobytes())
    return h.hexdigest()


# ---------------------------------------------------------------------------------------------
# building


def mechanical_channels(scan: Scan) -> dict[str, str]:
    """Channel -> unit of the mechanical channels a file lists (from a Scan's ``channel_units``)."""
    units = scan.metadata.get("channel_units") or {}
    return {name: unit for name, unit in units.items() if any(w in name.lower() for w in _MECHANICAL)}


def _saturation(scan: Scan) -> float | None:
    """The channel's full scale in its own unit when the file states it (NanoScope), else None."""
    per = scan.metadata.get("z_per_lsb")
    width = scan.metadata.get("stored_bytes_per_pixel")
    if per is None or width is None or scan.metadata.get("log10_decoded"):
        return None
    return abs(float(per)) * (2.0 ** (8 * int(width) - 1) - 1.0)


def _robust_outliers(x: np.ndarray, valid: np.ndarray, k: float, log: bool, quantum: float) -> np.ndarray:
    """Pixels farther than k robust scales from the median of x[valid].

    The scale is 1.4826 MAD, never below a floor that cannot vanish: for ``log`` (x = ln E)
    :data:`OUTLIER_SCALE_FLOOR` or the channel's quantum relative to the median value, else
    :data:`OUTLIER_SCALE_FLOOR` times the median magnitude or the quantum (x's unit; 0: unknown).
    A map whose MAD is 0 (a uniform map) thus still masks an absurd pixel."""
    if valid.sum() < 8:
        return np.zeros_like(valid)
    v = x[valid]
    med = float(np.median(v))
    mad = 1.4826 * float(np.median(np.abs(v - med)))
    if log:
        floor = max(OUTLIER_SCALE_FLOOR, quantum / math.exp(med))
    else:
        floor = max(OUTLIER_SCALE_FLOOR * float(np.median(np.abs(v))), quantum)
    with np.errstate(invalid="ignore"):
        return valid & (np.abs(x - med) > k * max(mad, floor))


def _quantum(scan: Scan, factor: float) -> float:
    """One LSB of a channel in SI (its ``z_per_lsb`` times the SI ``factor``; 0 when unknown)."""
    per = scan.metadata.get("z_per_lsb")
    return 0.0 if per is None else abs(float(per)) * float(factor)


def channel_disagreement(linear: Scan, log: Scan, usable: np.ndarray) -> np.ndarray:
    r"""Pixels where a linear modulus channel and its logarithmic twin disagree (bool (ny, nx)).

    ``log`` is the decoded ``LogDMTModulus`` (:func:`arsurf.load_scan` returns 10**value), in the
    linear channel's unit; ``usable`` the pixels both can be compared at (the linear value is a
    fit: finite, not zero, not saturated). They agree where
    :math:`|E_{lin} - E_{log}| \le q + \epsilon E_{log}`, with *q* one LSB of the linear channel
    (its rounding; 0 when the file does not state it) and :math:`\epsilon` =
    :data:`CROSS_CHECK_RELATIVE`. A pixel whose log value is not a positive number disagrees.

    On sample_0.spm 17.2 % of the pixels disagree, almost all by a factor :math:`16^k`,
    k = 1...5 (pySPM reads the same values: it is in the file).
    """
    if _unit(linear) != _unit(log):
        raise MaterialMapError(f"the log modulus channel {log.channel!r} is in {_unit(log)!r}, the modulus channel "
                               f"{linear.channel!r} in {_unit(linear)!r}: they cannot be compared; give both in one "
                               "unit, or cross_check='off' (CLI --cross-check off)")
    a = np.asarray(linear.heights, dtype=np.float64)
    b = np.asarray(log.heights, dtype=np.float64)
    q = _quantum(linear, 1.0)
    with np.errstate(invalid="ignore"):
        agree = np.isfinite(b) & (b > 0.0) & (np.abs(a - b) <= q + CROSS_CHECK_RELATIVE * b)
    return usable & ~agree


def _check_grid(height: Scan, chan: Scan, offset, what: str) -> str:
    """'same grid', or how the channel is resampled; raises when it does not cover the height image."""
    ny, nx = chan.shape
    hy, hx = height.shape
    same = ((ny, nx) == (hy, hx) and math.isclose(chan.dx, height.dx, rel_tol=1e-9)
            and math.isclose(chan.dy, height.dy, rel_tol=1e-9) and offset == (0.0, 0.0))
    if same:
        return "same grid"
    x0, y0 = offset
    cx = (x0, x0 + (nx - 1) * chan.dx)
    cy = (y0, y0 + (ny - 1) * chan.dy)
    hxr = (0.0, (hx - 1) * height.dx)
    hyr = (0.0, (hy - 1) * height.dy)
    tx, ty = 0.5 * max(chan.dx, height.dx), 0.5 * max(chan.dy, height.dy)
    if not (cx[0] <= hxr[0] + tx and cx[1] >= hxr[1] - tx and cy[0] <= hyr[0] + ty and cy[1] >= hyr[1] - ty):
        raise MaterialMapError(
            f"the {what} channel {chan.channel!r} ({nx}x{ny} px of {chan.dx * 1e9:.4g} x {chan.dy * 1e9:.4g} nm) covers "
            f"x {cx[0] * 1e9:.4g}..{cx[1] * 1e9:.4g} nm, y {cy[0] * 1e9:.4g}..{cy[1] * 1e9:.4g} nm, but the height "
            f"image ({hx}x{hy} px of {height.dx * 1e9:.4g} x {height.dy * 1e9:.4g} nm) spans x 0..{hxr[1] * 1e9:.4g} nm, "
            f"y 0..{hyr[1] * 1e9:.4g} nm: the grids do not match. Pass offset=(x0, y0) (m) if the map starts "
            "elsewhere in the height image, or crop both to the same area")
    return (f"resampled: {nx}x{ny} px of {chan.dx * 1e9:.4g} x {chan.dy * 1e9:.4g} nm at offset "
            f"({x0 * 1e9:.4g}, {y0 * 1e9:.4g}) nm onto {hx}x{hy} px of {height.dx * 1e9:.4g} x {height.dy * 1e9:.4g} nm")


def _stats(v: np.ndarray) -> dict:
    p5, p50, p95 = np.percentile(v, [5.0, 50.0, 95.0])
    return {"median": float(p50), "p5": float(p5), "p95": float(p95), "pixels": int(v.size)}


def _fill(values: np.ndarray, mask: np.ndarray, like: Scan) -> np.ndarray:
    """Masked pixels filled by Laplace inpainting (:func:`arsurf.inpaint`)."""
    from arsurf.scan.inpaint import inpaint

    if not mask.any():
        return values
    return np.array(inpaint(Scan(np.where(mask, np.nan, values), like.dx, like.dy, like.channel, {},
                                 like.source)).heights)


def _smooth(values: np.ndarray, like: Scan, sigma: float) -> np.ndarray:
    """Gaussian smoothing of width sigma (m; 0: none), :func:`arsurf.smooth`."""
    from arsurf.scan.smooth import smooth

    if not sigma > 0.0:
        return values
    return np.array(smooth(Scan(values, like.dx, like.dy, like.channel, {}, like.source), sigma).heights)


def _fit(values: np.ndarray, like: Scan, control_shape, smoothing: float):
    """(coef (nu, nv), ku, kv) of the height's bicubic fit to a field on the channel's grid."""
    from arsurf.spline.fit import fit_surface

    surf = fit_surface(Scan(values, like.dx, like.dy, like.channel, {}, like.source), control_shape=control_shape,
                       smoothing=smoothing)
    return np.ascontiguousarray(surf.control_points[..., 2]), surf.knots_u.copy(), surf.knots_v.copy()


def _unit(scan: Scan) -> str:
    u = scan.metadata.get("z_unit")
    return "m" if u is None else str(u)


def build_material_map(height: Scan, channels: Mapping[str, Scan], conversion: MaterialConversion, *,
                       offset=(0.0, 0.0), sigma: float = 0.0, smoothing: float = 0.0, control_shape=None,
                       source: str = "") -> MaterialMap:
    """A :class:`MaterialMap` from mechanical channels, registered to a height image.

    Parameters
    ----------
    height : Scan
        The height image the model is fitted to (its grid is the frame of the map).
    channels : mapping
        ``"modulus"`` (sample Young modulus) and ``"adhesion"`` (pull-off force) Scans, required;
        ``"deformation"``, ``"dissipation"`` optional (viewer maps). Each carries its unit in
        ``metadata["z_unit"]`` (what :func:`arsurf.load_scan` gives); all on one grid.
    conversion : MaterialConversion
    offset : (x0, y0), m
        Where the channels' first pixel sits in the height image's frame.
    sigma : float, m
        Gaussian smoothing of the fields (0: none).
    smoothing, control_shape
        As :func:`arsurf.fit_surface` (default: the interpolating fit).
    source : str
        Where the channels came from (for messages and the record).

    Raises
    ------
    MaterialMapError
        A required channel is missing, a unit has no stated conversion, the grid does not cover
        the height image, or a channel has no usable pixel.
    """
    if not isinstance(conversion, MaterialConversion):
        raise MaterialMapError(f"conversion must be a MaterialConversion (got {type(conversion).__name__})")
    unknown = sorted(set(channels) - set(CHANNEL_NAMES))
    if unknown:
        raise MaterialMapError(f"unknown channel roles {unknown}; roles are {sorted(CHANNEL_NAMES)}")
    for need in ("modulus", "adhesion"):
        if channels.get(need) is None:
            raise MaterialMapError(f"a material map needs the {need} channel (a {CHANNEL_NAMES[need]}-like image)")
    try:
        offset = (float(offset[0]), float(offset[1]))
    except (TypeError, ValueError, IndexError):
        raise MaterialMapError(f"offset must be (x0, y0) in metres (got {offset!r})") from None
    if not all(math.isfinite(o) for o in offset):
        raise MaterialMapError(f"offset must be finite (got {offset!r} m)")
    sigma = float(sigma)
    if not (math.isfinite(sigma) and sigma >= 0.0):
        raise MaterialMapError(f"sigma must be >= 0 m (got {sigma!r}); it is the Gaussian smoothing width")
    ref = channels["modulus"]
    present = {k: v for k, v in channels.items() if v is not None}
    if conversion.cross_check == "off":
        present.pop("log_modulus", None)   # not compared, not used: not part of the map
    for role, chan in present.items():
        if not isinstance(chan, Scan):
            raise MaterialMapError(f"the {role} channel must be an arsurf Scan (got {type(chan).__name__})")
        if chan.shape != ref.shape or not (math.isclose(chan.dx, ref.dx, rel_tol=1e-9)
                                           and math.isclose(chan.dy, ref.dy, rel_tol=1e-9)):
            raise MaterialMapError(f"the {role} channel ({chan.shape[1]}x{chan.shape[0]} px) is not on the modulus "
                                   f"channel's grid ({ref.shape[1]}x{ref.shape[0]} px): the channels of one map share "
                                   "one grid")
        if chan.shape[0] < 4 or chan.shape[1] < 4:
            raise MaterialMapError(f"the {role} channel has {chan.shape[1]}x{chan.shape[0]} pixels; a map needs 4x4")
    registration = _check_grid(height, ref, offset, "modulus")
    masked: dict[str, dict[str, float]] = {}
    n = ref.heights.size

    def base_mask(role: str, raw: np.ndarray, scan: Scan) -> dict[str, np.ndarray]:
        fs = _saturation(scan)
        with np.errstate(invalid="ignore"):
            reasons = {"not_finite": ~np.isfinite(raw), "zero": raw == 0.0,
                       "saturated": (np.abs(raw) >= fs * (1.0 - 1e-9)) if fs else np.zeros(raw.shape, bool)}
        return reasons

    def record(role: str, reasons: dict[str, np.ndarray]) -> np.ndarray:
        total = np.zeros(ref.shape, bool)
        for m in reasons.values():
            total |= m
        masked[role] = {k: float(v.sum()) / n for k, v in reasons.items()}
        masked[role]["masked"] = float(total.sum()) / n
        if total.all():
            raise MaterialMapError(f"every pixel of the {role} channel {present[role].channel!r} is unusable "
                                   f"({', '.join(f'{k} {v:.1%}' for k, v in masked[role].items())})")
        return total

    mod = present["modulus"]
    conv, poisson_source = conversion.with_sample_poisson(mod.metadata.get("sample_poisson_ratio"))
    # modulus: the cross-check of the two channels, then log E_s, masked, filled, smoothed
    raw = np.asarray(mod.heights, dtype=np.float64)
    reasons = base_mask("modulus", raw, mod)
    twin = present.get("log_modulus")
    cross: dict = {"policy": conv.cross_check, "channel": None, "compared_fraction": 0.0,
                   "disagreeing_fraction": None, "tolerance": f"1 LSB + {CROSS_CHECK_RELATIVE:.0%}"}
    if twin is not None:
        usable = ~(reasons["not_finite"] | reasons["zero"] | reasons["saturated"])
        disagree = channel_disagreement(mod, twin, usable)
        cross.update(channel=twin.channel, compared_fraction=float(usable.sum()) / n,
                     disagreeing_fraction=float(disagree.sum()) / n)
        if conv.cross_check == "mask":
            reasons["channels_disagree"] = disagree
        else:  # "log": the log channel's values; a failed fit (a linear zero) stays masked
            log_raw = np.asarray(twin.heights, dtype=np.float64)
            reasons = {"not_finite": ~np.isfinite(log_raw), "zero": reasons["zero"] | (log_raw == 0.0),
                       "saturated": np.zeros(raw.shape, bool)}
            raw, mod = log_raw, twin
    es, _, how_e = channel_to_si(raw, _unit(mod), "modulus", conv, mod.channel)
    with np.errstate(invalid="ignore", divide="ignore"):
        reasons["nonpositive"] = np.isfinite(es) & (es < 0.0)
        log_es = np.log(np.where(es > 0.0, es, np.nan))
    ok = ~np.logical_or.reduce(list(reasons.values()))
    reasons["outlier"] = _robust_outliers(log_es, ok, conv.outlier_mads, True, _quantum(mod, how_e["factor"]))
    m_mod = record("modulus", reasons)
    log_es = _fill(log_es, m_mod, mod)
    e_star_pixels = reduced_modulus(np.exp(log_es), conv)  # filled, not smoothed: the statistics' E*
    e_star = reduced_modulus(np.exp(_smooth(log_es, mod, sigma)), conv)
    # adhesion: pull-off force, masked, filled, smoothed, floored
    adh = present["adhesion"]
    raw = np.asarray(adh.heights, dtype=np.float64)
    fo, _, how_f = channel_to_si(raw, _unit(adh), "adhesion", conv, adh.channel)
    reasons = base_mask("adhesion", raw, adh)
    ok = ~(reasons["not_finite"] | reasons["zero"] | reasons["saturated"])
    reasons["outlier"] = _robust_outliers(fo, ok, conv.outlier_mads, False, _quantum(adh, how_f["factor"]))
    m_adh = record("adhesion", reasons)
    f_fill = _smooth(_fill(fo, m_adh, adh), adh, sigma)
    floor = conv.adhesion_floor
    if floor is None:  # the noise of the field the map is made of (smoothing lowers it)
        neg = f_fill[f_fill < 0.0]
        pos = f_fill[f_fill > 0.0]
        if neg.size:
            floor = float(np.sqrt(np.mean(neg * neg)))
        elif pos.size:
            floor = 1e-3 * float(np.median(pos))
        else:
            raise MaterialMapError(f"the adhesion channel {adh.channel!r} has no positive pull-off force")
    floored = f_fill < floor
    masked["adhesion"]["floored"] = float(floored.sum()) / n
    masked["adhesion"]["floor_N"] = floor
    w = work_of_adhesion_from_pull_off(np.maximum(f_fill, floor), e_star, conv)
    # the statistics: every unmasked pixel's own pull-off (floored) at its own E*, no smoothing
    w_valid = work_of_adhesion_from_pull_off(np.maximum(fo[~m_adh], floor), e_star_pixels[~m_adh], conv)
    fields = {}
    for name, values, unit, channel in (("reduced_modulus", e_star, "Pa", mod.channel),
                                        ("work_of_adhesion", w, "J/m^2", adh.channel)):
        refv = float(np.median(values))
        z = np.log(values / refv)
        coef, ku, kv = _fit(z, mod, control_shape, smoothing)
        fields[name] = MapField(name, unit, channel, True, refv, coef, ku, kv, float(z.min()), float(z.max()),
                                _readonly(values))
    # the viewer's maps, in SI when a scale is stated, else in the channel's unit
    for role in ("deformation", "dissipation"):
        chan = present.get(role)
        if chan is None:
            continue
        raw = np.asarray(chan.heights, dtype=np.float64)
        vals, unit, _ = channel_to_si(raw, _unit(chan), role, conv, chan.channel)
        reasons = base_mask(role, raw, chan)
        reasons.pop("zero")  # a zero deformation or dissipation is a value, not a failed fit
        m = record(role, reasons)
        filled = _smooth(_fill(vals, m, chan), chan, sigma)
        coef, ku, kv = _fit(filled, chan, control_shape, smoothing)
        fields[role] = MapField(role, unit, chan.channel, False, 1.0, coef, ku, kv, float(filled.min()),
                                float(filled.max()), _readonly(filled))
    stats = {"reduced_modulus": _stats(e_star_pixels[~m_mod]), "work_of_adhesion": _stats(w_valid),
             "pull_off_force": _stats(fo[~m_adh]), "sample_modulus": _stats(es[~m_mod])}
    processing = {"sigma": sigma, "smoothing": float(smoothing),
                  "control_shape": None if control_shape is None else [int(c) for c in control_shape],
                  "modulus_conversion": how_e, "adhesion_conversion": how_f, "cross_check": cross,
                  "sample_poisson_source": poisson_source}
    return MaterialMap(MappingProxyType(fields), offset, (ref.dx, ref.dy), conv,
                       MappingProxyType({k: v.channel for k, v in present.items()}),
                       MappingProxyType(masked), MappingProxyType(stats), registration, processing,
                       source or ref.source)


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a, dtype=np.float64)
    a.setflags(write=False)
    return a


def material_map_from_file(path, conversion: MaterialConversion, *, height: Scan | None = None,
                           channels: Mapping[str, str | None] | None = None, units: Mapping[str, str] | None = None,
                           offset=(0.0, 0.0), sigma: float = 0.0, smoothing: float = 0.0,
                           control_shape=None) -> MaterialMap:
    """A :class:`MaterialMap` from the mechanical channels of a scan file.

    ``channels`` maps a role to a channel name (default :data:`CHANNEL_NAMES`; ``log_modulus``
    (the cross-check's), ``deformation`` and ``dissipation`` are optional and skipped when the
    file lacks them, a name given as None is skipped too). ``units`` gives the unit of a role's channel in a file that does not state
    it (a bare ``.npz``: ``{"modulus": "Pa", "adhesion": "N"}``, as ``z_unit`` of
    :func:`arsurf.load_scan`). ``height`` is the image the map registers to (default: the file's
    height channel as read, which has the grid of the model's fit). Other arguments as
    :func:`build_material_map`.
    """
    from arsurf.errors import ChannelNotFound
    from arsurf.scan.io import load_scan

    names = dict(CHANNEL_NAMES)
    names.update(channels or {})
    if conversion.cross_check == "off":
        names["log_modulus"] = None
    units = dict(units or {})
    bad = sorted(set(units) - set(CHANNEL_NAMES))
    if bad:
        raise MaterialMapError(f"units for unknown roles {bad}; roles are {sorted(CHANNEL_NAMES)}")
    scans: dict[str, Scan] = {}
    for role, name in names.items():
        if name is None:
            continue
        try:
            scans[role] = load_scan(path, channel=name, z_unit=units.get(role))
        except ChannelNotFound:
            if role in ("modulus", "adhesion") or (channels and channels.get(role)):
                raise
    if height is None:
        height = load_scan(path)
    m = build_material_map(height, scans, conversion, offset=offset, sigma=sigma, smoothing=smoothing,
                           control_shape=control_shape, source=str(path))
    if units:
        m.processing["units"] = units  # type: ignore[index]  (recorded: a replay reads the same way)
    return m


def contact_vector(material: MaterialMap | None, contact, n_friction: int, n_dent: int) -> np.ndarray:
    """The contact vector of the model's tick: the reference law, the map, and scratch space.

    ``contact`` is the model's reference Maugis-Dugdale law; without a map the vector says so and
    :func:`local_contact_kernel` returns the reference law's arguments. With a map the law's tip
    radius and Dugdale range must be the conversion's (the same tip and interface law).
    ``n_friction``, ``n_dent``: the sizes of the sections for the model's local friction vector
    (scratch) and the dent the tick records (their offsets at ``H_FRICTION`` and ``H_DENT``).
    """
    ref = np.array(contact.kernel_args, dtype=np.float64)
    head = np.zeros(C_BODY - C_HEAD)
    parts: list[np.ndarray] = []
    pos = C_BODY

    def section(a) -> int:
        nonlocal pos
        at = pos
        parts.append(np.ascontiguousarray(a, dtype=np.float64).ravel())
        pos += parts[-1].size
        return at

    head[H_FRICTION - C_HEAD] = section(np.zeros(n_friction))
    head[H_DENT - C_HEAD] = section(np.zeros(n_dent))
    head[H_KU - C_HEAD] = pos     # the end of the dent without a map
    if material is not None:
        if not isinstance(material, MaterialMap):
            raise MaterialMapError(f"material must be an arsurf MaterialMap (got {type(material).__name__})")
        conv = material.conversion
        if not math.isclose(contact.tip_radius, conv.tip_radius, rel_tol=1e-12):
            raise MaterialMapError(f"the material map was converted for a {conv.tip_radius * 1e9:.6g} nm tip, the "
                                   f"model's tip is {contact.tip_radius * 1e9:.6g} nm: convert the map with the model's "
                                   "tip radius")
        if not math.isclose(contact.interaction_range, conv.dugdale_range, rel_tol=1e-9):
            raise MaterialMapError(f"the contact law's Dugdale range w/sigma0 ({contact.interaction_range!r} m) differs "
                                   f"from the map's ({conv.dugdale_range!r} m); build the law with "
                                   "MaterialMap.contact_law()")
        fe, fw = material.fields["reduced_modulus"], material.fields["work_of_adhesion"]
        off_e = math.log(fe.reference / contact.effective_modulus)
        off_w = math.log(fw.reference / contact.work_of_adhesion)
        # the lambda range the kernel can reach: lambda ~ (w / E*)^(2/3) within the clamped ratios
        lam = contact.maugis_parameter
        table, x0, step = critical_point_table(lam * math.exp(2.0 / 3.0 * ((fw.lo + off_w) - (fe.hi + off_e))),
                                               lam * math.exp(2.0 / 3.0 * ((fw.hi + off_w) - (fe.lo + off_e))))
        values = {H_ON: 1.0, H_X0: material.offset[0], H_Y0: material.offset[1], H_OFF_E: off_e, H_OFF_W: off_w,
                  H_LO_E: fe.lo, H_HI_E: fe.hi, H_LO_W: fw.lo, H_HI_W: fw.hi, H_LNLAM0: x0, H_TABLE_STEP: step,
                  H_NU: fe.coef.shape[0], H_NV: fe.coef.shape[1], H_NTABLE: table.shape[0],
                  H_KU: section(fe.knots_u), H_KV: section(fe.knots_v), H_TABLE: section(table),
                  H_COEF: section(np.stack([fe.coef, fw.coef], axis=-1))}
        for key, val in values.items():
            head[key - C_HEAD] = val
    return np.concatenate([ref, ref, head, *parts])
