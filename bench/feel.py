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
  taps): the same motion at 1 and 10 kHz through the same virtual coupling, the 10 kHz force read
  where the 1 kHz loop sampled the surface (its probe matched along the path), compared at the
  1 kHz ticks (the 5 ms after a contact is made or broken left out; the scale at least 1 % of the
  peak force): rms difference <= 5 % (:data:`arsurf.feel_scenarios.RATE_TOLERANCE`), and energy
  >= -E0 at both rates.

The full table is ``--families 240 --runs 4 2`` (240 generated surfaces and the real scans, 1440
runs on the generated ones, 25.8 M loop ticks). ``--jobs 2`` judges in two processes, ``--out
FILE`` appends each judged run to a JSON-lines file as it comes (units in the keys) and skips the
runs already there (a stopped table resumes), ``--budget S`` starts no run after S seconds,
``--summarize FILE`` prints the pass counts per family, motion, rate and source and the worst runs
of each criterion, ``--compare OLD NEW`` the runs two tables of the same plan pass differently and
the measures of each beyond the pass count (mean rate error, reversals, energy beyond -E0: a change
moves a few runs across each threshold either way). ``--estimate`` prints the size and the time (from the table's own pace when
``--out`` has rows, else a calibration run).

Run: .venv/bin/python bench/feel.py [--quick] [--seconds 3] [--families N [--runs 2 1] [--seed S] [--estimate]
     [--out rows.jsonl] [--jobs 2] [--budget 600]] [--summarize rows.jsonl] [--compare old.jsonl new.jsonl]
     [--vtk-only [--parts] [--scans NAME ...]]
(prints JSON)
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import sys
from pathlib import Path

import numpy as np

from arsurf.assembly import PRESETS
from arsurf.feel_scenarios import (GENERATED_PIXELS, MOTIONS, RATE_TOLERANCE, SOURCES, GeneratedSurface,
                                   generated_surfaces, judge_run, plan_runs, prepared_surface, run_scenario,
                                   synthetic_surface, ticks)

sys.path.insert(0, str(Path(__file__).resolve().parent))
from collision import surface_mesh, vtk_locator  # noqa: E402  (the VTK peer, built the same way in every bench)

SCANS = Path(os.environ.get("ARSURF_REAL_SCANS", Path(__file__).resolve().parents[2] / "shared" / "scans-real"))
REAL = ("Veeco_20160622.003", "sample_0.spm", "sample_0.jpk")


def line(r: dict) -> str:
    """One stderr line per judged run."""
    head = f"{r['surface']} {r['motion']} {r['heading_deg']:.0f}deg {r['source']}"
    if r["kind"] == "fast":
        return (f"{head}: {'ok' if r['ok'] else 'FAIL'} rate error {100 * r['rate_error']:.2f} % (low-passed "
                f"reference {100 * r['low_passed_error']:.1f} %) E/E0 {min(_num(x) for x in r['min_energy_over_E0']):.2f}")
    return (f"{head} {r['rate_hz'] / 1e3:.0f} kHz: {'ok' if r['ok'] else 'FAIL'} hf "
            f"{'/'.join(f'{100 * x:.2f}' for x in r['high_frequency_over_normal'])} % rev {sum(r['reversals'])} "
            f"E/E0 {_num(r['min_energy_over_E0']):.2f} rest {100 * _num(r['rest_error']):.3f} %")


def _num(x) -> float:
    """A number of a row (None, as JSON lines hold NaN, back to NaN)."""
    return math.nan if x is None else float(x)


def _jsonable(v):
    """A row's value for a JSON line: numpy scalars and arrays as Python numbers and lists, NaN as null."""
    if isinstance(v, dict):
        return {k: _jsonable(x) for k, x in v.items()}
    if isinstance(v, (list, tuple, np.ndarray)):
        return [_jsonable(x) for x in v]
    if isinstance(v, (np.bool_, bool)):
        return bool(v)
    if isinstance(v, (np.integer, int)):
        return int(v)
    if isinstance(v, (np.floating, float)):
        return None if math.isnan(v) else float(v)
    return v


def plan_table(count: int, seed: int, real: bool = True, slow_runs: int = 2, fast_runs: int = 1):
    """(runs, unreadable): every planned run of the generated table (``count`` surfaces, seeded) and
    of every real scan the project opens, each with its ``key`` (unique, stable: what a resumed run
    skips), ``family`` (the generator's, or ``real``), ``tip_radius_m`` and how to make its surface
    (``generated``: the generator's parameters, or ``scan``: the file's name)."""
    rng = np.random.default_rng(seed)
    table = [(g.name, g.family, {"generated": dataclasses.asdict(g)}, g.tip_radius, GENERATED_PIXELS * g.pixel)
             for g in generated_surfaces(count, seed)]
    unreadable = {}
    if real:
        for path in sorted(p for p in SCANS.iterdir() if p.suffix != ".md") if SCANS.exists() else []:
            try:
                s = prepared_surface(path)[1]
            except Exception as exc:  # noqa: BLE001 - a file the project cannot open: said, not fatal
                unreadable[path.name] = f"{type(exc).__name__}: {exc}"[:200]
                continue
            (u0, u1), (v0, v1) = s.domain
            table.append((path.name, "real", {"scan": path.name}, float(PRESETS["demo"].tip_radius),
                          min(u1 - u0, v1 - v0)))
    runs = []
    for i, (name, family, make, tip, side) in enumerate(table):
        for j, run in enumerate(plan_runs(name, rng, tip, side, slow_runs, fast_runs)):
            runs.append({"key": f"{seed}:{i}:{j}:{name}", "family": family, "tip_radius_m": tip, **make, **run})
    return runs, unreadable


def add_table_arguments(ap, families: int, runs: tuple[int, int], seed: int) -> None:
    """The arguments of a diagnostic bench that runs a families table's rows again (``bench/feel_field.py``,
    ``bench/feel_pairs.py``): the table, ``--all``, ``--limit`` and the plan it was written with."""
    ap.add_argument("table", help="a families table (JSON lines) written by bench/feel.py --out")
    ap.add_argument("--all", action="store_true", help="every run of its kind, not only the failing ones")
    ap.add_argument("--limit", type=int, default=8, help="at most this many runs (default 8)")
    ap.add_argument("--seed", type=int, default=seed)
    ap.add_argument("--families", type=int, default=families)
    ap.add_argument("--runs", type=int, nargs=2, default=runs)


def table_runs(args, kind: str) -> list[dict]:
    """The planned runs of the rows of ``kind`` (``"slow"`` or ``"fast"``) of ``args.table`` (the
    failing ones, or ``args.all``), at most ``args.limit``, planned as ``args`` says
    (:func:`add_table_arguments`; the real scans fitted only when a row is one). A key the plan
    does not hold: SystemExit, one line."""
    rows = [r for r in read_rows(args.table) if r.get("kind") == kind and (args.all or not r.get("ok"))]
    rows = rows[:max(args.limit, 0)]
    real = any(r.get("family") == "real" for r in rows)
    planned = {r["key"]: r for r in plan_table(args.families, args.seed, real, *args.runs)[0]}
    for row in rows:
        if row.get("key") not in planned:
            raise SystemExit(f"error: {row.get('key')!r} is not in the plan of --seed {args.seed} --families "
                             f"{args.families} --runs {args.runs[0]} {args.runs[1]}: give the table's own")
    return [planned[r["key"]] for r in rows]


_SURFACES: dict = {}


def _surface(run: dict):
    """The surface of a planned run, fitted once per worker process (the last two kept)."""
    key = run.get("scan") or run["surface"]
    if key not in _SURFACES:
        if len(_SURFACES) >= 2:
            _SURFACES.pop(next(iter(_SURFACES)))
        _SURFACES[key] = (prepared_surface(SCANS / run["scan"])[1] if "scan" in run
                          else GeneratedSurface(**run["generated"]).surface())
    return _SURFACES[key]


def judge_planned(run: dict) -> dict:
    """One planned run judged (:func:`arsurf.feel_scenarios.judge_run`), as a JSON-line row (units in
    the names; ``wall_s`` its wall time)."""
    import time

    t0 = time.perf_counter()
    keep = {k: v for k, v in run.items() if k not in ("generated", "scan")}
    options = {"zone_energy": True} if run.get("zone_energy") else {}
    if run.get("zone_energy"):
        options["zone_closed_form"] = run.get("zone_closed_form", True)
    row = judge_run(keep, _surface(run), run["tip_radius_m"], **options)
    return _jsonable({**row, "wall_s": time.perf_counter() - t0})


def read_rows(path) -> list[dict]:
    """The rows of a JSON-lines table (a line cut short by a stopped run is skipped)."""
    rows = []
    if path and Path(path).exists():
        for text in Path(path).read_text().splitlines():
            try:
                rows.append(json.loads(text))
            except json.JSONDecodeError:
                continue
    return rows


def summarize(rows: list[dict], worst: int = 8) -> dict:
    """Pass counts (``"passed/runs"``) per family, motion, loop rate (a rate pair counts as
    ``1+10 kHz``) and source, and the worst runs of each criterion."""
    def count(key):  # "passed/runs" per group
        out = {}
        for r in rows:
            c = out.setdefault(key(r), [0, 0])
            c[0] += bool(r["ok"])
            c[1] += 1
        return {k: f"{a}/{b}" for k, (a, b) in sorted(out.items())}

    slow = [r for r in rows if r["kind"] == "slow"]
    fast = [r for r in rows if r["kind"] == "fast"]

    def top(rs, measure):
        return [line(r) for r in sorted(rs, key=measure, reverse=True)[:worst]]

    return {"runs": len(rows), "pass": sum(bool(r["ok"]) for r in rows),
            "surfaces": len({r["surface"] for r in rows}),
            "by_family": count(lambda r: r["family"]), "by_motion": count(lambda r: r["motion"]),
            "by_rate": count(lambda r: "1+10 kHz" if r["kind"] == "fast" else f"{r['rate_hz'] / 1e3:.0f} kHz"),
            "by_source": count(lambda r: r["source"]),
            "rate_tolerance": RATE_TOLERANCE,
            "worst_rate_error": top(fast, lambda r: r["rate_error"]),
            "worst_high_frequency": top(slow, lambda r: max(r["high_frequency_over_normal"])),
            "most_reversals": top([r for r in slow if sum(r["reversals"])], lambda r: sum(r["reversals"])),
            "lowest_energy": top([r for r in rows if not r["energy_ok"]],
                                 lambda r: -min(_num(x) for x in np.atleast_1d(r["min_energy_over_E0"]))),
            "worst_rest_error": top([r for r in slow if r["rest_error"] is not None], lambda r: r["rest_error"]),
            "failed": [line(r) for r in rows if not r["ok"]]}


def measures(rows: list[dict]) -> dict:
    """The table beyond its pass count: a change to the loop moves a few runs across each threshold
    either way (on the whole table, any change tried moved 3-10 of 1508), so what it did is read in
    these. Rate pairs: mean and median rate error (%) and how many exceed the tolerance; still and
    slow runs: the mean of each run's largest content above 100 Hz (% of the mean normal force), how
    many exceed the buzz limit, reversals summed and the runs with any; every run: how many fail the
    energy criterion (below -E0 beyond the score's tolerance), how many fell below -E0 at all and by
    how much in all (E0)."""
    from arsurf.haptics.feel import BUZZ_LIMIT

    fast = [r for r in rows if r["kind"] == "fast"]
    slow = [r for r in rows if r["kind"] == "slow"]
    rate = np.array([_num(r["rate_error"]) for r in fast])
    high = np.array([max(r["high_frequency_over_normal"]) for r in slow])
    reversals = np.array([sum(r["reversals"]) for r in slow])
    lowest = np.array([min(_num(x) for x in np.atleast_1d(r["min_energy_over_E0"])) for r in rows])
    below = lowest[lowest < -1.0]

    def pct(values, f):
        return round(100.0 * float(f(values)), 3) if len(values) else None

    return {"runs": len(rows), "pass": sum(bool(r["ok"]) for r in rows), "rate_pairs": len(fast),
            "rate_error_mean_percent": pct(rate, np.mean), "rate_error_median_percent": pct(rate, np.median),
            "rate_pairs_beyond_tolerance": int((rate > RATE_TOLERANCE).sum()), "slow_runs": len(slow),
            "slow_high_frequency_mean_percent": pct(high, np.mean),
            "slow_runs_beyond_buzz_limit": int((high > BUZZ_LIMIT).sum()),
            "reversals_summed": int(reversals.sum()), "slow_runs_with_reversals": int((reversals > 0).sum()),
            "runs_failing_energy": sum(not r.get("energy_ok", True) for r in rows),
            "runs_below_minus_E0": int(len(below)), "energy_beyond_minus_E0_summed_over_E0": round(float((below + 1.0).sum()), 3)}


def compare(old: list[dict], new: list[dict]) -> dict:
    """Two tables of the same plan (``--out`` files of the same ``--families``, ``--runs`` and
    ``--seed``) on the runs both hold: the runs ``gained`` and ``lost`` (each as ``old line -> new
    line``, :func:`line`) and the :func:`measures` of each."""
    before = {r["key"]: r for r in old}
    both = [r for r in new if r["key"] in before]
    paired = [before[r["key"]] for r in both]

    def moved(ok):
        return [f"{line(a)} -> {line(b)}" for a, b in zip(paired, both) if bool(b["ok"]) == ok and bool(a["ok"]) != ok]

    return {"runs_compared": len(both), "gained": moved(True), "lost": moved(False),
            "old": measures(paired), "new": measures(both)}


def families(count: int, seed: int, real: bool = True, slow_runs: int = 2, fast_runs: int = 1,
             estimate_only: bool = False, out=None, jobs: int = 1, budget: float = math.inf,
             zone_energy: bool = False, closed_form: bool = True) -> dict:
    """The generated table (``count`` surfaces, seeded) and every real scan the project opens, judged
    in ``jobs`` processes, each row appended to the JSON-lines file ``out`` as it is judged; the
    runs already in ``out`` are skipped (a stopped table resumes where it was). No new run starts
    after ``budget`` s of wall time (the runs under way are dropped, to be done on resuming).
    Prints the size and a time estimate (calibrated on a short run, over ``jobs`` processes)
    first; returns the summary of every row in ``out`` (:func:`summarize`) or of this run's.
    ``zone_energy``: every model's contact the energy of the whole tip, ``closed_form`` with its closed form where
    trusted (default; False: the lattice's sum everywhere; each row says which)."""
    import time

    runs, unreadable = plan_table(count, seed, real, slow_runs, fast_runs)
    if zone_energy:
        runs = [{**r, "zone_energy": True, "zone_closed_form": closed_form} for r in runs]
    planned = {r["key"]: r for r in runs}
    judged = [r for r in read_rows(out) if r.get("key") in planned]
    done = {r["key"] for r in judged}
    todo = [r for r in runs if r["key"] not in done]
    total, left = sum(ticks(r) for r in runs), sum(ticks(r) for r in todo)
    if judged:  # the table's own pace so far: wall time per tick of a run, set-up and fits included
        per_tick = sum(r["wall_s"] for r in judged) / sum(ticks(planned[r["key"]]) for r in judged)
    elif todo and estimate_only:  # a short calibration run on the table's first generated surface
        g = generated_surfaces(1, seed)[0]
        per_tick = _tick_cost(g.surface(), g.tip_radius)
    else:
        per_tick = 0.0
    estimate = {"surfaces": len({r["surface"] for r in runs}), "generated_surfaces": count,
                "real_scans": len({r["surface"] for r in runs if r["family"] == "real"}),
                "runs": len(runs), "runs_done": len(runs) - len(todo), "loop_ticks": total, "loop_ticks_left": left,
                "jobs": jobs, "per_tick_us": per_tick * 1e6, "estimated_seconds": left * per_tick / max(jobs, 1)}
    if not per_tick:
        print(f"families: {estimate['surfaces']} surfaces, {len(runs)} runs, {total} ticks (the time: --estimate, or"
              f" a resumed --out)", file=sys.stderr)
    else:
        print(f"families: {estimate['surfaces']} surfaces, {len(runs)} runs ({len(runs) - len(todo)} done), {left} "
              f"of {total} ticks left: about {estimate['estimated_seconds']:.0f} s in {jobs} process(es) at "
              f"{per_tick * 1e6:.0f} us of wall time per tick and process "
              f"({'the judged runs' if judged else 'a calibration run'} on this machine, now)", file=sys.stderr)
    if estimate_only:
        return {"estimate": estimate}
    rows, t0, complete, pool = [], time.perf_counter(), False, None
    import signal

    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))  # a stopped table still stops its workers (below)
    sink = open(out, "a") if out else None  # noqa: SIM115 - closed below, appended to as rows come
    if sink and sink.tell() > 0 and not Path(out).read_bytes().endswith(b"\n"):
        sink.write("\n")  # a line cut short by a stopped run stays on its own line (skipped when read)
    try:
        if jobs > 1:
            import multiprocessing

            pool = multiprocessing.get_context("spawn").Pool(jobs)
            results = pool.imap_unordered(judge_planned, todo, chunksize=1)  # streamed as judged
        else:
            pool, results = None, (judge_planned(r) for r in todo)
        for row in results:
            rows.append(row)
            print(line(row), file=sys.stderr)
            if sink:
                sink.write(json.dumps(row) + "\n")
                sink.flush()
            if time.perf_counter() - t0 > budget:
                print(f"families: stopped after {budget:.0f} s ({len(rows)} runs judged); run again to resume",
                      file=sys.stderr)
                break
        else:
            complete = True
    finally:
        if pool is not None:
            if complete:
                pool.close()  # every run done: the workers end on their own
            else:
                pool.terminate()  # stopped (budget, fault, interrupt): the runs under way are dropped
            pool.join()
        if sink:
            sink.close()
    table = [r for r in read_rows(out) if r.get("key") in planned] if out else rows
    return {"summary": {**estimate, "seed": seed, "runs_judged_now": len(rows), "unreadable": unreadable,
                        **summarize(table)}, "rows": rows}


def _tick_cost(surface, tip_radius) -> float:
    """Seconds per loop tick of a scenario on ``surface`` (a 1.2 s press at 5 kHz, after a warm-up)."""
    import time

    run_scenario(surface, motion="press", rate=1000.0, seconds=1.2, tip_radius=tip_radius)
    t0 = time.perf_counter()
    run_scenario(surface, motion="press", rate=5000.0, seconds=1.2, tip_radius=tip_radius)
    return (time.perf_counter() - t0) / 6000.0


def vtk_ratio(surface, rounds: int = 3, zone_energy: bool = False, closed_form: bool = True) -> dict:
    """Tick median vs one VTK closest-point query at the same tip positions (slide at 100 nm/s;
    ``zone_energy``: the model's contact the energy of the whole tip, ``closed_form`` with its closed form where
    trusted, the default).

    Two timings of the peer, same run: ``vtk_query_median_us`` times the round's tip positions
    back to back after the round (the peer alone in a tight loop: its locator stays in the CPU's
    caches), ``vtk_interleaved_median_us`` times one query right after each tick at that tick's
    tip, inside the loop's own iteration (device, recording), as the tick itself is timed."""
    pts, faces = surface_mesh(surface)
    _build, query, one = vtk_locator(pts, faces)
    ticks, queries, inter = [], [], []
    for _ in range(rounds):
        beside = []
        run = run_scenario(surface, motion="slide-100", source="blended", seconds=2.0, zone_energy=zone_energy,
                           zone_closed_form=closed_form,
                           after_tick=lambda tip, probe, model: beside.append(one((float(tip[0]), float(tip[1]), float(tip[2])))))
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
    ap.add_argument("--parts", action="store_true", help="with --vtk-only: also where each scan's tick goes "
                    "(bench/_tick_parts.py: model tick, collision, contact behind the coupling, in compiled loops)")
    ap.add_argument("--scans", nargs="+", metavar="NAME", help="with --vtk-only: only these scans of the folder")
    ap.add_argument("--motions", nargs="+", choices=MOTIONS, help="only these motions")
    ap.add_argument("--sources", nargs="+", choices=SOURCES, help="only these sources")
    ap.add_argument("--rates", nargs="+", type=float, help="only these loop rates, Hz")
    ap.add_argument("--families", type=int, metavar="N", help="only the generated families: N surfaces "
                    "(and every real scan; --quick: no real scans); the full table is --families 240 --runs 4 2")
    ap.add_argument("--runs", type=int, nargs=2, default=(2, 1), metavar=("SLOW", "FAST"),
                    help="runs per surface of the families: still/slow motions, rate-convergence pairs")
    ap.add_argument("--estimate", action="store_true", help="with --families: only the table size and time estimate")
    ap.add_argument("--seed", type=int, default=0, help="seed of the generated families")
    ap.add_argument("--out", metavar="JSONL", help="with --families: append each judged run here as a JSON line; "
                    "the runs already in it are skipped (resume)")
    ap.add_argument("--zone-energy", action="store_true",
                    help="with --families or --vtk-only: the models' contact the energy of the whole tip "
                         "(ARModel zone_energy)")
    ap.add_argument("--zone-sum", action="store_true",
                    help="with --zone-energy: the lattice's sum everywhere, not its closed form where trusted "
                         "(ARModel zone_closed_form=False)")
    ap.add_argument("--jobs", type=int, default=1, help="with --families: processes judging runs (default 1)")
    ap.add_argument("--budget", type=float, default=math.inf, metavar="SECONDS",
                    help="with --families: start no new run after this wall time (resume later with --out)")
    ap.add_argument("--summarize", metavar="JSONL", help="only the pass counts and worst runs of a table written by --out")
    ap.add_argument("--compare", nargs=2, metavar=("OLD", "NEW"), help="only the runs two tables written by --out "
                    "(same plan) pass differently, and the measures of each beyond the pass count")
    ap.add_argument("--bode", metavar="PNG", help="only the transparency estimate; write its Bode plot here")
    args = ap.parse_args()
    if args.summarize:
        rows = read_rows(args.summarize)
        if not rows:
            ap.error(f"--summarize: no judged runs in {args.summarize!r} (write them with --families N --out FILE)")
        print(json.dumps({"families": {"summary": summarize(rows)}}, indent=1))
        return
    if args.compare:
        tables = [read_rows(f) for f in args.compare]
        for f, rows in zip(args.compare, tables):
            if not rows:
                ap.error(f"--compare: no judged runs in {f!r} (write them with --families N --out FILE)")
        print(json.dumps({"families": {"compare": compare(*tables)}}, indent=1))
        return
    if args.families is not None:
        if args.families < 0 or args.jobs < 1 or not args.budget > 0:
            ap.error(f"--families must be >= 0, --jobs >= 1 and --budget > 0 s (got {args.families}, {args.jobs}, "
                     f"{args.budget})")
        print(json.dumps({"families": families(args.families, args.seed, real=not args.quick, slow_runs=args.runs[0],
                                               fast_runs=args.runs[1], estimate_only=args.estimate, out=args.out,
                                               jobs=args.jobs, budget=args.budget,
                                               zone_energy=args.zone_energy, closed_form=not args.zone_sum)},
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
            if args.scans and path.name not in args.scans:
                continue
            try:
                s = surfaces.get(path.name) or prepared_surface(path)[1]
            except Exception as exc:  # noqa: BLE001 - a file the demo cannot prepare: said, not fatal
                rows[path.name] = {"error": f"{type(exc).__name__}: {exc}"[:200]}
                continue
            rows[path.name] = {"control_points": list(s.shape), **vtk_ratio(s, zone_energy=args.zone_energy,
                                                                                     closed_form=not args.zone_sum)}
            r = rows[path.name]
            if args.parts:
                from _tick_parts import tick_parts

                r["parts_us"] = tick_parts(s)
                print(f"{path.name}: parts {json.dumps({k: round(v, 2) for k, v in r['parts_us'].items()})}",
                      file=sys.stderr)
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
