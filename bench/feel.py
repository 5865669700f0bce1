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

Generated families (issue 27 §3, ``--families N``; ``--quick`` runs a seeded sample): N surfaces
drawn by the seeded generators of :func:`arsurf.feel_scenarios.generated_surfaces` (Gaussian and
power-law rough surfaces, rms 0.5-20 nm x correlation length 2-200 nm x pixel 0.25-8 nm, steps and
ridges, against tip radii 2-50 nm), plus every real scan of ../shared/scans-real the loader can
prepare, each judged with the default loop (the virtual device, coupling and passivity on):

* a still or slow tip (press; slides at 0.1, 1, 10 nm/s; a seeded source and rate of 1, 5,
  10 kHz): content above 100 Hz <= 2 % of the mean normal force on each axis after 1 s, no
  tick-to-tick reversal above 1 % of the peak, observed energy >= -E0 (``FeelScore.buzzes``);
* a faster motion (circles at 100 and 1000 nm/s, strokes, taps): the same motion at 1 and 10
  kHz, the 10 kHz force averaged over each 1 ms tick of the 1 kHz loop: their rms difference
  over the rms 10 kHz force after 1 s <= :data:`RATE_TOLERANCE` (what the surface gives stays
  when the rate changes; what the loop adds does not), and energy >= -E0 at both rates.

Run: .venv/bin/python bench/feel.py [--quick] [--seconds 3] [--families N --seed S]   (prints JSON)
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path

import numpy as np

from arsurf.feel_scenarios import (MOTIONS, RATE_TOLERANCE, SOURCES, generated_surfaces, prepared_surface,
                                   rate_convergence, run_scenario, synthetic_surface)

sys.path.insert(0, str(Path(__file__).resolve().parent))
from collision import vtk_locator  # noqa: E402  (the VTK peer, built the same way in every bench)

SCANS = Path(os.environ.get("ARSURF_REAL_SCANS", Path(__file__).resolve().parents[2] / "shared" / "scans-real"))
REAL = ("Veeco_20160622.003", "sample_0.spm", "sample_0.jpk")


SLOW_MOTIONS = ("press", "slide-0.1", "slide-1", "slide-10")
FAST_MOTIONS = ("circle-100", "circle-1000", "stroke", "tap")
RATES = (1000.0, 5000.0, 10000.0)


def judge_surface(name: str, surface, rng, seconds: float, tip_radius=None, slow_runs: int = 2,
                  fast_runs: int = 1) -> list:
    """The family criteria (module docstring) on one surface: ``slow_runs`` still/slow motions at a
    seeded rate and source, ``fast_runs`` rate-convergence pairs; slides and strokes only where
    the surface has room for them (a small scan's tip would leave it)."""
    rows = []
    (u0, u1), (v0, v1) = surface.domain
    room = 0.5 * min(u1 - u0, v1 - v0) - (tip_radius or 20e-9) - 2e-9  # m the tip may travel from the middle
    slow = [m for m in SLOW_MOTIONS if not m.startswith("slide-") or float(m[6:]) * 1e-9 * (seconds - 0.5) <= room]
    fast = [m for m in FAST_MOTIONS if m != "stroke" or 150e-9 <= room]
    for motion in rng.choice(slow, size=min(slow_runs, len(slow)), replace=False):
        rate = float(rng.choice(RATES))
        source = str(rng.choice(SOURCES))
        run = run_scenario(surface, motion=str(motion), source=source, rate=rate, seconds=seconds,
                           tip_radius=tip_radius)
        rows.append({"surface": name, "kind": "slow", "motion": str(motion), "source": source, "rate_hz": rate,
                     **run.score.as_dict(), "ok": not run.score.buzzes})
    for motion in rng.choice(fast, size=min(fast_runs, len(fast)), replace=False):
        source = str(rng.choice(SOURCES))
        rows.append({"surface": name, "kind": "fast",
                     **rate_convergence(surface, str(motion), source, seconds, tip_radius=tip_radius)})
    for r in rows:
        print(f"{name} {r['kind']} {r['motion']} {r['source']}: {'ok' if r['ok'] else 'FAIL'}"
              + (f" rate error {100 * r['rate_error']:.1f} %" if r["kind"] == "fast" else
                 f" hf {'/'.join(f'{100 * x:.2f}' for x in r['high_frequency_over_normal'])} %"
                 f" rev {sum(r['reversals'])}"), file=sys.stderr)
    return rows


def families(count: int, seed: int, seconds: float, real: bool = True, slow_runs: int = 2,
             fast_runs: int = 1) -> dict:
    """The generated table (``count`` surfaces, seeded) and every real scan, judged."""
    rng = np.random.default_rng(seed)
    rows = []
    for g in generated_surfaces(count, seed):
        rows += judge_surface(g.name, g.surface(), rng, seconds, g.tip_radius, slow_runs, fast_runs)
    if real:
        for path in sorted(p for p in SCANS.iterdir() if p.suffix != ".md") if SCANS.exists() else []:
            try:
                s = prepared_surface(path)[1]
            except Exception as exc:  # noqa: BLE001 - a file the demo cannot prepare: said, not fatal
                rows.append({"surface": path.name, "kind": "unreadable", "ok": None,
                             "error": f"{type(exc).__name__}: {exc}"[:200]})
                continue
            rows += judge_surface(path.name, s, rng, seconds, None, slow_runs, fast_runs)
    judged = [r for r in rows if r["ok"] is not None]
    failed = [r for r in judged if not r["ok"]]
    fast = [r["rate_error"] for r in judged if r["kind"] == "fast"]
    return {"summary": {"generated_surfaces": count, "seed": seed, "real_scans": len({r["surface"] for r in rows})
                        - count, "runs": len(judged), "failed": len(failed),
                        "failed_runs": [f"{r['surface']} {r['kind']} {r['motion']} {r['source']}" for r in failed],
                        "rate_tolerance": RATE_TOLERANCE, "worst_rate_error": max(fast, default=math.nan),
                        "unreadable": [r["surface"] for r in rows if r["ok"] is None]},
            "rows": rows}


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
                    "(and every real scan); --quick: 8 surfaces, no real scans")
    ap.add_argument("--seed", type=int, default=0, help="seed of the generated families")
    ap.add_argument("--bode", metavar="PNG", help="only the transparency estimate; write its Bode plot here")
    args = ap.parse_args()
    if args.families is not None:
        print(json.dumps({"families": families(args.families, args.seed, args.seconds, real=not args.quick)},
                         indent=1))
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
            print(f"{path.name}: tick/VTK {rows[path.name]['tick_over_vtk_median']:.2f}", file=sys.stderr)
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
