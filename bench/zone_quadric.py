"""Benchmark (accuracy, a next step measured outside the engine): the zone law in closed form over
the quadratic gap about its minimum, against the lattice's sum.

The energy of the whole tip (:mod:`arsurf.contact.zone_energy`) sums its law over ~1000 lattice
samples under a contact 1-3 nm deep, whatever the surface. Where the surface is smooth at the
scale of the contact (a scan whose pixels are wider than the contact) the gap about its minimum
:math:`g_0` (at :math:`x^*`) is nearly quadratic, :math:`g \\approx g_0 + \\tfrac12 (x - x^*)^T M
(x - x^*)`, M the Hessian of the vertical gap there (the sphere's plus the surface's curvature), and
the area within a gap g grows linearly, :math:`dA = 2\\pi\\,dg/\\sqrt{\\det M}`; with the sphere's
own shape kept to the next order (over a flat the area within s = g - g0 of the minimum is
:math:`\\pi(2Rs - s^2)`, so :math:`dA/dg = 2\\pi R(1 - s/R)`):

.. math::

    E \\approx \\frac{2\\pi}{\\sqrt{\\det M}} \\int_{g_0}^{h_0} \\varphi(g)
    \\left(1 - \\frac{g - g_0}{R}\\right) dg ,

one term instead of a lattice. Here, at tips of ``bench/feel.py``'s 100 nm/s slide on real scans
(the demo preset, the zone energy as the contact, recorded from the loop): E and F from that
formula (the minimum by Nelder-Mead on the spline's height, M by finite differences, F = -grad E by
central differences) against the lattice's :func:`~arsurf.contact.zone_energy.zone_energy` (whose
own error on a flat is 0.8-1.7 %, ``bench/zone_quadrature.py``), with the paraboloid's area alone
(without the factor) beside it, on the scans whose zone-energy tick is over 3x one VTK query and
on ``sample_0.spm``; a scan rough under the tip shows where the lattice stays needed. And what
one term costs, compiled (the minimum by Newton's method on the spline's second derivatives, the
weighted integral in closed form: :func:`one_term_energy`), against one sum of the lattice
(without its Hessian) at the same tips, each in a compiled loop, the rounds alternated.

Run: .venv/bin/python bench/zone_quadric.py [--scans NAME ...] [--points 20] (prints JSON, one
line per scan; Python evaluations, a few seconds a scan)
"""
from __future__ import annotations

import argparse
import json
import math
import os
import time
from pathlib import Path

import numpy as np
from numba import njit
from scipy.integrate import quad
from scipy.optimize import minimize

from arsurf.assembly import PRESETS
from arsurf.contact.maugis_dugdale import MaugisDugdale
from arsurf.contact.zone_energy import ZONE_OUT, ZoneLaw, lattice_for, zone_energy, zone_energy_kernel, zone_law_kernel
from arsurf.feel_scenarios import prepared_surface, run_scenario
from arsurf.spline.basis import surface_point

SCANS = Path(os.environ.get("ARSURF_REAL_SCANS", Path(__file__).resolve().parents[2] / "shared" / "scans-real"))
DEFAULT_SCANS = ("2018-02-09_1506_PH_dt20nmwindow1_Z_C.gsf", "AR_20211011.ibw", "Park_20210916_034.tiff",
                 "2022-04-28_1518_PH_trivial_dose1,1_FB_horizontal_interf_synchronize_nanoFTIR_Z.gsf",
                 "2024-08-21_132732_PH_pmma_wedge_on_gold_thick_1600nm_Z_raw.gsf",
                 "2024-10-24_104052_PH_wg_wv_No3_15slits_pol45deg_anal90deg_fine.gwy", "Veeco_20160622.003",
                 "sample_0.spm")
#: the finite-difference steps (m) of M and of F
CURVATURE_STEP, FORCE_STEP = 0.05e-9, 2e-12


def quadric_energy(surface, law: ZoneLaw, tip, sphere: bool = True) -> float:
    """E (J) of the module docstring's formula at the tip centre ``tip`` (m); ``sphere`` False: the
    paraboloid's area alone."""
    radius, h0 = law.tip_radius, law.interaction_range
    (u0, u1), (v0, v1) = surface.domain
    corner = surface.evaluate(np.array([u0, u1]), np.array([v0, v1]))  # a height-field net: x affine in u, y in v
    sx, sy = (corner[1, 0] - corner[0, 0]) / (u1 - u0), (corner[1, 1] - corner[0, 1]) / (v1 - v0)

    def gap(xy):
        u = np.array([u0 + (xy[0] - corner[0, 0]) / sx])
        v = np.array([v0 + (xy[1] - corner[0, 1]) / sy])
        r = math.hypot(xy[0] - tip[0], xy[1] - tip[1])
        return tip[2] - radius + radius - math.sqrt(max(radius * radius - r * r, 0.0)) - float(
            surface.evaluate(u, v)[..., 2].ravel()[0])

    x = minimize(gap, np.asarray(tip[:2], float), method="Nelder-Mead",
                 options={"xatol": 1e-14, "fatol": 1e-16, "maxiter": 4000}).x
    g0 = gap(x)
    if g0 >= h0:
        return 0.0
    d, e = CURVATURE_STEP, np.eye(2) * CURVATURE_STEP
    m = np.array([[(gap(x + e[i] + e[j]) - gap(x + e[i] - e[j]) - gap(x - e[i] + e[j]) + gap(x - e[i] - e[j]))
                   / (4 * d * d) for j in range(2)] for i in range(2)])

    def integrand(g):
        return zone_law_kernel(g, *law.args)[0] * ((1.0 - (g - g0) / radius) if sphere else 1.0)

    return 2.0 * math.pi * quad(integrand, g0, h0, points=[0.0] if g0 < 0.0 else None, limit=200)[0] \
        / math.sqrt(np.linalg.det(m))


@njit  # not cached: a bench's cached function breaks its own run as a script (docs/benchmarks.rst)
def _weighted_law_integral(g0, radius, e_star, sigma0, h0):
    r""":math:`\int_{g_0}^{h_0} \varphi(g)\,(1 - (g - g_0)/R)\,dg` in closed form (the module docstring's
    law: :math:`\varphi = \tfrac23 k(-g)^{3/2} - w` below 0, :math:`k = E^*/\pi\sqrt R`;
    :math:`-\sigma_0(h_0 - g) - \sigma_0 h_0 \sin(2\pi g/h_0)/2\pi` on (0, h0)), as
    :math:`c_0 \int\varphi - \int g\varphi/R` with :math:`c_0 = 1 + g_0/R`."""
    stiff, w = e_star / (math.pi * math.sqrt(radius)), sigma0 * h0
    c0 = 1.0 + g0 / radius
    total = 0.0
    if g0 < 0.0:  # over [g0, 0], t = -g in [0, d]
        d = -g0
        i0 = 2.0 / 3.0 * stiff * 0.4 * d ** 2.5 - w * d  # int phi dg
        i1 = -(2.0 / 3.0 * stiff * d ** 3.5 / 3.5) + w * d * d / 2.0  # int g phi dg
        total += c0 * i0 - i1 / radius
    a = max(g0, 0.0)
    if a < h0:  # over [a, h0]: phi = -sigma0 (h0 - g) - sigma0 h0 sin(q g) / (2 pi), q = 2 pi / h0
        q = 2.0 * math.pi / h0
        i0 = -sigma0 * (h0 - a) ** 2 / 2.0 + sigma0 * h0 / (2.0 * math.pi) * (math.cos(q * h0) - math.cos(q * a)) / q
        lin = -sigma0 * (h0 * (h0 * h0 - a * a) / 2.0 - (h0 ** 3 - a ** 3) / 3.0)  # int -sigma0 (h0 - g) g dg
        # int g sin(q g) dg = sin(q g)/q^2 - g cos(q g)/q
        gs = (math.sin(q * h0) / q ** 2 - h0 * math.cos(q * h0) / q) - (math.sin(q * a) / q ** 2 - a * math.cos(q * a) / q)
        i1 = lin - sigma0 * h0 / (2.0 * math.pi) * gs
        total += c0 * i0 - i1 / radius
    return total


@njit  # not cached (above)
def one_term_energy(ctrl, ku, kv, u, v, tx, ty, tz, radius, e_star, sigma0, h0, ev):
    """E (J) of the module docstring's formula, compiled: the gap's minimum by Newton's method on
    the spline's height (from the net's point (``u``, ``v``) under the tip; ``ev`` (6, 3) scratch),
    M from the sphere's and the surface's second derivatives there, and the law's weighted integral
    in closed form. A height-field net: x depends on u only, y on v only."""
    g0, det = 0.0, 0.0
    for _ in range(20):
        surface_point(ctrl, ku, kv, u, v, 2, ev)
        xu, yv = ev[1, 0], ev[2, 1]
        zx, zy = ev[1, 2] / xu, ev[2, 2] / yv
        zxx = (ev[3, 2] - zx * ev[3, 0]) / (xu * xu)
        zxy = ev[4, 2] / (xu * yv)
        zyy = (ev[5, 2] - zy * ev[5, 1]) / (yv * yv)
        dx, dy = ev[0, 0] - tx, ev[0, 1] - ty
        root = math.sqrt(radius * radius - dx * dx - dy * dy)
        g0 = tz - root - ev[0, 2]
        gx, gy = dx / root - zx, dy / root - zy
        i3 = 1.0 / (root * root * root)
        mxx, mxy, myy = 1.0 / root + dx * dx * i3 - zxx, dx * dy * i3 - zxy, 1.0 / root + dy * dy * i3 - zyy
        det = mxx * myy - mxy * mxy
        sx, sy = -(myy * gx - mxy * gy) / det, -(mxx * gy - mxy * gx) / det
        u += sx / xu
        v += sy / yv
        if sx * sx + sy * sy < 1e-18 * radius * radius:  # 1e-9 R: g0 to 1e-18 R
            break
    if g0 >= h0 or not det > 0.0:
        return 0.0
    return 2.0 * math.pi * _weighted_law_integral(g0, radius, e_star, sigma0, h0) / math.sqrt(det)


@njit  # not cached (above)
def _one_terms(ctrl, ku, kv, us, vs, tips, radius, e_star, sigma0, h0, ev, energies):
    for k in range(tips.shape[0]):
        energies[k] = one_term_energy(ctrl, ku, kv, us[k], vs[k], tips[k, 0], tips[k, 1], tips[k, 2], radius, e_star,
                                      sigma0, h0, ev)


@njit  # not cached (above)
def _lattice_sums(lat, tips, radius, e_star, sigma0, h0, out, empty, energies):
    for k in range(tips.shape[0]):
        zone_energy_kernel(lat, tips[k, 0], tips[k, 1], tips[k, 2], radius, e_star, sigma0, h0, out, empty)
        energies[k] = out[0]


def time_against_the_lattice(surface, law: ZoneLaw, lattice, tips, rounds: int = 7) -> dict:
    """Time (us) of one compiled one-term energy and of one lattice sum (no Hessian) at the same
    ``tips``, each over all of them in a compiled loop, the rounds alternated (the median round),
    and the two energies' largest difference."""
    ctrl = np.array(surface.rest_control_points, order="C")
    ku, kv = surface.knots_u, surface.knots_v
    (u0, u1), (v0, v1) = surface.domain
    corner = surface.evaluate(np.array([u0, u1]), np.array([v0, v1]))
    tips = np.ascontiguousarray(tips)
    us = u0 + (tips[:, 0] - corner[0, 0]) * (u1 - u0) / (corner[1, 0] - corner[0, 0])
    vs = v0 + (tips[:, 1] - corner[0, 1]) * (v1 - v0) / (corner[1, 1] - corner[0, 1])
    ev, out, empty = np.empty((6, 3)), ZONE_OUT.zeros(), np.empty((0, 0))
    one, summed = np.empty(len(tips)), np.empty(len(tips))
    times = {"one": [], "sum": []}
    for _ in range(rounds + 1):  # the first compiles
        t0 = time.perf_counter()
        _one_terms(ctrl, ku, kv, us, vs, tips, *law.args, ev, one)
        t1 = time.perf_counter()
        _lattice_sums(*lattice.kernel_args(), tips, *law.args, out, empty, summed)
        t2 = time.perf_counter()
        times["one"].append((t1 - t0) / len(tips))
        times["sum"].append((t2 - t1) / len(tips))
    return {"one_term_us": 1e6 * float(np.median(times["one"][1:])),
            "lattice_sum_us": 1e6 * float(np.median(times["sum"][1:])),
            "compiled_energy_difference_max": float(np.max(np.abs(one - summed) / np.abs(summed)))}


def compare(name: str, points: int) -> dict:
    """The formula against the lattice at ``points`` tips of the scan's slide (module docstring)."""
    surface = prepared_surface(SCANS / name)[1]
    tips = []
    run_scenario(surface, motion="slide-100", source="blended", seconds=1.5, zone_energy=True,
                 after_tick=lambda tip, probe, model: tips.append(np.array(tip)))
    p = PRESETS["demo"]
    law = ZoneLaw.from_law(MaugisDugdale(p.tip_radius, p.effective_modulus, p.work_of_adhesion))
    lattice = lattice_for(surface, p.tip_radius, law.interaction_range)
    h, ex, ez = FORCE_STEP, np.array([FORCE_STEP, 0.0, 0.0]), np.array([0.0, 0.0, FORCE_STEP])
    out = {"scan": name, "tips": points}
    chosen = tips[len(tips) // 3::max(1, (len(tips) - len(tips) // 3) // points)][:points]
    for label, sphere in (("sphere", True), ("paraboloid", False)):
        rows = []
        for tip in chosen:
            e_lat, f_lat = zone_energy(lattice, law, tip)
            e_q = quadric_energy(surface, law, tip, sphere)
            fz = -(quadric_energy(surface, law, tip + ez, sphere) - quadric_energy(surface, law, tip - ez, sphere)) / (2 * h)
            fx = -(quadric_energy(surface, law, tip + ex, sphere) - quadric_energy(surface, law, tip - ex, sphere)) / (2 * h)
            rows.append((abs(e_q - e_lat) / abs(e_lat), abs(fz - f_lat[2]) / abs(f_lat[2]),
                         abs(fx - f_lat[0]) / abs(f_lat[2]), f_lat[2]))
        a = np.array(rows)
        out[label] = {"energy_difference_median": float(np.median(a[:, 0])), "energy_difference_max": float(a[:, 0].max()),
                      "fz_difference_median": float(np.median(a[:, 1])), "fz_difference_max": float(a[:, 1].max()),
                      "fx_difference_over_fz_max": float(a[:, 2].max()), "lattice_fz_median_N": float(np.median(a[:, 3]))}
    out["cost"] = time_against_the_lattice(surface, law, lattice, chosen)
    return out


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scans", nargs="+", default=list(DEFAULT_SCANS))
    parser.add_argument("--points", type=int, default=20)
    args = parser.parse_args(argv)
    for name in args.scans:
        print(json.dumps(compare(name, args.points)), flush=True)


if __name__ == "__main__":
    main()
