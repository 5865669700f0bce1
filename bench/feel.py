"""Benchmark: the feel of the haptic loop over surfaces x sources x motions x rates, and its tick time.

For every case of the table - real scans from ../shared/scans-real (prepared as the demo
prepares them) and synthetic steps/ridges, x sources (simulated, measured with 1e-8 rad of
photodiode noise, blended) x motions (press still, slide 1/10/100 nm/s, stroke across, tap) x
loop rates (1, 5, 10 kHz) - a modelled hand closes the loop on a VirtualDevice
(:mod:`arsurf.feel_scenarios`) and the device force is scored (:mod:`arsurf.haptics.feel`):
content above 100 Hz / mean normal force per axis, tick-to-tick reversals above 1 % of the peak,
smallest observed energy, largest step, passivity-controller ticks, steady-state transparency,
tick time. Peer, same run: one bare VTK ``vtkStaticCellLocator.FindClosestPoint`` on the fitted
surface's triangulation at the tip positions of a slide, timed in rounds interleaved with the
loop's ticks at those positions.

Run: .venv/bin/python bench/feel.py [--quick] [--seconds 3]   (prints JSON)
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path

import numpy as np

from arsurf.feel_scenarios import MOTIONS, SOURCES, prepared_surface, run_scenario, synthetic_surface

sys.path.insert(0, str(Path(__file__).resolve().parent))
from collision import vtk_locator  # noqa: E402  (the VTK peer, built the same way in every bench)

SCANS = Path(os.environ.get("ARSURF_REAL_SCANS", Path(__file__).resolve().parents[2] / "shared" / "scans-real"))
REAL = ("Veeco_20160622.003", "sample_0.spm", "sample_0.jpk")


def vtk_ratio(surface, rounds: int = 3) -> dict:
    """Tick median vs one VTK closest-point query at the same tip positions (slide at 100 nm/s)."""
    (u0, u1), (v0, v1) = surface.domain
    nu, nv = surface.shape
    uu, vv = np.meshgrid(np.linspace(u0, u1, nu), np.linspace(v0, v1, nv), indexing="ij")
    pts = surface.evaluate(uu.ravel(), vv.ravel())
    idx = np.arange(nu * nv).reshape(nu, nv)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    faces = np.concatenate([np.column_stack([a, b, d]), np.column_stack([a, d, c])])
    _build, query = vtk_locator(pts, faces)
    ticks, queries = [], []
    for _ in range(rounds):
        run = run_scenario(surface, motion="slide-100", source="blended", seconds=2.0)
        ticks.append(float(np.median(run.tick_ns)) * 1e-3)
        queries.append(float(np.median(query(run.tip)[0])) * 1e6)
    ratios = [t / q for t, q in zip(ticks, queries)]
    return {"tick_median_us": ticks, "vtk_query_median_us": queries, "tick_over_vtk": ratios,
            "tick_over_vtk_median": float(np.median(ratios)), "triangles": int(faces.shape[0])}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=3.0)
    ap.add_argument("--quick", action="store_true", help="1 kHz only, three motions (a smoke run)")
    ap.add_argument("--no-vtk", action="store_true")
    args = ap.parse_args()
    surfaces = {}
    for name in REAL:
        path = SCANS / name
        if path.exists():
            surfaces[name] = prepared_surface(path)[1]
    for kind in ("step", "ridge"):
        surfaces[f"synthetic-{kind}"] = synthetic_surface(kind)
    motions = ("press", "slide-10", "stroke") if args.quick else MOTIONS
    rates = (1000.0,) if args.quick else (1000.0, 5000.0, 10000.0)
    rows = []
    for sname, s in surfaces.items():
        for motion in motions:
            for source in SOURCES:
                for rate in rates:
                    run = run_scenario(s, motion=motion, source=source, rate=rate, seconds=args.seconds)
                    rows.append({"surface": sname, "motion": motion, "source": source, "rate_hz": rate,
                                 **run.score.as_dict(), "passivity_ticks": run.passivity_ticks,
                                 "transparency": run.transparency,
                                 "tick_median_us": float(np.median(run.tick_ns)) * 1e-3,
                                 "tick_p99_us": float(np.percentile(run.tick_ns, 99)) * 1e-3})
                    print(f"{sname} {motion} {source} {rate:.0f} Hz: {run.score.summary()}", file=sys.stderr)
    buzz = [r for r in rows if r["buzzes"]]
    summary = {
        "cases": len(rows), "buzzing_cases": len(buzz),
        "buzzing": [f"{r['surface']} {r['motion']} {r['source']} {r['rate_hz']:.0f} Hz" for r in buzz],
        "worst_high_frequency_over_normal": max(max(r["high_frequency_over_normal"]) for r in rows),
        "most_reversals": max(sum(r["reversals"]) for r in rows),
        "min_energy_J": min(r["min_energy_J"] for r in rows if not math.isnan(r["min_energy_J"])),
        "transparency_range": [min(r["transparency"] for r in rows if r["motion"] == "press"),
                               max(r["transparency"] for r in rows if r["motion"] == "press")],
    }
    vtk_rows = {} if args.no_vtk else {n: vtk_ratio(s) for n, s in surfaces.items() if not n.startswith("synthetic")}
    print(json.dumps({"summary": summary, "vtk": vtk_rows, "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
