"""Benchmark: the cost of a material map in the haptic tick, with and without a map, same run.

The full haptic tick (HapticLoop.step: collision, MD, dent, friction, decoupling, filter, safety)
on a 512 x 512 sinusoid surface, the hand pressing and sliding in circles (in contact most of
the time), once with the constant contact law and once with a material map on the same grid
whose E* varies over 2 decades and w over a factor 4 (lambda from ~0.2 to ~7, with and without a
fold), the two interleaved in rounds (A B A B ...) so that each pair sees the same machine.
Also the lookup kernel alone (the map's two spline contractions and the scaled MD arguments).
Budget (issue 17): at most 10 % added to the tick median.
Run: .venv/bin/python bench/material.py [--rounds 6] [--ticks 4000]   (prints JSON)
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from numba import njit

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _timing import best_round, emit, round_ratio, stats, time_calls  # noqa: E402

from arsurf.contact.material_conversion import MaterialConversion  # noqa: E402
from arsurf.contact.material_map import build_material_map, local_contact_kernel  # noqa: E402
from arsurf.contact.maugis_dugdale import LAMBDA_TRANSITION  # noqa: E402
from arsurf.force.cantilever import Cantilever  # noqa: E402
from arsurf.haptics.loop import HapticLoop, LoopConfig  # noqa: E402
from arsurf.haptics.virtual_device import HandModel, VirtualDevice  # noqa: E402
from arsurf.model import MODEL_ARGS, ARModel  # noqa: E402
from arsurf.scan.scan import Scan  # noqa: E402
from arsurf.scan.synthetic import sinusoid  # noqa: E402
from arsurf.spline.fit import fit_surface  # noqa: E402

R = 20e-9


def material(scan):
    ny, nx = scan.shape
    y, x = np.mgrid[0:ny, 0:nx]
    e = 1e8 * 10.0 ** (1.0 + np.sin(x / 37.0) * np.cos(y / 53.0))             # 0.1 ... 10 GPa
    f = 6e-9 * 2.0 ** (1.0 + np.sin(x / 29.0 + 1.0) * np.sin(y / 41.0))      # 6 ... 24 nN
    chans = {"modulus": Scan(e, scan.dx, scan.dy, "DMTModulus", {"z_unit": "Pa"}),
             "adhesion": Scan(f, scan.dx, scan.dy, "Adhesion", {"z_unit": "N"})}
    return build_material_map(scan, chans, MaterialConversion(R))


def build(scan, mat, law):
    model = ARModel(fit_surface(scan), R, law, Cantilever(450e-6, 50e-6, 2.5e-6, 15e-6, 169e9, 0.27), material=mat,
                    coupling_stiffness=5.0)
    c = (1000e-9, 1000e-9)
    origin = (*c, model.surface.evaluate(*c)[2] + R + 3e-9)

    def traj(t):  # press 8 nm in and slide 40 nm in circles
        return np.array([2e-3 * np.cos(3 * t), 2e-3 * np.sin(3 * t), -0.8e-3])

    dev = VirtualDevice(dt=1e-3, hand=HandModel(traj)).open()
    loop = HapticLoop.direct(model, dev.info, origin, config=LoopConfig(source="blended", signal_noise=1e-8))
    for _ in range(3000):  # warm-up on the real trajectory
        s = dev.read_state()
        dev.command_force(loop.step(s, s.timestamp))
    return dev, loop, model


@njit(cache=True)
def lookup_many(cv, xs, ys):
    acc = 0.0
    for k in range(xs.size):
        md, ratio, jump, zero, here = local_contact_kernel(cv, xs[k], ys[k])
        acc += md[3] + ratio
    return acc


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--rounds", type=int, default=6)
    ap.add_argument("--ticks", type=int, default=4000)
    args = ap.parse_args()
    scan = sinusoid((512, 512), 4e-9, 5e-9, 160e-9)
    mat = material(scan)
    law = mat.contact_law()
    plain = build(scan, None, law)
    mapped = build(scan, mat, law)

    def ticker(dev, loop):
        def tick():
            s = dev.read_state()
            dev.command_force(loop.step(s, s.timestamp))
        return tick

    a_rounds, b_rounds = [], []
    for _ in range(args.rounds):
        a_rounds.append(time_calls(ticker(*plain[:2]), args.ticks, warmup=10))
        b_rounds.append(time_calls(ticker(*mapped[:2]), args.ticks, warmup=10))
    # the lookup alone, compiled, at points along a slide (the tick's own call)
    cv = mapped[2].kernel_args()[MODEL_ARGS.index("md_args")]
    n = 200_000
    xs = np.linspace(0.2e-6, 1.8e-6, n)
    ys = 1e-6 + 0.3e-6 * np.sin(xs / 1e-7)
    lookup_many(cv, xs[:10], ys[:10])
    per_call = time_calls(lambda: lookup_many(cv, xs, ys), 5, warmup=1) / n
    e = mat.fields["reduced_modulus"].pixels
    w = mat.fields["work_of_adhesion"].pixels
    lam = law.maugis_parameter * ((w / law.work_of_adhesion) / (e / law.effective_modulus)) ** (2.0 / 3.0)
    results = {
        "tick_without_map": best_round(a_rounds),
        "tick_with_map": best_round(b_rounds),
        "ratio_with_over_without (median of paired rounds)": round_ratio(b_rounds, a_rounds),
        "added_us (best rounds)": round(float(np.min([np.median(r) for r in b_rounds])
                                             - np.min([np.median(r) for r in a_rounds])) * 1e6, 3),
        "lookup_kernel_per_call (compiled loop)": stats(per_call),
        "map": {"pixels": list(e.shape), "E*_GPa_range": [float(e.min() / 1e9), float(e.max() / 1e9)],
                "w_range": [float(w.min()), float(w.max())], "reference_lambda": law.maugis_parameter,
                "lambda_range": [float(lam.min()), float(lam.max())],
                "pixels_with_a_fold (lambda > lambda_t)": float(np.mean(lam > LAMBDA_TRANSITION))},
        "budget": "at most 10 % added to the tick median (issue 17)",
    }
    emit("material", results)


if __name__ == "__main__":
    main()
