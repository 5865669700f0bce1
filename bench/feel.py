"""Benchmark: the feel of the haptic loop over surfaces x sources x motions x rates, and its tick time.

For every case of the table - real scans from ../shared/scans-real (prepared as the demo
prepares them) and synthetic steps/ridges, x sources (simulated, measured with 1e-8 rad of
photodiode noise, blended) x motions (press still, slide 1/10/100 nm/s, stroke across, tap) x
loop rates (1, 5, 10 kHz) - a modelled hand closes the loop on a VirtualDevice
(:mod:`arsurf.feel_scenarios`) and the device force is scored (:mod:`arsurf.haptics.feel`):
content above 100 Hz / mean normal force per axis, tick-to-tick reversals above 1 % of the peak,
smallest observed energy, largest step, passivity-controller ticks, steady-state transparency,
tick time. Peer, same run: one bare VTK ``vtkStaticCellLocator.FindClosestPoint`` on the fitted
surface's triangulation at the tip positions of a slide, timed two ways in the same run: back to
back after each round of ticks (rounds interleaved), and one query right after each tick at its
tip, inside the loop's iteration - the peer under the very conditions (caches, interpreter) the
tick is timed in.

Generated families (issue 27 §3, ``--families N``): N surfaces drawn by the seeded generators of
:func:`arsurf.feel_scenarios.generated_surfaces` (Gaussian and power-law rough surfaces, rms
0.5-20 nm x correlation length 2-200 nm x pixel 0.25-8 nm, steps and ridges, against tip radii
2-50 nm), plus every real scan of ../shared/scans-real the project opens (not with ``--quick``),
each surface with ``--runs SLOW FAST`` seeded runs (:func:`arsurf.feel_scenarios.plan_runs`: a
drawn heading, source and, for a still/slow run, rate), judged with the default loop (the virtual
device, coupling and passivity on) by :func:`arsurf.feel_scenarios.judge_run`:

* a still or slow tip (press; slides at 0.1, 1, 10 nm/s): content above 100 Hz <= 2 % of the
  mean normal force on each axis after 1 s, no tick-to-tick reversal above 1 % of the peak,
  observed energy >= -E0, a press at rest within 1 % of K_f F;
* a faster motion (slides at 100 and 1000 nm/s turning back at the scan's edge, circles, strokes,
  taps): the same motion at 1 and 10 kHz through the same virtual coupling, the 10 kHz force
  low-passed (zero phase) at 450 Hz, compared at the 1 kHz ticks (the 5 ms after a contact is
  made or broken left out): rms difference <= 5 % of the rms force
  (:data:`arsurf.feel_scenarios.RATE_TOLERANCE`), and energy >= -E0 at both rates.

The full table is ``--families 240 --runs 4 2`` (240 generated surfaces and the real scans, 1440
runs on the generated ones, 25.8 M loop ticks); it prints its size and a time estimate (from a
calibration run on this machine, now) first, ``--estimate`` only that.

Run: .venv/bin/python bench/feel.py [--quick] [--seconds 3] [--families N [--runs 2 1] [--seed S] [--estimate]]
(prints JSON)
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path

import numpy as np

from arsurf.assembly import PRESETS
from arsurf.feel_scenarios import (GENERATED_PIXELS, MOTIONS, RATE_CUTOFF, RATE_TOLERANCE, SOURCES,
                                   generated_surfaces, judge_run, plan_runs, prepared_surface, run_scenario,
                                   synthetic_surface, ticks)

sys.path.insert(0, str(Path(__file__).resolve().parent))
from collision import vtk_locator  # noqa: E402  (the VTK peer, built the same way in every bench)

SCANS = Path(os.environ.get("ARSURF_REAL_SCANS", Path(__file__).resolve().parents[2] / "shared" / "scans-real"))
REAL = ("Veeco_20160622.003", "sample_0.spm", "sample_0.jpk")


def line(r: dict) -> str:
    """One stderr line per judged run."""
    head = f"{r['surface']} {r['motion']} {r['heading_deg']:.0f}deg {r['source']}"
    if r["kind"] == "fast":
        return (f"{head}: {'ok' if r['ok'] else 'FAIL'} rate error {100 * r['rate_error']:.2f} % (tick mean "
                f"{100 * r['tick_mean_error']:.1f} %) E/E0 {min(r['min_energy_over_E0']):.2f}")
    return (f"{head} {r['rate_hz'] / 1e3:.0f} kHz: {'ok' if r['ok'] else 'FAIL'} hf "
            f"{'/'.join(f'{100 * x:.2f}' for x in r['high_frequency_over_normal'])} % rev {sum(r['reversals'])} "
            f"E/E0 {r['min_energy_over_E0']:.2f} rest {100 * r['rest_error']:.3f} %")


def families(count: int, seed: int, real: bool = True, slow_runs: int = 2, fast_runs: int = 1,
             estimate_only: bool = False) -> dict:
    """The generated table (``count`` surfaces, seeded) and every real scan the project opens, judged;
    prints the time estimate (calibrated on a short run) before it starts."""
    rng = np.random.default_rng(seed)
    table = [(g.name, g.surface, g.tip_radius, GENERATED_PIXELS * g.pixel) for g in generated_surfaces(count, seed)]
    unreadable = {}
    if real:
        for path in sorted(p for p in SCANS.iterdir() if p.suffix != ".md") if SCANS.exists() else []:
            try:
                s = prepared_surface(path)[1]
            except Exception as exc:  # noqa: BLE001 - a file the project cannot open: said, not fatal
                unreadable[path.name] = f"{type(exc).__name__}: {exc}"[:200]
                continue
            (u0, u1), (v0, v1) = s.domain
            table.append((path.name, (lambda s=s: s), float(PRESETS["demo"].tip_radius), min(u1 - u0, v1 - v0)))
    plan = [(make, tip, runs) for name, make, tip, side in table
            for runs in [plan_runs(name, rng, tip, side, slow_runs, fast_runs)]]
    total = sum(ticks(r) for _, _, runs in plan for r in runs)
    per_tick = _tick_cost(table[0][1](), table[0][2]) if table else 0.0
    estimate = {"surfaces": len(table), "generated_surfaces": count, "real_scans": len(table) - count,
                "runs": sum(len(runs) for _, _, runs in plan), "loop_ticks": total,
                "estimated_seconds": total * per_tick, "per_tick_us": per_tick * 1e6}
    print(f"families: {estimate['surfaces']} surfaces, {estimate['runs']} runs, {total} ticks: about "
          f"{estimate['estimated_seconds']:.0f} s at {per_tick * 1e6:.0f} us per tick (this machine, now)", file=sys.stderr)
    if estimate_only:
        return {"estimate": estimate}
    rows = []
    for make, tip, runs in plan:
        surface = make()
        for run in runs:
            rows.append(judge_run(run, surface, tip))
            print(line(rows[-1]), file=sys.stderr)
    failed = [r for r in rows if not r["ok"]]
    fast = [r["rate_error"] for r in rows if r["kind"] == "fast"]
    slow = [r for r in rows if r["kind"] == "slow"]
    return {"summary": {**estimate, "seed": seed, "failed": len(failed),
                        "failed_runs": [line(r) for r in failed],
                        "rate_tolerance": RATE_TOLERANCE, "rate_cutoff_hz": RATE_CUTOFF,
                        "worst_rate_error": max(fast, default=math.nan),
                        "worst_tick_mean_error": max((r["tick_mean_error"] for r in rows if r["kind"] == "fast"),
                                                     default=math.nan),
                        "worst_high_frequency_over_normal": max((max(r["high_frequency_over_normal"]) for r in slow),
                                                                default=math.nan),
                        "most_reversals": max((sum(r["reversals"]) for r in slow), default=0),
                        "lowest_energy_over_E0": min((min(np.atleast_1d(r["min_energy_over_E0"])) for r in rows),
                                                     default=math.nan),
                        "worst_rest_error": max((r["rest_error"] for r in slow if not math.isnan(r["rest_error"])),
                                                default=math.nan),
                        "unreadable": unreadable},
            "rows": rows}


def _tick_cost(surface, tip_radius) -> float:
    """Seconds per loop tick of a scenario on ``surface`` (a 1.2 s press at 5 kHz, after a warm-up)."""
    import time

    run_scenario(surface, motion="press", rate=1000.0, seconds=1.2, tip_radius=tip_radius)
    t0 = time.perf_counter()
    run_scenario(surface, motion="press", rate=5000.0, seconds=1.2, tip_radius=tip_radius)
    return (time.perf_counter() - t0) / 6000.0


def vtk_ratio(surface, rounds: int = 3) -> dict:
    """Tick median vs one VTK closest-point query at the same tip positions (slide at 100 nm/s).

    Two timings of the peer, same run: ``vtk_query_median_us`` times the round's tip positions
    back to back after the round (the peer alone in a tight loop: its locator stays in the CPU's
    caches), ``vtk_interleaved_median_us`` times one query right after each tick at that tick's
    tip, inside the loop's own iteration (device, recording), as the tick itself is timed."""
    (u0, u1), (v0, v1) = surface.domain
    nu, nv = surface.shape
    uu, vv = np.meshgrid(np.linspace(u0, u1, nu), np.linspace(v0, v1, nv), indexing="ij")
    pts = surface.evaluate(uu.ravel(), vv.ravel())
    idx = np.arange(nu * nv).reshape(nu, nv)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    faces = np.concatenate([np.column_stack([a, b, d]), np.column_stack([a, d, c])])
    _build, query, one = vtk_locator(pts, faces)
    ticks, queries, inter = [], [], []
    for _ in range(rounds):
        beside = []
        run = run_scenario(surface, motion="slide-100", source="blended", seconds=2.0,
                           after_tick=lambda tip: beside.append(one((float(tip[0]), float(tip[1]), float(tip[2])))))
        ticks.append(float(np.median(run.tick_ns)) * 1e-3)
        queries.append(float(np.median(query(run.tip)[0])) * 1e6)
        inter.append(float(np.median(beside)) * 1e6)
    ratios = [t / q for t, q in zip(ticks, queries)]
    ratios_i = [t / q for t, q in zip(ticks, inter)]
    return {"tick_median_us": ticks, "vtk_query_median_us": queries, "tick_over_vtk": ratios,
            "tick_over_vtk_median": float(np.median(ratios)), "vtk_interleaved_median_us": inter,
            "tick_over_vtk_interleaved": ratios_i, "tick_over_vtk_interleaved_median": float(np.median(ratios_i)),
            "triangles": int(faces.shape[0])}


def transparency(surface, rate: float, source: str, seconds: float = 6.0) -> dict:
    """Rendered (device) force over the scaled tip force K_f F_z, as a frequency response: the
    hand presses and a multisine wobbles it (motion ``wobble``); H(f) = S_tip,dev / S_tip,tip at
    the ten tones (Welch, 1 s segments, after the first second)."""
    from scipy.signal import csd, welch

    from arsurf.assembly import PRESETS
    from arsurf.feel_scenarios import run_scenario as run

    gain = float(PRESETS["demo"].haptics["force_gain"])
    r = run(surface, motion="wobble", source=source, rate=rate, seconds=seconds)
    start = int(rate)
    x = r.probe_force[start:, 2] * gain
    y = r.force[start:, 2]
    f, sxy = csd(x, y, fs=rate, nperseg=int(rate))
    _, sxx = welch(x, fs=rate, nperseg=int(rate))
    tones = np.geomspace(2.0, 400.0, 10)
    idx = [int(np.argmin(np.abs(f - t))) for t in tones if t < rate / 2]
    h = sxy[idx] / sxx[idx]
    return {"rate_hz": rate, "source": source, "frequency_hz": [float(f[i]) for i in idx],
            "magnitude": [float(abs(v)) for v in h], "phase_deg": [float(np.degrees(np.angle(v))) for v in h]}


def bode_figure(rows, path) -> None:
    """Magnitude and phase of the rendered vs the scaled tip force, one line per rate/source."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (am, ph) = plt.subplots(2, 1, figsize=(6.4, 5.2), sharex=True, constrained_layout=True)
    for r in rows:
        label = f"{r['rate_hz'] / 1e3:.0f} kHz, {r['source']}"
        am.semilogx(r["frequency_hz"], 20 * np.log10(r["magnitude"]), "o-", ms=3, label=label)
        ph.semilogx(r["frequency_hz"], r["phase_deg"], "o-", ms=3, label=label)
    am.set_ylabel("|F_device / (K_f F_tip)| (dB)")
    ph.set_ylabel("phase (deg)")
    ph.set_xlabel("frequency (Hz)")
    am.axhline(0.0, color="0.6", lw=0.8)
    am.legend(fontsize=7)
    am.set_title("Transparency of the rendered force (pressing on a real scan)", fontsize=9)
    fig.savefig(path, dpi=150)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=3.0)
    ap.add_argument("--quick", action="store_true", help="1 kHz only, three motions (a smoke run)")
    ap.add_argument("--no-vtk", action="store_true")
    ap.add_argument("--vtk-only", action="store_true", help="only the tick vs VTK closest point on the real scans")
    ap.add_argument("--motions", nargs="+", choices=MOTIONS, help="only these motions")
    ap.add_argument("--sources", nargs="+", choices=SOURCES, help="only these sources")
    ap.add_argument("--rates", nargs="+", type=float, help="only these loop rates, Hz")
    ap.add_argument("--families", type=int, metavar="N", help="only the generated families: N surfaces "
                    "(and every real scan; --quick: no real scans); the full table is --families 240 --runs 4 2")
    ap.add_argument("--runs", type=int, nargs=2, default=(2, 1), metavar=("SLOW", "FAST"),
                    help="runs per surface of the families: still/slow motions, rate-convergence pairs")
    ap.add_argument("--estimate", action="store_true", help="with --families: only the table size and time estimate")
    ap.add_argument("--seed", type=int, default=0, help="seed of the generated families")
    ap.add_argument("--bode", metavar="PNG", help="only the transparency estimate; write its Bode plot here")
    args = ap.parse_args()
    if args.families is not None:
        print(json.dumps({"families": families(args.families, args.seed, real=not args.quick, slow_runs=args.runs[0],
                                               fast_runs=args.runs[1], estimate_only=args.estimate)}, indent=1))
        return
    surfaces = {}
    for name in REAL:
        path = SCANS / name
        if path.exists():
            surfaces[name] = prepared_surface(path)[1]
    if args.bode:
        s = next(iter(surfaces.values()), None) or synthetic_surface("step")
        rows = [transparency(s, rate, source) for rate in (args.rates or (1000.0, 10000.0))
                for source in (args.sources or ("simulated", "measured"))]
        bode_figure(rows, args.bode)
        print(json.dumps({"transparency": rows, "figure": args.bode}, indent=1))
        return
    if args.vtk_only:  # every real scan of the folder, not only the feel table's three
        rows = {}
        for path in sorted(p for p in SCANS.iterdir() if p.suffix != ".md"):
            try:
                s = surfaces.get(path.name) or prepared_surface(path)[1]
            except Exception as exc:  # noqa: BLE001 - a file the demo cannot prepare: said, not fatal
                rows[path.name] = {"error": f"{type(exc).__name__}: {exc}"[:200]}
                continue
            rows[path.name] = {"control_points": list(s.shape), **vtk_ratio(s)}
            r = rows[path.name]
            print(f"{path.name}: tick {np.median(r['tick_median_us']):.2f} us, VTK {np.median(r['vtk_query_median_us']):.2f} "
                  f"us back to back, {np.median(r['vtk_interleaved_median_us']):.2f} us beside each tick; tick/VTK "
                  f"{r['tick_over_vtk_median']:.2f}, interleaved {r['tick_over_vtk_interleaved_median']:.2f}",
                  file=sys.stderr)
        print(json.dumps({"vtk": rows}, indent=1))
        return
    for kind in ("step", "ridge"):
        surfaces[f"synthetic-{kind}"] = synthetic_surface(kind)
    motions = args.motions or (("press", "slide-10", "stroke") if args.quick else MOTIONS)
    rates = args.rates or ((1000.0,) if args.quick else (1000.0, 5000.0, 10000.0))
    sources = args.sources or SOURCES
    rows = []
    for sname, s in surfaces.items():
        for motion in motions:
            for source in sources:
                for rate in rates:
                    run = run_scenario(s, motion=motion, source=source, rate=rate, seconds=args.seconds)
                    rows.append({"surface": sname, "motion": motion, "source": source, "rate_hz": rate,
                                 **run.score.as_dict(), "passivity_ticks": run.passivity_ticks,
                                 "transparency": run.transparency,
                                 "tick_median_us": float(np.median(run.tick_ns)) * 1e-3,
                                 "tick_p99_us": float(np.percentile(run.tick_ns, 99)) * 1e-3})
                    print(f"{sname} {motion} {source} {rate:.0f} Hz: {run.score.summary()}", file=sys.stderr)
    buzz = [r for r in rows if r["buzzes"]]
    presses = [r["transparency"] for r in rows if r["motion"] == "press"]
    summary = {
        "cases": len(rows), "buzzing_cases": len(buzz),
        "buzzing": [f"{r['surface']} {r['motion']} {r['source']} {r['rate_hz']:.0f} Hz" for r in buzz],
        "worst_high_frequency_over_normal": max(max(r["high_frequency_over_normal"]) for r in rows),
        "most_reversals": max(sum(r["reversals"]) for r in rows),
        "min_energy_J": min(r["min_energy_J"] for r in rows if not math.isnan(r["min_energy_J"])),
        "transparency_range": [min(presses, default=math.nan), max(presses, default=math.nan)],
    }
    vtk_rows = {} if args.no_vtk else {n: vtk_ratio(s) for n, s in surfaces.items() if not n.startswith("synthetic")}
    print(json.dumps({"summary": summary, "vtk": vtk_rows, "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
