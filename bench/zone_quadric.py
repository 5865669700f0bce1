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
one term costs in the engine (:mod:`arsurf.contact.zone_quadric`: the minimum by Newton's method on
the spline, the weighted integral in closed form, the checks of its weight), and the energy joined
to the lattice where they trust it (:func:`~arsurf.contact.zone_energy.tip_energy_kernel`), against
one sum of the lattice (all without a Hessian) at the same tips, each in a compiled loop, the rounds
alternated.

And, with ``--families N``, the engine's joined energy against the lattice on generated rough
surfaces under their own tips: how often the one term is trusted alone, and how well it then does
(:func:`family_accuracy`).

Run: .venv/bin/python bench/zone_quadric.py [--scans NAME ...] [--points 20] (prints JSON, one
line per scan; Python evaluations, a few seconds a scan); [--families 60 --points 10 --seed 7]
(one line; a few minutes)
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
from arsurf.contact.zone_energy import (L_CURV, ZONE_OUT, ZoneLaw, lattice_for, tip_energy_kernel, zone_energy,
                                        zone_energy_kernel, zone_law_kernel)
from arsurf.contact.zone_quadric import QUADRIC_OUT, quadric_contact_kernel
from arsurf.feel_scenarios import prepared_surface, run_scenario

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
def _one_terms(ctrl, ku, kv, curv, curv_ku, curv_kv, tips, radius, e_star, sigma0, h0, quad, empty, energies):
    for k in range(tips.shape[0]):
        quadric_contact_kernel(ctrl, ku, kv, curv, curv_ku, curv_kv, tips[k, 0], tips[k, 1], tips[k, 2], radius,
                               e_star, sigma0, h0, quad, empty)
        energies[k] = quad[0]


@njit  # not cached (above)
def _joined(lat, tips, radius, e_star, sigma0, h0, out, empty, energies):
    for k in range(tips.shape[0]):
        tip_energy_kernel(lat, tips[k, 0], tips[k, 1], tips[k, 2], radius, e_star, sigma0, h0, out, empty)
        energies[k] = out[0]


@njit  # not cached (above)
def _lattice_sums(lat, tips, radius, e_star, sigma0, h0, out, empty, energies):
    for k in range(tips.shape[0]):
        zone_energy_kernel(lat, tips[k, 0], tips[k, 1], tips[k, 2], radius, e_star, sigma0, h0, out, empty)
        energies[k] = out[0]


def time_against_the_lattice(surface, law: ZoneLaw, lattice, tips, rounds: int = 7) -> dict:
    """Time (us) of the engine's one term with its checks (:func:`~arsurf.contact.zone_quadric.quadric_contact_kernel`),
    of the energy joined to the lattice where they trust it (:func:`~arsurf.contact.zone_energy.tip_energy_kernel`
    on a lattice made with ``closed_form``) and of one lattice sum, all without a Hessian, at the same ``tips``,
    each over all of them in a compiled loop, the rounds alternated (the median round); the one term's largest
    energy difference from the sum, and the share of tips the joined energy took from the one term alone."""
    ctrl = np.array(surface.rest_control_points, order="C")
    joined = lattice_for(surface, law.tip_radius, law.interaction_range, closed_form=True)
    tips = np.ascontiguousarray(tips)
    quad, out, empty = QUADRIC_OUT.full(math.nan), ZONE_OUT.zeros(), np.empty((0, 0))
    one, both, summed = np.empty(len(tips)), np.empty(len(tips)), np.empty(len(tips))
    times = {"one": [], "joined": [], "sum": []}
    for _ in range(rounds + 1):  # the first compiles
        t0 = time.perf_counter()
        _one_terms(ctrl, surface.knots_u, surface.knots_v, *joined.arrays[L_CURV:L_CURV + 3], tips, *law.args, quad,
                   empty, one)
        t1 = time.perf_counter()
        _joined(joined.arrays, tips, *law.args, out, empty, both)
        t2 = time.perf_counter()
        _lattice_sums(*lattice.kernel_args(), tips, *law.args, out, empty, summed)
        t3 = time.perf_counter()
        times["one"].append((t1 - t0) / len(tips))
        times["joined"].append((t2 - t1) / len(tips))
        times["sum"].append((t3 - t2) / len(tips))
    alone = sum(tip_energy_kernel(joined.arrays, *t, *law.args, out, empty) == -1 for t in tips)
    return {"one_term_us": 1e6 * float(np.median(times["one"][1:])),
            "joined_us": 1e6 * float(np.median(times["joined"][1:])),
            "lattice_sum_us": 1e6 * float(np.median(times["sum"][1:])),
            "one_term_share": alone / len(tips),
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


def family_accuracy(count: int, seed: int, points: int) -> dict:
    """The engine's joined energy on ``count`` generated Gaussian and power-law surfaces
    (:func:`~arsurf.feel_scenarios.generated_surfaces`, ``seed``), ``points`` tips each pressed
    0.2-2 nm below first touch in the middle of the scan, under each surface's own tip (the demo's
    law): the share of tips the one term takes alone (weight 1) and there its force's difference
    from the lattice's (over the larger of that force and the pull-off 1.5 pi R w), median, 90th
    percentile and largest."""
    from arsurf.contact.materials import default_dugdale_stress
    from arsurf.contact.zone_energy import L_QUAD
    from arsurf.contact.zone_quadric import Q_GAP, Q_WEIGHT
    from arsurf.feel_scenarios import clearance_height, generated_surfaces

    p = PRESETS["demo"]
    alone, other = [], 0
    for g in generated_surfaces(count, seed, families=("gaussian", "power-law")):
        surface, radius = g.surface(), g.tip_radius
        law = ZoneLaw(radius, p.effective_modulus, p.work_of_adhesion, default_dugdale_stress(p.work_of_adhesion))
        joined = lattice_for(surface, radius, law.interaction_range, closed_form=True)
        summed = lattice_for(surface, radius, law.interaction_range)
        (u0, u1), (v0, v1) = surface.domain
        rng = np.random.default_rng(g.seed)
        out = ZONE_OUT.zeros()
        for _ in range(points):
            x = rng.uniform(u0 + 0.3 * (u1 - u0), u1 - 0.3 * (u1 - u0))
            y = rng.uniform(v0 + 0.3 * (v1 - v0), v1 - 0.3 * (v1 - v0))
            tip = np.array([x, y, clearance_height(surface, x, y, radius, samples=101) - rng.uniform(0.2e-9, 2e-9)])
            used = tip_energy_kernel(joined.arrays, *tip, *law.args, out, np.empty((0, 0)))
            if not joined.arrays[L_QUAD][Q_GAP] < law.interaction_range:
                continue  # out of the law's reach
            force = zone_energy(summed, law, tip)[1]
            scale = max(float(np.linalg.norm(force)), 1.5 * math.pi * radius * p.work_of_adhesion)
            if used == -1:
                alone.append(float(np.linalg.norm(out[1:4] - force)) / scale)
            else:
                other += 1
    a = np.array(alone) if alone else np.full(1, math.nan)
    return {"families": count, "seed": seed, "tips": len(alone) + other,
            "one_term_share": len(alone) / max(len(alone) + other, 1),
            "one_term_force_difference": {"median": float(np.median(a)), "p90": float(np.percentile(a, 90)),
                                          "max": float(a.max())}}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scans", nargs="+", default=list(DEFAULT_SCANS))
    parser.add_argument("--points", type=int, default=20)
    parser.add_argument("--families", type=int, default=0,
                        help="instead: the joined energy's accuracy on this many generated surfaces "
                             "(--points tips each)")
    parser.add_argument("--seed", type=int, default=7, help="with --families: their seed")
    args = parser.parse_args(argv)
    if args.families:
        print(json.dumps(family_accuracy(args.families, args.seed, args.points)), flush=True)
        return
    for name in args.scans:
        print(json.dumps(compare(name, args.points)), flush=True)


if __name__ == "__main__":
    main()
