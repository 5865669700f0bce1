r"""Local deformation of the control net by the tip ([SplineAR]), reversible and O(patch).

[SplineAR]: "all control points in the area of contact, i.e. which lie within the contact radius
around the central line of contact, are projected onto the sphere representing the tip". With C
the tip centre, R its radius, n the unit contact normal (out of the sample) and a the contact
radius (Maugis-Dugdale), a control point P at rest position P₀ has the axial and radial parts

.. math:: s = (P_0 - C)\cdot n, \qquad \mathbf r = (P_0 - C) - s\,n, \qquad ρ = |\mathbf r|.

**Inside the contact** (ρ < a: pressed in on approach, held up by adhesion on retraction - the
neck) it is moved onto the sample-side cap of the tip sphere,

.. math:: P = C + \mathbf r - \sqrt{R^2 - ρ^2}\; n

(for a contact wider than 0.9 R, far beyond the small-strain theory, where the sphere turns
vertical, the contact zone follows the contact's own paraboloid, :math:`u = δ - ρ^2/2R`).

**Outside the contact** (ρ ≥ a) the surface is not on the sphere: it follows the elastic
half-space under the Maugis-Dugdale tractions, moved along -n by the normal displacement
u(ρ) (positive into the sample; Johnson 1985 Eq. 3.42 for the Hertz part, Maugis 1992 for the
Dugdale zone). The tractions are a Hertz pressure of radius a plus the Dugdale stress written as
a superposition of flat punches, :math:`G_D(t) = -\tfrac{2σ_0}{π}\,t/\sqrt{c^2-t^2}` on a < t < c
(its Abel transform is exactly Maugis' :math:`-\tfrac{σ_0}{π}\arccos\frac{2a^2-c^2-r^2}{c^2-r^2}`
inside a and :math:`-σ_0` on the annulus); a flat punch of radius t displaces the surface by
π/E* inside t and :math:`\tfrac{2}{E^*}\arcsin(t/ρ)` outside. With
:math:`δ_D = δ - a^2/R \le 0` (the adhesive part of the depth, :math:`-2σ_0\sqrt{c^2-a^2}/E^*`):

.. math::

    u(ρ) = \frac{1}{πR}\Big[(2a^2 - ρ^2)\arcsin\frac aρ + a\sqrt{ρ^2 - a^2}\Big]
         + \frac{2δ_D}{π}\Big[\arcsin\frac aρ + \frac{J(ρ)}{\sqrt{c^2-a^2}}\Big],
    \qquad J(ρ) = \int_a^{\min(ρ, c)} \sqrt{\frac{c^2 - t^2}{ρ^2 - t^2}}\,dt .

It meets the contact's paraboloid at ρ = a (u(a) = δ - a²/2R), gives the
gap :math:`h_0` at ρ = c (Maugis' condition, tested), and decays as 1/ρ (a point load). For Hertz
(c = a, δ = a²/R) only the first term is left, and the surface meets the tip exactly on the
circle ρ = a: the dent's rim is the contact radius, not the geometric overlap √(2Rδ) (the
points between a and √(2Rδ) lie *below* the tip, where the elastic surface is). J is a smooth
integral after t = ρ - v² (ρ ≤ c) or t = c - v² (ρ > c): Gauss-Legendre
(:func:`elastic_displacement`, checked against Boussinesq's solution summed over Maugis'
tractions).

In the tick both bracketed shapes are read from tables built once at import (the Hertz shape
on q = a/ρ, the zone's on (a/c, √((ρ - a)/(c - a))) inside the zone and (a/c, c/ρ) beyond it),
the profile is tabulated at :data:`PROFILE_SIZE` radii uniform in :math:`\sqrt{ρ^2 - a^2}`
(dense at the rim, where an adhesive neck is steep), and each control point reads it by linear
interpolation: a few flops and one square root per point. The paraboloid lies below the
sphere at the rim by :math:`R - \sqrt{R^2-a^2} - a^2/2R` (~a⁴/8R³): the net is lifted by that
much at ρ = a, the lift fading out by 1.5 a, so the dent is continuous where it leaves the tip
(:func:`dent_displacement`, what the dent draws). The tables cost at most ~0.5 % of
the depth, at the edge of the Dugdale zone where the profile has a logarithmic kink (tested to
1 %). The elastic surface is drawn out to 3a, its 1/ρ tail faded to zero (raised cosine) over
[1.5a, 3a], so the dent stays local (on a flat sample the rest surface is already below the
tip beyond 1.5a, Hertz included, so the fade never leaves a point inside it). Out to R, a rest
point still inside the sphere (a rough patch under the tip, which the half-space solution does
not know) is put on the sphere. Every other control point keeps its rest position **bitwise**.

Only the index box of control points whose rest (x, y) lies within :math:`r_b = \max(R, 3a)`
(+ one knot spacing) of the tip axis' foot can move: the reference kernel puts the previous box
back to rest where the new one does not cover it and writes the new one, each point once, so a
dent costs O((2 r_b/h)²) whatever the scan size (:func:`sync_dent_kernel`). That is
:math:`(2r_b/h)^2`: 27,000 points for a 20 nm tip on a 0.25 nm net, 250,000 at 0.1 nm and
50 nm. Most of that guard box is never moved: only the points within 3a of the axis (the
contact and its elastic surface) and those a rough surface leaves inside the tip ball. The
read therefore uses :func:`sync_dent_tiled_kernel`: the box is cut into 8 × 8 tiles, and a tile
whose bounding sphere (from its rest heights) misses every contact's cylinder ρ < 3a and tip
ball is skipped (or copied back to rest if the dent shown before reached it); the others are
written point by point by the same rule. The net is the reference's bit for bit (tested over
0.1-2 nm pitch × 2-50 nm tips, tilted, adhesive, wide, multi-contact dents and releases), and
the read costs O(the points the dent moves), ~(6a/h)², not O((2R/h)²). So the haptic tick does
not dent: it *records* the dent (centre, normal, R, a, δ, c:
:func:`record_dent_kernel`, O(1) whatever the pitch), and the net is moved to the recorded dent
when it is next read (:meth:`Deformer.sync`, called by
:meth:`~arsurf.spline.surface.BSplineSurface.sync` before every read of the net: evaluation,
the control points, the kernel arrays). A reader therefore sees exactly, bitwise, the full dent
of the last tick - there is no approximation to state - and the work is done at the reader's
rate (a 60 Hz view) instead of the tick's (10 kHz), once per read. (The compiled tick holds
the GIL while it records, and the reader copies the record while it holds the GIL, so it never
sees a half-recorded dent; the net is then written without the GIL - the tick never reads the
live net - so a reader in another thread does not stall the haptic thread.)
:meth:`Deformer.release` puts the box back to rest; ``surface.reset()`` restores everything.

**Several contacts of one tip** (a groove, two asperities: contacts k = 1..n with their own
normal n_k, contact radius a_k, depth δ_k and zone c_k) each record a dent, and the net is
moved to all of them at once: a point inside contact k's disc goes onto the tip's cap along
n_k; elsewhere the elastic displacements add,

.. math:: P = P_0 - \sum_k u_k(ρ_k)\, n_k ,

the half-space's response to the sum of the contacts' tractions (linear elasticity: Johnson
1985 §3.2, superposition of Boussinesq's solution), each :math:`u_k` the single-contact
profile above; a point still inside the tip then goes onto the sphere. The cost is that of
the union of the contacts' boxes (each point written once), and one contact is the
single-contact dent bit for bit.

The rest net must be a height-field net on the Greville abscissae (what
:func:`arsurf.fit_surface` builds), so the index box is found in O(1) from the knot spacing.

Sources: [SplineAR] (the dent); K. L. Johnson, *Contact Mechanics* (1985) Eq. 3.42 (Hertz
displacement outside the contact) and §3.8 (flat punch); D. Maugis, J. Colloid Interface Sci.
150, 243 (1992) (the Dugdale zone).
"""
from __future__ import annotations

import math
import threading
from dataclasses import dataclass

import numpy as np
from numba import njit

from arsurf._layout import Layout
from arsurf.errors import ContactError
from arsurf.spline.surface import BSplineSurface

# status bits returned by the kernel
DEFORM_OK = 0
DEFORM_NO_PATCH = 1  # the tip is outside the net's footprint: nothing to move

#: radii of the per-tick profile table (uniform in sqrt(rho^2 - a^2)): the scratch array's length
PROFILE_SIZE = 32
#: the dented patch of the control net (int64): control-point rows [i0, i1) and columns [j0, j1)
DENT_PATCH = Layout("dent patch", [("rows", 2), ("columns", 2)])
_I0, _J0 = DENT_PATCH.offset("rows"), DENT_PATCH.offset("columns")
_I1, _J1 = _I0 + 1, _J0 + 1
_PATCH = DENT_PATCH.size
#: the contact zone is put on the sphere up to a = SPHERE_LIMIT R; a wider contact (far beyond
#: small strain, where the sphere turns vertical) follows the contact's own paraboloid
SPHERE_LIMIT = 0.9
#: the net meets the sphere at the rim to within this many a^2/R (0.2 % of the Hertz depth): the
#: profile table's chord next to the rim (at most a^2/960R) stays below the tip
RIM_MARGIN = 2e-3
#: the elastic surface reaches PATCH_PER_CONTACT * a, its tail faded over the outer half; the
#: patch is max(R, that): points inside the tip are put on it out to R
PATCH_PER_CONTACT = 3.0
_GAUSS = np.polynomial.legendre.leggauss(48)


@njit(cache=True, inline="always")
def _index_range(lo, hi, u0, h, n):
    """Control indices whose Greville abscissa may lie in [lo, hi] (one spare each side)."""
    i0 = int(math.floor((lo - u0) / h)) - 1
    i1 = int(math.floor((hi - u0) / h)) + 3
    if i0 < 0:
        i0 = 0
    if i1 > n:
        i1 = n
    return i0, i1


def _hertz_shape(q):
    """f(q) = (2 - 1/q^2) arcsin q + sqrt(1/q^2 - 1), q = a/rho in (0, 1]; the series
    4q/3 + 2q^3/15 + 3q^5/70 below q = 0.02 (no cancellation)."""
    q = np.asarray(q, dtype=np.float64)
    qs = np.maximum(q, 0.02)
    exact = (2.0 - 1.0 / qs ** 2) * np.arcsin(np.minimum(qs, 1.0)) + np.sqrt(np.maximum(1.0 / qs ** 2 - 1.0, 0.0))
    q2 = q * q
    return np.where(q < 0.02, q * (4.0 / 3.0 + q2 * (2.0 / 15.0 + q2 * 3.0 / 70.0)), exact)


def _zone_shape(x, m):
    """G = arcsin(1/x) + J/sqrt(m^2 - 1) at x = rho/a >= 1 for a Dugdale zone m = c/a > 1 (a = 1):
    J = int_1^min(x, m) sqrt((m^2 - t^2)/(x^2 - t^2)) dt, by 48-point Gauss-Legendre after
    t = x - v^2 (x <= m: the integrand becomes 2 sqrt(m^2 - t^2)/sqrt(x + t)) or t = m - v^2 (x > m:
    2 v^2 sqrt(m + t)/sqrt(x^2 - t^2)); both smooth, no trigonometry. Broadcasts."""
    x, m = np.broadcast_arrays(np.asarray(x, dtype=np.float64), np.asarray(m, dtype=np.float64))
    gx, gw = _GAUSS
    inside = x <= m
    top = np.sqrt(np.where(inside, x, m) - 1.0)          # v runs over [0, top]
    v = 0.5 * top[..., None] * (gx + 1.0)
    t = np.where(inside, x, m)[..., None] - v * v
    xx, mm = x[..., None], m[..., None]
    with np.errstate(invalid="ignore", divide="ignore"):
        f_in = 2.0 * np.sqrt(np.maximum((mm - t) * (mm + t), 0.0)) / np.sqrt(xx + t)
        f_out = 2.0 * v * v * np.sqrt(mm + t) / np.sqrt(np.maximum((xx - t) * (xx + t), 1e-300))
    j = 0.5 * top * np.sum(gw * np.where(inside[..., None], f_in, f_out), axis=-1)
    return np.arcsin(1.0 / x) + j / np.sqrt((m - 1.0) * (m + 1.0))


def elastic_displacement(rho, a, tip_radius, depth, zone_radius):
    """Normal displacement u (m, into the sample) of the surface at ρ >= a outside a contact.

    ``a`` contact radius, ``tip_radius`` R, ``depth`` δ, ``zone_radius`` c >= a (Dugdale zone;
    c = a and δ = a²/R is Hertz), all metres; ``rho`` a float or an array. The equation is in
    the module docstring (quadrature to ~1e-12; the compiled dent reads tables of it). For ρ < a
    it returns u(a); δ above a²/R (no adhesive part) is taken as a²/R.

    Examples
    --------
    >>> R, a = 20e-9, 4e-9
    >>> round(elastic_displacement(a, a, R, a * a / R, a) / (a * a / (2 * R)), 12)   # Hertz: u(a) = a^2/2R
    1.0
    """
    rho = np.maximum(np.asarray(rho, dtype=np.float64), a)
    u = a * a / (math.pi * tip_radius) * _hertz_shape(a / rho)
    d_adh = depth - a * a / tip_radius
    if zone_radius > a and d_adh < 0.0:
        u = u + 2.0 * d_adh / math.pi * _zone_shape(rho / a, zone_radius / a)
    return u if np.ndim(u) else float(u)


# tables of the shapes, read by the compiled dent (bilinear; built once at import, ~10 ms):
# Hertz f(q) on q = a/rho; the zone shape G inside the zone on (mu = a/c, sqrt((rho - a)/(c - a)))
# and outside it on (mu, c/rho), mu from 0 (c >> a) to 1 (c = a)
_NQ, _NMU, _NR = 513, 97, 97
_Q = np.linspace(0.0, 1.0, _NQ)
_F_HERTZ = _hertz_shape(_Q)


def _zone_tables():
    mu = np.linspace(0.0, 1.0, _NMU)
    mu[0] = 1e-8                      # c -> infinity: the limit (the elliptic integral E(rho/c)) to 1e-8
    r = np.linspace(0.0, 1.0, _NR)
    g_in = np.empty((_NMU, _NR))
    g_out = np.zeros((_NMU, _NR))     # r = c/rho = 0: infinitely far, no displacement
    m = 1.0 / mu[:-1, None]
    g_in[:-1] = _zone_shape(1.0 + r[None, :] ** 2 * (m - 1.0), m)
    g_out[:-1, 1:] = _zone_shape(m / r[None, 1:], m)
    g_in[-1] = 0.5 * math.pi          # c -> a: the zone is a line; outside it a flat punch, arcsin(a/rho)
    g_out[-1] = np.arcsin(r)
    return g_in, g_out


_G_IN, _G_OUT = _zone_tables()


@njit(cache=True, inline="always")
def _lerp2(table, x, y):
    """Bilinear interpolation of table (n, k) over [0, 1] x [0, 1]."""
    n, k = table.shape
    fx = min(max(x, 0.0), 1.0) * (n - 1)
    fy = min(max(y, 0.0), 1.0) * (k - 1)
    i = min(int(fx), n - 2)
    j = min(int(fy), k - 2)
    fx -= i
    fy -= j
    return ((1.0 - fx) * ((1.0 - fy) * table[i, j] + fy * table[i, j + 1])
            + fx * ((1.0 - fy) * table[i + 1, j] + fy * table[i + 1, j + 1]))


@njit(cache=True)
def _table_displacement(rho, a, tip_radius, d_adh, c):
    """:func:`elastic_displacement` from the tables (rho >= a > 0)."""
    q = a / rho
    fq = q * (_NQ - 1)
    i = min(int(fq), _NQ - 2)
    fq -= i
    u = a * a / (math.pi * tip_radius) * (_F_HERTZ[i] + fq * (_F_HERTZ[i + 1] - _F_HERTZ[i]))
    if c <= a or d_adh >= 0.0:
        return u
    mu = a / c
    if rho <= c:
        g = _lerp2(_G_IN, mu, math.sqrt((rho - a) / (c - a)))
    else:
        g = _lerp2(_G_OUT, mu, c / rho)
    return u + 2.0 * d_adh / math.pi * g


@njit(cache=True, inline="always")
def rim_lift(a, tip_radius):
    """How far the net is lifted at the rim, m: the height of the tip sphere above the contact's
    paraboloid there, :math:`R - \\sqrt{R^2 - a^2} - a^2/2R`, less :data:`RIM_MARGIN` a²/R (so that
    the table's chord near the rim never puts a point inside the tip); 0 when the contact zone
    follows the paraboloid (a > :data:`SPHERE_LIMIT` R)."""
    if a <= 0.0 or a > SPHERE_LIMIT * tip_radius:
        return 0.0
    gap = tip_radius - math.sqrt((tip_radius - a) * (tip_radius + a)) - 0.5 * a * a / tip_radius
    return max(gap - RIM_MARGIN * a * a / tip_radius, 0.0)


@njit(cache=True, inline="always")
def _rim_fade(rho, a):
    """1 at the rim, 0 from 1.5 a on (raised cosine)."""
    x = (rho - a) / (0.5 * a)
    return 0.0 if x >= 1.0 else 0.5 * (1.0 + math.cos(math.pi * max(x, 0.0)))


@njit(cache=True)
def _fill_profile(profile, a, tip_radius, depth, zone_radius, r_elastic):
    """profile[k] = the dent's displacement at rho_k (:func:`dent_displacement`), rho_k^2 = a^2 +
    w_k^2 with w_k uniform from 0 to sqrt(r_elastic^2 - a^2) (dense at the rim, where an adhesive
    neck is steep)."""
    n = profile.size
    fade0 = 0.5 * r_elastic
    w_max2 = r_elastic * r_elastic - a * a
    d_adh = depth - a * a / tip_radius
    lift = rim_lift(a, tip_radius)
    for k in range(n):
        f = k / (n - 1)
        rho = math.sqrt(a * a + f * f * w_max2)
        u = _table_displacement(rho, a, tip_radius, d_adh, zone_radius) - lift * _rim_fade(rho, a)
        if rho > fade0:
            u *= 0.5 * (1.0 + math.cos(math.pi * min((rho - fade0) / (r_elastic - fade0), 1.0)))
        profile[k] = u


def dent_displacement(rho, a, tip_radius, depth, zone_radius):
    """What the dent does to a flat net at ρ >= a (m, into the sample): the elastic surface
    (:func:`elastic_displacement`) lifted at the rim onto the tip sphere by :func:`rim_lift`,
    the lift fading out by 1.5 a (raised cosine), and the tail faded over [1.5 a, 3 a]; the
    compiled dent reads a table of it. Arrays of ρ broadcast.

    Examples
    --------
    >>> R, a = 20e-9, 4e-9
    >>> sphere = a * a / R - (R - (R * R - a * a) ** 0.5)   # how far the sphere is pushed in at rho = a
    >>> round((dent_displacement(a, a, R, a * a / R, a) - sphere) / (a * a / R), 6)   # RIM_MARGIN
    0.002
    """
    rho = np.asarray(rho, dtype=np.float64)
    u = elastic_displacement(rho, a, tip_radius, depth, zone_radius)
    x = np.clip((rho - a) / (0.5 * a), 0.0, 1.0)
    u = u - rim_lift(a, tip_radius) * 0.5 * (1.0 + np.cos(np.pi * x))
    r_el = PATCH_PER_CONTACT * a
    y = np.clip((rho - 0.5 * r_el) / (0.5 * r_el), 0.0, 1.0)
    u = np.where(rho > 0.5 * r_el, u * 0.5 * (1.0 + np.cos(np.pi * y)), u)
    return u if np.ndim(u) else float(u)


@njit(cache=True, inline="always")
def _dent_box(nu, nv, ku, kv, cx, cy, radius, contact_radius):
    """Index box (i0, i1, j0, j1) of the control points a dent may move: rest (x, y) within
    max(R, 3a) (+ one knot spacing) of the tip axis' foot; empty for a release (R <= 0)."""
    if radius <= 0.0:
        return 0, 0, 0, 0
    r_box = max(radius, PATCH_PER_CONTACT * max(contact_radius, 0.0))
    hu = (ku[nu] - ku[3]) / (nu - 3)
    hv = (kv[nv] - kv[3]) / (nv - 3)
    i0, i1 = _index_range(cx - r_box, cx + r_box, ku[3], hu, nu)
    j0, j1 = _index_range(cy - r_box, cy + r_box, kv[3], hv, nv)
    if i0 >= i1 or j0 >= j1:
        return 0, 0, 0, 0
    return i0, i1, j0, j1


# The dent as the tick records it (DENT vector, float64): the tick writes these numbers, O(1)
# whatever the pitch, and the net is moved to them when it is read (Deformer.sync). A model with
# several contacts records one DENT per contact, one after the other (sync_dent_kernel).
DENT = Layout("recorded dent", [("seq", 1), ("center", 3), ("radius", 1), ("normal", 3), ("contact_radius", 1),
                                 ("depth", 1), ("zone_radius", 1)])
D_SEQ, D_CX, D_RADIUS, D_NX = DENT.offset("seq"), DENT.offset("center"), DENT.offset("radius"), DENT.offset("normal")
D_CY, D_CZ, D_NY, D_NZ = D_CX + 1, D_CX + 2, D_NX + 1, D_NX + 2
D_A, D_DEPTH, D_ZONE = DENT.offset("contact_radius"), DENT.offset("depth"), DENT.offset("zone_radius")
#: length of the recorded dent of one contact (:func:`record_dent_kernel`)
DENT_SIZE = DENT.size


@njit(cache=True, inline="always")
def _in_boxes(boxes, n, i, j):
    """True if control point (i, j) lies in one of the first ``n`` index boxes (:data:`DENT_PATCH` each)."""
    for k in range(n):
        b = k * _PATCH
        if boxes[b + _I0] <= i < boxes[b + _I1] and boxes[b + _J0] <= j < boxes[b + _J1]:
            return True
    return False


@njit(cache=True, inline="always")
def _contact(dents, k):
    """Contact k of the recorded dents: (offset of its record, tip radius R, contact radius a >= 0);
    R <= 0 is no dent."""
    b = k * DENT_SIZE
    return b, dents[b + D_RADIUS], max(dents[b + D_A], 0.0)


@njit(cache=True)
def _dent_rows(ctrl, rest, i0, i1, j0, j1, dents, n_dents, profiles, n_prof, scales, boxes, skip, patch, axes):
    """Write control points [i0, i1) x [j0, j1) under the recorded dents (the module docstring's
    rule; several contacts of one tip superpose their elastic surfaces); returns how many are
    dented. A point in one of the dents' index ``boxes`` is dented, or put back to rest if the
    dent leaves it there and a previous box (``patch``) held it; a point outside every box goes
    back to rest if a previous box held it; points in the first ``skip`` boxes are left alone
    (written with an earlier box). ``axes`` is (n_dents, 7) scratch: the point about each
    contact's axis, P₀ - C, its radial part and ρ², found once.

    The rule is written in the loop, not in a function called per point: numba's per-point
    call (inlined or not) cost 2.2x the whole rule (60 vs 27 ns a point, thread CPU time,
    bench/deformation.py --read and the same-run A/B in docs/performance.rst)."""
    moved = 0
    for i in range(i0, i1):
        for j in range(j0, j1):
            if _in_boxes(boxes, skip, i, j):
                continue   # written with an earlier box
            old = _in_boxes(patch, n_dents, i, j)
            if not _in_boxes(boxes, n_dents, i, j):
                if old:
                    for c in range(3):
                        ctrl[i, j, c] = rest[i, j, c]
                continue
            # 1. inside a contact disc: on the tip's cap (or the contact's paraboloid beyond SPHERE_LIMIT)
            on_cap = False
            for k in range(n_dents):
                b, radius, a = _contact(dents, k)
                if radius <= 0.0:
                    continue
                px = rest[i, j, 0] - dents[b + D_CX]
                py = rest[i, j, 1] - dents[b + D_CY]
                pz = rest[i, j, 2] - dents[b + D_CZ]
                nx, ny, nz = dents[b + D_NX], dents[b + D_NY], dents[b + D_NZ]
                s = px * nx + py * ny + pz * nz
                rx = px - s * nx
                ry = py - s * ny
                rz = pz - s * nz
                rho2 = rx * rx + ry * ry + rz * rz
                axes[k, 0], axes[k, 1], axes[k, 2], axes[k, 3] = px, py, pz, rx
                axes[k, 4], axes[k, 5], axes[k, 6] = ry, rz, rho2
                if rho2 < a * a:
                    if a <= SPHERE_LIMIT * radius:
                        cap = -math.sqrt(radius * radius - rho2)
                        ctrl[i, j, 0] = dents[b + D_CX] + rx + cap * nx
                        ctrl[i, j, 1] = dents[b + D_CY] + ry + cap * ny
                        ctrl[i, j, 2] = dents[b + D_CZ] + rz + cap * nz
                    else:
                        u = dents[b + D_DEPTH] - 0.5 * rho2 / radius
                        ctrl[i, j, 0] = rest[i, j, 0] - u * nx
                        ctrl[i, j, 1] = rest[i, j, 1] - u * ny
                        ctrl[i, j, 2] = rest[i, j, 2] - u * nz
                    on_cap = True
                    break
            if on_cap:
                moved += 1
                continue
            # 2. the elastic surfaces outside the contacts, superposed (linear elasticity)
            qx = rest[i, j, 0]
            qy = rest[i, j, 1]
            qz = rest[i, j, 2]
            near = False
            for k in range(n_dents):
                b, radius, a = _contact(dents, k)
                if radius <= 0.0:
                    continue
                r_elastic = PATCH_PER_CONTACT * a
                r_box = max(radius, r_elastic)
                px, py, pz, rho2 = axes[k, 0], axes[k, 1], axes[k, 2], axes[k, 6]
                if rho2 >= r_box * r_box or (rho2 >= r_elastic * r_elastic
                                             and px * px + py * py + pz * pz >= radius * radius):
                    continue  # beyond this dent's elastic surface and outside its tip
                near = True
                if rho2 < r_elastic * r_elastic:
                    x = math.sqrt(rho2 - a * a) * scales[k]
                    m = int(x)
                    if m >= n_prof - 1:
                        m = n_prof - 2
                    f = x - m
                    p0 = k * n_prof + m
                    u = profiles[p0] + f * (profiles[p0 + 1] - profiles[p0])
                    qx -= u * dents[b + D_NX]
                    qy -= u * dents[b + D_NY]
                    qz -= u * dents[b + D_NZ]
            if not near:  # at rest, bitwise
                if old:
                    for c in range(3):
                        ctrl[i, j, c] = rest[i, j, c]
                continue
            # 3. still inside the tip: onto the sphere
            for k in range(n_dents):
                b, radius, a = _contact(dents, k)
                if radius <= 0.0:
                    continue
                r2 = radius * radius
                rx, ry, rz, rho2 = axes[k, 3], axes[k, 4], axes[k, 5], axes[k, 6]
                if rho2 < r2:
                    cx, cy, cz = dents[b + D_CX], dents[b + D_CY], dents[b + D_CZ]
                    dx = qx - cx
                    dy = qy - cy
                    dz = qz - cz
                    if dx * dx + dy * dy + dz * dz < r2:
                        cap = -math.sqrt(r2 - rho2)
                        qx = cx + rx + cap * dents[b + D_NX]
                        qy = cy + ry + cap * dents[b + D_NY]
                        qz = cz + rz + cap * dents[b + D_NZ]
                        break
            ctrl[i, j, 0] = qx
            ctrl[i, j, 1] = qy
            ctrl[i, j, 2] = qz
            moved += 1
    return moved


@njit(cache=True)
def _dent_boxes(nu, nv, ku, kv, dent, profile):
    """The index boxes (n × :data:`DENT_PATCH`) of the recorded dents, each contact's profile
    filled into ``profile`` and its scale (profile index per sqrt(ρ² - a²)) returned beside."""
    n_dents = dent.size // DENT_SIZE
    n_prof = profile.size // n_dents
    boxes = np.zeros(n_dents * _PATCH, dtype=np.int64)
    scales = np.zeros(n_dents)
    for k in range(n_dents):
        b, radius, a = _contact(dent, k)
        q = k * _PATCH
        i0, i1, j0, j1 = _dent_box(nu, nv, ku, kv, dent[b + D_CX], dent[b + D_CY], radius, dent[b + D_A])
        boxes[q + _I0] = i0
        boxes[q + _I1] = i1
        boxes[q + _J0] = j0
        boxes[q + _J1] = j1
        if i0 < i1 and a > 0.0:
            r_elastic = PATCH_PER_CONTACT * a   # the elastic surface, faded over its outer half
            _fill_profile(profile[k * n_prof:(k + 1) * n_prof], a, radius, dent[b + D_DEPTH], dent[b + D_ZONE],
                          r_elastic)
            scales[k] = (n_prof - 1) / math.sqrt(r_elastic * r_elastic - a * a)
    return boxes, scales


@njit(cache=True, nogil=True)
def sync_dent_kernel(ctrl, rest, ku, kv, dent, profile, patch):
    """Move the net from the dents in ``patch`` to the dents recorded in ``dent``; write their
    index boxes to ``patch``. The full dent (the module docstring's rule), exact: the reference
    of :func:`sync_dent_tiled_kernel`, which gives the same net doing only the tiles a dent reaches.

    ``dent`` holds one :data:`DENT` record per contact (n × :data:`DENT_SIZE` floats; a record
    with R <= 0 is no dent), ``patch`` their index boxes (n × :data:`DENT_PATCH` int64),
    ``profile`` n × :data:`PROFILE_SIZE` floats of scratch. The contacts of one tip superpose
    their elastic surfaces (linear elasticity); a point inside a contact disc lies on the tip;
    one contact is :func:`deform_kernel`'s dent, bit for bit.

    Incremental: the points of the previous boxes outside every new one go back to rest; inside
    the new boxes every point is written once (dented, or back to rest if a previous box held
    it). Cost O(points in the boxes × n), whatever the net's size. Runs without the GIL: the
    tick (which never reads the live net) goes on while a reader in another thread syncs.
    Returns the number of control points dented (>= 0).
    """
    n_dents = dent.size // DENT_SIZE
    n_prof = profile.size // n_dents
    boxes, scales = _dent_boxes(ctrl.shape[0], ctrl.shape[1], ku, kv, dent, profile)
    axes = np.empty((n_dents, 7))
    # 1. the previous boxes outside every new one back to rest
    for k in range(n_dents):
        q = k * _PATCH
        for i in range(patch[q + _I0], patch[q + _I1]):
            for j in range(patch[q + _J0], patch[q + _J1]):
                if not _in_boxes(boxes, n_dents, i, j):
                    for c in range(3):
                        ctrl[i, j, c] = rest[i, j, c]
    # 2. the new boxes, each point once
    moved = 0
    for k in range(n_dents):
        q = k * _PATCH
        moved += _dent_rows(ctrl, rest, boxes[q + _I0], boxes[q + _I1], boxes[q + _J0], boxes[q + _J1], dent, n_dents,
                            profile, n_prof, scales, boxes, k, patch, axes)
    for k in range(boxes.size):
        patch[k] = boxes[k]
    return moved


#: control points per side of the tiles :func:`sync_dent_tiled_kernel` culls by
TILE = 8
#: the tiles' bounding spheres are widened by this fraction (and TILE_SLACK_M) against rounding
TILE_SLACK = 1e-6
TILE_SLACK_M = 1e-15


@njit(cache=True, nogil=True)
def tile_heights_kernel(rest, zlo, zhi):
    """Lowest and highest rest height (m) of each :data:`TILE` × :data:`TILE` tile of the net,
    into ``zlo``, ``zhi`` (ceil(nu / TILE), ceil(nv / TILE)): once per deformer, O(N)."""
    nu, nv = rest.shape[0], rest.shape[1]
    for ti in range(zlo.shape[0]):
        for tj in range(zlo.shape[1]):
            lo = np.inf
            hi = -np.inf
            for i in range(ti * TILE, min((ti + 1) * TILE, nu)):
                for j in range(tj * TILE, min((tj + 1) * TILE, nv)):
                    z = rest[i, j, 2]
                    lo = min(lo, z)
                    hi = max(hi, z)
            zlo[ti, tj] = lo
            zhi[ti, tj] = hi


@njit(cache=True, inline="always")
def _tile_reached(rest, zlo, zhi, ti, tj, dents, n_dents):
    """True if a dent of ``dents`` may move a rest point of tile (ti, tj): the bounding sphere of
    the tile's rest points meets a contact's elastic cylinder (ρ < 3a about its axis: the
    contact disc and the elastic surface) or its tip ball (the module docstring's rule moves no
    point outside both). Conservative: a tile reached may still hold no moved point."""
    nu, nv = rest.shape[0], rest.shape[1]
    i0 = ti * TILE
    i1 = min(i0 + TILE, nu) - 1
    j0 = tj * TILE
    j1 = min(j0 + TILE, nv) - 1
    x0, x1 = rest[i0, j0, 0], rest[i1, j0, 0]   # a height-field net: x on i only, y on j only
    y0, y1 = rest[i0, j0, 1], rest[i0, j1, 1]
    z0, z1 = zlo[ti, tj], zhi[ti, tj]
    qx, qy, qz = 0.5 * (x0 + x1), 0.5 * (y0 + y1), 0.5 * (z0 + z1)
    rt = 0.5 * math.sqrt((x1 - x0) ** 2 + (y1 - y0) ** 2 + (z1 - z0) ** 2) * (1.0 + TILE_SLACK) + TILE_SLACK_M
    for k in range(n_dents):
        b, radius, a = _contact(dents, k)
        if radius <= 0.0:
            continue
        px = qx - dents[b + D_CX]
        py = qy - dents[b + D_CY]
        pz = qz - dents[b + D_CZ]
        d2 = px * px + py * py + pz * pz
        if d2 < (radius + rt) * (radius + rt):
            return True   # the tip ball
        if a > 0.0:
            s = px * dents[b + D_NX] + py * dents[b + D_NY] + pz * dents[b + D_NZ]
            r_cyl = PATCH_PER_CONTACT * a + rt
            if d2 - s * s < r_cyl * r_cyl:
                return True   # the elastic cylinder (the distance to a line is 1-Lipschitz)
    return False


@njit(cache=True, inline="always")
def _tile_done(boxes, n, ti, tj):
    """True if tile (ti, tj) meets one of the first ``n`` boxes (it was done with that box)."""
    for k in range(n):
        b = k * _PATCH
        if (boxes[b + _I0] < (ti + 1) * TILE and boxes[b + _I1] > ti * TILE
                and boxes[b + _J0] < (tj + 1) * TILE and boxes[b + _J1] > tj * TILE):
            return True
    return False


@njit(cache=True, nogil=True)
def sync_dent_tiled_kernel(ctrl, rest, ku, kv, dent, shown, profile, patch, zlo, zhi, written):
    """:func:`sync_dent_kernel`'s net, bit for bit, visiting point by point only the tiles a dent reaches.

    The boxes are cut into :data:`TILE` × :data:`TILE` tiles of control points. A tile that no
    recorded dent reaches (:func:`_tile_reached`: its bounding sphere, from the rest heights
    ``zlo``/``zhi`` of :func:`tile_heights_kernel`, misses every contact's elastic cylinder
    and tip ball) holds only points the full dent leaves at rest: it is skipped, or copied
    back to rest when the dents the net shows (``shown``, with their boxes in ``patch``)
    reached it. Every other tile of the boxes is written point by point, as the reference
    does. So the cost is that of the points the dents move (the contact's elastic surface,
    ~(6a/h)², and the rough patches inside the tip), not of the guard box (2 max(R, 3a)/h)².
    ``written`` (2n × :data:`DENT_PATCH` int64, old boxes then new) receives, per box, the
    index box of the tiles written (empty: i0 = i1 = 0). Returns the points dented (the
    reference's count).
    """
    nu = ctrl.shape[0]
    nv = ctrl.shape[1]
    n_dents = dent.size // DENT_SIZE
    n_prof = profile.size // n_dents
    boxes, scales = _dent_boxes(nu, nv, ku, kv, dent, profile)
    axes = np.empty((n_dents, 7))
    both = np.concatenate((patch, boxes))   # the old boxes, then the new: a tile is done with the first it meets
    written[:] = 0
    moved = 0
    for q in range(2 * n_dents):
        b = q * _PATCH
        if both[b + _I0] >= both[b + _I1] or both[b + _J0] >= both[b + _J1]:
            continue
        w0, w1, v0, v1 = nu, 0, nv, 0
        for ti in range(both[b + _I0] // TILE, (both[b + _I1] - 1) // TILE + 1):
            for tj in range(both[b + _J0] // TILE, (both[b + _J1] - 1) // TILE + 1):
                if _tile_done(both, q, ti, tj):
                    continue
                i0 = ti * TILE
                i1 = min(i0 + TILE, nu)
                j0 = tj * TILE
                j1 = min(j0 + TILE, nv)
                if _tile_reached(rest, zlo, zhi, ti, tj, dent, n_dents):   # as the reference
                    moved += _dent_rows(ctrl, rest, i0, i1, j0, j1, dent, n_dents, profile, n_prof, scales, boxes, 0,
                                        patch, axes)
                elif _tile_reached(rest, zlo, zhi, ti, tj, shown, n_dents):
                    for i in range(i0, i1):   # no new dent here: the old boxes' points back to rest
                        for j in range(j0, j1):
                            if _in_boxes(patch, n_dents, i, j):
                                for c in range(3):
                                    ctrl[i, j, c] = rest[i, j, c]
                else:
                    continue   # at rest before and after
                w0, w1, v0, v1 = min(w0, i0), max(w1, i1), min(v0, j0), max(v1, j1)
        if w0 < w1:
            written[b + _I0], written[b + _I1], written[b + _J0], written[b + _J1] = w0, w1, v0, v1
    for k in range(boxes.size):
        patch[k] = boxes[k]
    return moved


@njit(cache=True)
def deform_kernel(ctrl, rest, ku, kv, cx, cy, cz, radius, nx, ny, nz, contact_radius, depth, zone_radius,
                  profile, patch):
    """Move the net from the dent in ``patch`` (i0, i1, j0, j1) to the dent of this tip; write
    its index box to ``patch``: :func:`sync_dent_kernel` for one contact given by its numbers.

    ``depth`` δ and ``zone_radius`` c (m) shape the elastic surface outside the contact
    (:func:`elastic_displacement`; Hertz: δ = a²/R, c = a); ``profile`` is a scratch array of
    :data:`PROFILE_SIZE` floats. Returns the number of control points dented (>= 0).
    ``contact_radius`` <= 0 only pushes points out of the sphere (no contact zone, no elastic
    surface); a ``radius`` <= 0 releases.
    """
    dent = np.zeros(DENT_SIZE)
    record_dent_kernel(dent, ku, kv, cx, cy, cz, radius, nx, ny, nz, contact_radius, depth, zone_radius)
    return sync_dent_kernel(ctrl, rest, ku, kv, dent, profile, patch)


@njit(cache=True)
def record_dent_kernel(dent, ku, kv, cx, cy, cz, radius, nx, ny, nz, contact_radius, depth, zone_radius):
    """Record the dent of this tip in ``dent`` (:data:`DENT_SIZE`,) for :meth:`Deformer.sync`, O(1).

    The arguments are those of :func:`deform_kernel` (``radius`` <= 0: no dent). The sequence
    number ``dent[D_SEQ]`` grows by one per record. Returns the number of control points in
    the dent's index box (those the dent may move; 0 without a dent): the tick's ``moved``.
    A model with several contacts records contact k in ``record[k * DENT_SIZE:]``."""
    dent[D_CX] = cx
    dent[D_CY] = cy
    dent[D_CZ] = cz
    dent[D_RADIUS] = radius
    dent[D_NX] = nx
    dent[D_NY] = ny
    dent[D_NZ] = nz
    dent[D_A] = contact_radius
    dent[D_DEPTH] = depth
    dent[D_ZONE] = zone_radius
    dent[D_SEQ] += 1.0
    i0, i1, j0, j1 = _dent_box(ku.size - 4, kv.size - 4, ku, kv, cx, cy, radius, contact_radius)
    return (i1 - i0) * (j1 - j0)


@dataclass(frozen=True)
class DeformationResult:
    """What one :meth:`Deformer.apply` did: points moved and the index box touched."""

    moved: int
    patch: tuple[int, int, int, int]


class Deformer:
    """Dents a surface's control net around the tip, one or several contacts, reversibly.

    :meth:`apply` dents the net at once. The compiled tick only *records* its dent in
    :attr:`dent` (:func:`record_dent_kernel`, O(1) whatever the pitch); the net is moved to the
    recorded dent when it is next read (:meth:`sync`, which the surface calls from
    :meth:`~arsurf.spline.surface.BSplineSurface.sync` before anything reads it), so a reader
    always sees exactly the full dent of the last tick (:func:`sync_dent_kernel`), and the tick
    does not pay for control points nobody looks at. A tip touching at several points records
    one dent per contact (``contacts`` > 1; contact k at ``record[at + k * DENT_SIZE:]``): one
    sync writes them all, superposed, in O(their boxes).

    Parameters
    ----------
    surface : BSplineSurface
        Its rest net must be a height-field net (as :func:`arsurf.fit_surface` makes).
    record : float64 array, optional
        The vector the tick records its dents in (the model's contact vector), ``contacts`` ×
        :data:`DENT_SIZE` floats from offset ``at``; default a vector of its own. (Kept as the
        vector and an offset, not a view, so that a deep copy of a model stays connected.)
    at : int
        Offset of the first contact's dent in ``record``.
    contacts : int
        How many contacts can dent at once (default 1).

    Examples
    --------
    >>> import numpy as np
    >>> from arsurf.spline.surface import BSplineSurface
    >>> s = BSplineSurface.from_heights(np.zeros((20, 20)), (0, 17e-9), (0, 17e-9))
    >>> d = Deformer(s)
    >>> d.apply(center=(8e-9, 8e-9, 4e-9), radius=5e-9, normal=(0, 0, 1), contact_radius=3e-9).moved > 0
    True
    >>> d.release(); s.is_deformed
    False
    """

    def __init__(self, surface: BSplineSurface, record: np.ndarray | None = None, at: int = 0, contacts: int = 1):
        if not isinstance(surface, BSplineSurface):
            raise ContactError(f"Deformer needs a BSplineSurface (got {type(surface).__name__})")
        if not surface.is_height_field_net:
            raise ContactError(
                "the surface's rest net is not a height-field net (x must depend on i only and y on j only); "
                "build it with arsurf.fit_surface or BSplineSurface.from_heights"
            )
        if isinstance(contacts, bool) or not isinstance(contacts, (int, np.integer)) or contacts < 1:
            raise ContactError(f"`contacts` must be an integer >= 1 (got {contacts!r}); it is how many contacts dent")
        self.surface = surface
        self.contacts = int(contacts)
        self.patch = np.zeros(_PATCH * self.contacts, dtype=np.int64)
        self.profile = np.zeros(PROFILE_SIZE * self.contacts)
        size = DENT_SIZE * self.contacts
        self._record = np.zeros(size) if record is None else record
        self._at = int(at)
        if self._record.ndim != 1 or self._record.dtype != np.float64 or not 0 <= self._at <= self._record.size - size:
            raise ContactError(f"`record` must be a float64 vector holding {size} floats from offset {at} "
                               f"(got {self._record.dtype} {self._record.shape})")
        self._applied = self._seqs.copy()  # the recorded dents the net shows ...
        self.shown = np.zeros(size)        # ... their numbers (no dent yet)
        self.written = np.zeros(2 * _PATCH * self.contacts, dtype=np.int64)  # what the last sync wrote
        self._tiles = None                 # the rest net's tile heights, at the first sync
        self._lock = threading.Lock()      # one sync at a time (the kernel runs without the GIL)
        surface.attach_dent(self)

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        del state["_lock"]
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._lock = threading.Lock()

    def apply(self, center, radius: float, normal, contact_radius: float, *, depth: float | None = None,
              zone_radius: float | None = None, contact: int = 0) -> DeformationResult:
        """Press the tip sphere (centre, radius) into the net as contact ``contact`` (replacing
        that contact's previous dent; the other contacts' stay).

        Parameters
        ----------
        center : (3,) float, metres
        radius : float, metres (> 0)
        normal : (3,) float, unit contact normal out of the sample
        contact_radius : float, metres (>= 0; 0 = no contact zone: only points inside the sphere move)
        depth : float, metres, optional
            Indentation δ of the contact (default a²/R: Hertz).
        zone_radius : float, metres, optional
            Outer radius c >= a of the Dugdale zone (default a: no adhesive zone).
        contact : int
            Which of the ``contacts`` dents this is (default 0).
        """
        c = np.asarray(center, dtype=np.float64).reshape(3)
        n = np.asarray(normal, dtype=np.float64).reshape(3)
        radius = float(radius)
        contact_radius = float(contact_radius)
        if not np.isfinite(c).all():
            raise ContactError(f"`center` must be finite (got {c}); it is the tip centre in metres")
        if not (math.isfinite(radius) and radius > 0.0):
            raise ContactError(f"`radius` must be positive (got {radius!r} m); it is the tip radius in metres")
        if not (math.isfinite(contact_radius) and contact_radius >= 0.0):
            raise ContactError(f"`contact_radius` must be >= 0 (got {contact_radius!r} m)")
        depth = contact_radius ** 2 / radius if depth is None else float(depth)
        zone_radius = contact_radius if zone_radius is None else float(zone_radius)
        if not math.isfinite(depth):
            raise ContactError(f"`depth` must be finite (got {depth!r} m); it is the indentation of the contact")
        if not (math.isfinite(zone_radius) and zone_radius >= contact_radius):
            raise ContactError(f"`zone_radius` must be >= contact_radius ({contact_radius!r} m) (got {zone_radius!r} m); "
                               "it is the outer radius of the Dugdale zone")
        norm = float(np.linalg.norm(n))
        if not (math.isfinite(norm) and abs(norm - 1.0) < 1e-6):
            raise ContactError(f"`normal` must be a unit vector (got {n}, |n| = {norm:.6g})")
        k = self._contact_index(contact)
        _, _, ku, kv = self.surface.raw_arrays()
        record_dent_kernel(self.slot(k), ku, kv, c[0], c[1], c[2], radius, n[0], n[1], n[2], contact_radius, depth,
                           zone_radius)
        moved = self.sync()
        return DeformationResult(int(moved), tuple(int(p) for p in self.patch[k * _PATCH:(k + 1) * _PATCH]))

    def release(self, contact: int | None = None) -> None:
        """Put the dented points back to their rest positions (bitwise): every contact's, or
        only contact ``contact``'s."""
        _, _, ku, kv = self.surface.raw_arrays()
        for k in range(self.contacts) if contact is None else (self._contact_index(contact),):
            record_dent_kernel(self.slot(k), ku, kv, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)
        self.sync()

    def _contact_index(self, contact) -> int:
        if isinstance(contact, bool) or not isinstance(contact, (int, np.integer)) or not 0 <= contact < self.contacts:
            raise ContactError(f"`contact` must be an integer in [0, {self.contacts}) (got {contact!r}): "
                               f"this deformer dents {self.contacts} contact(s)")
        return int(contact)

    @property
    def dent(self) -> np.ndarray:
        """The recorded dents (``contacts`` × :data:`DENT_SIZE`,): a view into the record vector."""
        return self._record[self._at:self._at + DENT_SIZE * self.contacts]

    def slot(self, contact: int) -> np.ndarray:
        """The recorded dent of contact ``contact`` (:data:`DENT_SIZE`,): a view into the record vector."""
        b = self._at + DENT_SIZE * contact
        return self._record[b:b + DENT_SIZE]

    @property
    def _seqs(self) -> np.ndarray:
        """The contacts' sequence numbers (a strided view)."""
        return self._record[self._at + D_SEQ:self._at + DENT_SIZE * self.contacts:DENT_SIZE]

    @property
    def pending(self) -> bool:
        """True when a dent was recorded that the net does not show yet."""
        return not np.array_equal(self._seqs, self._applied)

    def sync(self) -> int:
        """Move the net to the last recorded dents (nothing if it shows them already), O(dent
        boxes); returns the number of control points dented (-1: nothing to do). The dents are
        copied while the GIL is held (the compiled tick, which records them, holds it), then
        the net is written without the GIL, so the haptic thread ticks on meanwhile. Tells the
        projection's hull boxes and the surface's watchers which index boxes changed."""
        with self._lock:
            seqs = self._seqs.copy()
            if np.array_equal(seqs, self._applied):
                return -1
            dents = self.dent.copy()
            ctrl, rest, ku, kv = self.surface.raw_arrays()
            if self._tiles is None:
                shape = (-(-rest.shape[0] // TILE), -(-rest.shape[1] // TILE))
                self._tiles = (np.empty(shape), np.empty(shape))
                tile_heights_kernel(rest, *self._tiles)
            moved = sync_dent_tiled_kernel(ctrl, rest, ku, kv, dents, self.shown, self.profile, self.patch,
                                           *self._tiles, self.written)
            self.shown[:] = dents
            self._applied = seqs
            self._refresh()
        return moved

    def forget(self) -> None:
        """The net was put back to rest by someone else (``surface.reset()``): no dent is shown."""
        self.patch[:] = 0
        self.shown[:] = 0.0
        self._applied = self._seqs.copy()

    def _refresh(self) -> None:
        """Tell the projection's hull boxes and the surface's watchers which index boxes the last
        sync wrote (:attr:`written`), O(those boxes)."""
        from arsurf.contact.projection import refresh_region

        for box in self.written.reshape(-1, _PATCH):
            if box[_I1] > box[_I0] and box[_J1] > box[_J0]:
                i0, i1, j0, j1 = int(box[_I0]), int(box[_I1]), int(box[_J0]), int(box[_J1])
                refresh_region(self.surface, i0, i1, j0, j1)
                self.surface.touched(i0, i1, j0, j1)
