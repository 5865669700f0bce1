"""Benchmark (accuracy and sums): the zone energy's tracking proxy against the proxy run to convergence.

A haptic tick moves the tip behind the coupling with :func:`~arsurf.contact.zone_energy.zone_proxy_kernel`
in its tracking mode (``reduction`` :data:`~arsurf.contact.zone_energy.TRACKING_REDUCTION`): one
Newton step from the point summed the tick before, one sum of the lattice where it lands, and the
rest of the way taken on the quadratic model about that point when it can be trusted. Here the
targets of ``bench/feel.py``'s slides on real scans (the demo preset, the energy of the whole tip,
the blended source at 1 kHz), recorded from the loop, are replayed through the tracking proxy and,
beside it on a lattice of its own, through the proxy run to convergence (its tolerance, 1e-6 of
k R): the Newton steps a tick (each one sum of the lattice unless its line search halves it), the
share of ticks whose tip is published off the point summed, and the largest difference of the
published force from the converged one on each axis, over the converged force's peak.

Run: .venv/bin/python bench/zone_tracking.py [--scans NAME ...] [--motions slide-100 slide-10]
[--seconds 2] (prints JSON, one line per scan and motion; the scans from ../shared/scans-real)
"""
from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import numpy as np

from arsurf.assembly import PRESETS
from arsurf.contact.maugis_dugdale import MaugisDugdale
from arsurf.contact.zone_energy import L_MEMO, TRACKING_REDUCTION, Z_FORCE, ZONE_OUT, ZoneLaw, lattice_for, zone_proxy_kernel
from arsurf.feel_scenarios import prepared_surface, run_scenario

SCANS = Path(os.environ.get("ARSURF_REAL_SCANS", Path(__file__).resolve().parents[2] / "shared" / "scans-real"))
DEFAULT_SCANS = ("2018-02-09_1506_PH_dt20nmwindow1_Z_C.gsf", "sample_0.spm")


def replay(surface, motion: str, seconds: float) -> dict:
    """The tracking and converging proxies over the targets of one slide (module docstring)."""
    targets, stiffness = [], []
    run_scenario(surface, motion=motion, source="blended", seconds=seconds, zone_energy=True,
                 after_tick=lambda tip, probe, model: (targets.append(np.array(probe)),
                                                       stiffness.append(model.coupling_stiffness)))
    p = PRESETS["demo"]
    law = ZoneLaw.from_law(MaugisDugdale(p.tip_radius, p.effective_modulus, p.work_of_adhesion))
    k = stiffness[-1]
    tracking, converging = (lattice_for(surface, p.tip_radius, law.interaction_range) for _ in range(2))
    start = len(targets) // 4  # in contact by then: the slide, not the approach
    tip = targets[start] + [0.0, 0.0, 2.0 * p.tip_radius]  # above the target: both come down to it
    full, out, full_out = tip.copy(), ZONE_OUT.zeros(), ZONE_OUT.zeros()
    zone_proxy_kernel(*converging.kernel_args(), *targets[start], k, *law.args, full, full_out)
    tip, out = full.copy(), full_out.copy()
    zone_proxy_kernel(*tracking.kernel_args(), *targets[start], k, *law.args, tip, out)
    steps, published, deviation, peak = [], 0, np.zeros(3), 0.0
    for target in targets[start + 1:]:
        steps.append(zone_proxy_kernel(*tracking.kernel_args(), *target, k, *law.args, tip, out, TRACKING_REDUCTION))
        published += not np.array_equal(tip, tracking.arrays[L_MEMO][:3])
        zone_proxy_kernel(*converging.kernel_args(), *target, k, *law.args, full, full_out)
        force = full_out[Z_FORCE:Z_FORCE + 3]
        deviation = np.maximum(deviation, np.abs(out[Z_FORCE:Z_FORCE + 3] - force))
        peak = max(peak, float(np.abs(force).max()))
    steps = np.abs(np.array(steps))
    return {"ticks": int(steps.size), "coupling_N_per_m": k, "newton_steps_per_tick_mean": float(steps.mean()),
            "ticks_with_more_than_one_step_share": float((steps > 1).mean()),
            "published_off_the_summed_point_share": published / steps.size,
            "peak_force_N": peak, "largest_difference_over_peak": (deviation / peak).tolist()}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scans", nargs="+", default=list(DEFAULT_SCANS))
    parser.add_argument("--motions", nargs="+", default=["slide-100", "slide-10"])
    parser.add_argument("--seconds", type=float, default=2.0)
    args = parser.parse_args(argv)
    for name in args.scans:
        surface = prepared_surface(SCANS / name)[1]
        for motion in args.motions:
            print(json.dumps({"scan": name, "motion": motion, **replay(surface, motion, args.seconds)}), flush=True)


if __name__ == "__main__":
    main()
