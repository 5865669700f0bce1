"""Benchmark (diagnostic): what one sum of the zone energy costs per sample, and what vector code would save.

:func:`~arsurf.contact.zone_energy.zone_energy_kernel` sums the law over the lattice samples in
reach of the tip: on a flat, the lattice of :func:`~arsurf.contact.zone_energy.lattice_for` (an
eighth of the interaction zone apart), a 20 nm tip pressed 0.3 and 1 nm, its time per sum with
and without the Hessian, over the samples in reach. Beside it, outside the engine, the same sum
written for vector units: the samples' x, y, z in separate rows, no branch (both of the tip's
sphere and cone, the law's repulsion and adhesion computed and selected; the adhesion a
polynomial bump of the same work, since sine and cosine do not vectorise without Intel's SVML),
reductions reassociated (fastmath): its time per sample it visits (every sample of a square
around the tip: what a row's window would visit), with the vector registers its assembly uses.

Run: .venv/bin/python bench/zone_sum_cost.py (prints JSON lines)
"""
from __future__ import annotations

import json
import math
import time

import numpy as np
from numba import njit

from arsurf.contact.maugis_dugdale import MaugisDugdale
from arsurf.contact.zone_energy import CONE_HALF_ANGLE, HESSIAN_FLOOR, ZONE_OUT, ZoneLaw, lattice_for, zone_energy_kernel
from arsurf.scan.scan import Scan
from arsurf.spline.fit import fit_surface


@njit
def _engine(lat, x, y, z, radius, e_star, sigma0, h0, out, hess, reps):
    n = 0
    for k in range(reps):
        n = zone_energy_kernel(lat, x + 1e-12 * (k % 7), y, z, radius, e_star, sigma0, h0, out, hess)
    return n


@njit(fastmath=True, error_model="numpy")  # not cached: a cached function shows no assembly
def _vector_row(xs, ys, zs, ar, tx, ty, tz, radius, stiff, sig, h0, rho0, cap, slope, floor):
    e = fx = fy = fz = 0.0
    h00 = h01 = h02 = h11 = h12 = h22 = 0.0
    r2max, r02 = radius * radius, rho0 * rho0
    for k in range(xs.shape[0]):
        dx, dy = tx - xs[k], ty - ys[k]
        r2 = dx * dx + dy * dy
        sphere = r2 < r02
        root = math.sqrt(max(r2max - r2, r02 * 1e-6))
        rho = math.sqrt(max(r2, 1e-40))
        inv = 1.0 / root
        q = inv if sphere else slope / rho
        q1 = inv * inv * inv if sphere else -slope / (rho * r2)
        g = tz - radius + (radius - root if sphere else cap + (rho - rho0) * slope) - zs[k]
        neg = g < 0.0
        s = math.sqrt(max(-g, 0.0))
        x = min(max(g / h0, 0.0), 1.0)
        y = 1.0 - x
        phi = (2.0 / 3.0 * stiff * s * s * s - sig * h0) if neg else -sig * h0 * (1.0 - x * x * x * (10.0 - 15.0 * x + 6.0 * x * x))
        p = stiff * s if neg else -30.0 * sig * x * x * y * y
        dp = (-0.5 * stiff / max(s, floor)) if neg else -60.0 * sig / h0 * x * y * (y - x)
        a = ar[k] if g < h0 else 0.0
        ex, ey = q * dx, q * dy
        e += a * phi
        f = a * p
        fx += f * ex
        fy += f * ey
        fz += f
        c = -a * dp
        h00 += c * ex * ex - f * (q + q1 * dx * dx)
        h01 += c * ex * ey - f * q1 * dx * dy
        h02 += c * ex
        h11 += c * ey * ey - f * (q + q1 * dy * dy)
        h12 += c * ey
        h22 += c
    return e + fx + fy + fz + h00 + h01 + h02 + h11 + h12 + h22


@njit
def _vector(xs, ys, zs, ar, tx, ty, tz, radius, stiff, sig, h0, rho0, cap, slope, floor, reps):
    t = 0.0
    for _ in range(reps):
        for i in range(xs.shape[0]):
            t += _vector_row(xs[i], ys[i], zs[i], ar[i], tx, ty, tz, radius, stiff, sig, h0, rho0, cap, slope, floor)
    return t


def _best(fn, reps: int = 200, rounds: int = 7) -> float:
    fn(1)
    best = math.inf
    for _ in range(rounds):
        t = time.perf_counter()
        fn(reps)
        best = min(best, (time.perf_counter() - t) / reps)
    return best


def main() -> None:
    radius = 20e-9
    law = ZoneLaw.from_law(MaugisDugdale(radius, 10e9, 0.1))
    r, e_star, sigma0, h0 = law.args
    surface = fit_surface(Scan(np.zeros((60, 60)), 2e-9, 2e-9))
    lattice = lattice_for(surface, radius, h0)
    h = lattice.spacing[0]
    out, hess, none = ZONE_OUT.zeros(), np.empty((3, 3)), np.empty((0, 0))
    rho0, cap = radius * math.cos(CONE_HALF_ANGLE), radius * (1.0 - math.sin(CONE_HALF_ANGLE))
    slope, floor = 1.0 / math.tan(CONE_HALF_ANGLE), math.sqrt(HESSIAN_FLOOR * h0)
    for depth in (0.3e-9, 1.0e-9):
        c, z = 59e-9, radius - depth
        n = _engine(lattice.arrays, c, c, z, r, e_star, sigma0, h0, out, none, 1)
        with_hessian = _best(lambda k: _engine(lattice.arrays, c, c, z, r, e_star, sigma0, h0, out, hess, k))
        without = _best(lambda k: _engine(lattice.arrays, c, c, z, r, e_star, sigma0, h0, out, none, k))
        side = 2 * int(math.ceil(math.sqrt(2.0 * radius * (depth + h0)) / h)) + 4
        grid = (np.arange(side) - side / 2) * h
        xs = np.ascontiguousarray(np.tile(grid, (side, 1)))
        ys = np.ascontiguousarray(xs.T)
        zs, ar = np.zeros_like(xs), np.full_like(xs, h * h)
        stiff = e_star / (math.pi * math.sqrt(radius))
        vector = _best(lambda k: _vector(xs, ys, zs, ar, 0.1 * h, 0.05 * h, z, radius, stiff, sigma0, h0, rho0, cap, slope,
                                         floor, k))
        asm = next(iter(_vector_row.inspect_asm().values()))
        print(json.dumps({"tip_radius_m": radius, "depth_m": depth, "spacing_m": h, "samples_in_reach": n,
                          "engine_sum_with_hessian_s": with_hessian, "engine_sum_s": without,
                          "engine_per_sample_in_reach_with_hessian_s": with_hessian / n,
                          "vector_sum_s": vector, "vector_samples_visited": side * side,
                          "vector_per_sample_visited_s": vector / (side * side),
                          "vector_registers": {"ymm": asm.count("ymm"), "zmm": asm.count("zmm")}}), flush=True)


if __name__ == "__main__":
    main()
