"""Benchmark: the full haptic tick over pitch x tip radius x depth, and the real-time scheduler with it.

Table (issue 28): HapticLoop.step (position scaling, model tick with the dent on, filters,
passivity, safety) for every pixel pitch (0.1-8 nm) x tip radius (2-50 nm) x depth on the
rough 256 x 256 surface of bench/_tick_table.py, the stylus sliding the tip 0.01 nm per tick:
median and p99 (a coarse grid by default, --full for the whole table).
Then the tick on a 512x512 sinusoid (median, p99 after warm-up), then the achieved rate,
jitter and overruns of the Scheduler running that tick (the device read into one reused sample)
at 1 kHz and 10 kHz under the ordinary policy (the default), and at 10 kHz with the loop thread
under SCHED_FIFO at the live loop's default priority (where granted: ``realtime_priority`` says).
Overruns <= 0.1 % at 10 kHz is the target (issue #13); issue 28 adds skipped slots (with the
overruns, <= 0.1 % of the nominal ticks) and the longest gap between two ticks (<= 1 ms).
Row ``multi_contact`` (issue 27): the model tick (``ARModel.tick``, dent on) of a 20 nm tip sliding
0.01 nm per tick through valleys narrower than itself (a 12 nm sinusoid: two contacts) against the
same tick on a 160 nm sinusoid (one contact), and one bare VTK ``vtkStaticCellLocator``
closest-point query at the same tip positions, in interleaved rounds (``--multi-only``: that row),
and the tick of a 6 nm tip on a rough power-law patch with ~10 contacts (``many_contacts``, and
where its time goes: ``many_contacts_parts_us``).
--lockup-check adds a SCHED_FIFO loop whose step never fits its period, pinned to one core.
Each table cell traces its ticks (bench/_tick_table.py ``traced``): wall and thread-CPU time per
tick, and for the ticks over 100 us whether they were preempted, ran the garbage collector or
moved the net (a sync inside the tick).
--diagnose runs only traced scheduler runs (an empty step, the 512x512 tick without and with the
dent, both policies) and gives every lost slot and every gap > 1 ms its cause (docs/scheduler.rst).
Run: .venv/bin/python bench/haptic_loop.py [--seconds 10] [--full] [--no-table] [--multi-only] [--lockup-check]
     [--table-only] [--pitches 0.25,2] [--tips 20] [--depths 1]   (prints JSON)
     .venv/bin/python bench/haptic_loop.py --diagnose [--seconds 8] [--policies fifo] [--workloads tick_dent]
"""
from __future__ import annotations

import argparse
import sys
from functools import partial
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _tick_table as tt  # noqa: E402
from _timing import best_round, emit, round_ratio, stats, time_calls  # noqa: E402
from collision import surface_mesh, vtk_locator  # noqa: E402

from arsurf.contact.maugis_dugdale import MaugisDugdale  # noqa: E402
from arsurf.force.cantilever import Cantilever  # noqa: E402
from arsurf.haptics.device import DeviceState  # noqa: E402
from arsurf.haptics.loop import L_F_PROBE, HapticLoop, LoopConfig  # noqa: E402
from arsurf.haptics.scheduler import Scheduler  # noqa: E402
from arsurf.haptics.virtual_device import HandModel, VirtualDevice  # noqa: E402
from arsurf.contact import multi_contact as mc  # noqa: E402
from arsurf.model import M_IN_CONTACT, S_CONTACTS, ARModel  # noqa: E402
from arsurf.scan.synthetic import rough, sinusoid  # noqa: E402
from arsurf.spline.fit import fit_surface  # noqa: E402

R = 20e-9


def build(rate: float, deform: bool = True):
    s = fit_surface(sinusoid((512, 512), 4e-9, 5e-9, 160e-9))
    model = ARModel(s, R, MaugisDugdale(R, 50e9, 0.05), Cantilever(450e-6, 50e-6, 2.5e-6, 15e-6, 169e9, 0.27),
                    deform=deform)
    c = (1000e-9, 1000e-9)
    origin = (*c, s.evaluate(*c)[2] + R + 3e-9)
    # the hand presses 8 nm in and slides 40 nm in circles: contact most of the time
    def traj(t):
        return np.array([2e-3 * np.cos(3 * t), 2e-3 * np.sin(3 * t), -0.8e-3])
    dev = VirtualDevice(dt=1.0 / rate, hand=HandModel(traj)).open()
    loop = HapticLoop.direct(model, dev.info, origin, config=LoopConfig(rate=rate, source="blended", signal_noise=1e-8))
    return dev, loop


def table_cell(surface, tip: float, depth: float, ticks: int) -> dict:
    """HapticLoop.step at 10 kHz on ``surface``, the stylus sliding the tip 0.01 nm per tick
    from ``depth`` below touching (:func:`_tick_table.start`)."""
    model = tt.model_on(surface, tip)
    dev = VirtualDevice(dt=1e-4).open()
    scale = 1e-5  # probe metres per stylus metre (HapticLoop.direct's default)
    loop = HapticLoop.direct(model, dev.info, tuple(tt.start(surface, tip, depth)), scale=scale,
                             config=LoopConfig(rate=10000.0, source="simulated"))
    st = DeviceState(np.zeros(3), np.zeros(3), 0, 0.0)
    k = [0]

    def tick():
        k[0] += 1
        st.position[0] = tt.STEP * (k[0] % 80) / scale
        st.timestamp = k[0] * 1e-4
        loop.step(st, st.timestamp)

    for _ in range(300):  # the ramp-in and the contact settle
        tick()
    row = tt.traced(tick, ticks, model._deformer, model=model)  # median, p99 and where the slow ticks' time went
    row["in_contact"] = bool(model.out[M_IN_CONTACT])
    dev.close()
    return row


def tick_table(full: bool, ticks: int, pitches=None, tips=None, depths=None) -> dict:
    """The tick over pitch x tip radius x depth (medians, p99), and the goals of issue 28
    (``pitches``, ``tips``, ``depths`` in nm: a subset of the cells; default the coarse or --full grid)."""
    rows = []
    for p in pitches or (tt.FULL_PITCHES_NM if full else tt.PITCHES_NM):
        s = tt.rough_surface(p * 1e-9)
        for r in tips or (tt.FULL_TIPS_NM if full else tt.TIPS_NM):
            for d in depths or (tt.FULL_DEPTHS_NM if full else tt.DEPTHS_NM):
                rows.append({"pitch_nm": p, "tip_radius_nm": r, "depth_nm": d, **table_cell(s, r * 1e-9, d * 1e-9, ticks)})
                x = rows[-1]
                print(f"pitch {p} nm, R {r} nm, depth {d} nm: {x['median_us']:.1f} us, p99 {x['p99_us']:.0f} us "
                      f"(cpu p99 {x['cpu_p99_us']:.0f} us; >100 us: {x['ticks_over_100us']}, preempted "
                      f"{x['over_100us_preempted']}, switched out {x['over_100us_switched_out']}, "
                      f"collision list rebuilt {x['over_100us_collision_rebuilt_list']} (of {x['ticks_collision_rebuilt_list']} "
                      f"rebuilds, median {x['collision_rebuilt_tick_median_us']:.0f} us), "
                      f"gc {x['over_100us_with_gc']}, syncs {x['ticks_with_net_sync']}; collision cells median "
                      f"{x['collision_cells_median']:.0f} / p99 {x['collision_cells_p99']:.0f}, Newton iterations "
                      f"{x['collision_newton_iterations_median']:.0f} / {x['collision_newton_iterations_p99']:.0f})",
                      file=sys.stderr)
    med = [r["median_us"] for r in rows]
    p99 = [r["p99_us"] for r in rows]

    def at(p, r):
        return float(np.median([x["median_us"] for x in rows if x["pitch_nm"] == p and x["tip_radius_nm"] == r]))

    summary = {"cells": len(rows), "max_median_us": max(med), "max_p99_us": max(p99),
               "cells_over_40us_median": sum(m > 40 for m in med), "cells_over_100us_p99": sum(m > 100 for m in p99),
               "max_cpu_p99_us": max(r["cpu_p99_us"] for r in rows),
               "ticks_with_net_sync": sum(r["ticks_with_net_sync"] for r in rows)}
    if {0.25, 2.0} <= {r["pitch_nm"] for r in rows} and any(r["tip_radius_nm"] == 20.0 for r in rows):
        summary["R20_median_0.25nm_over_2nm"] = at(0.25, 20.0) / at(2.0, 20.0)
    return {"summary": summary, "rows": rows}


def _slide(period: float, ticks: int):
    """A model on a sinusoid of ``period`` (1 nm pixels, 2 nm amplitude) and the tip centres of a
    slide 0.01 nm per tick along x, pressed 0.4 nm into the valley bottom's slopes."""
    s = fit_surface(sinusoid((96, 96), 1e-9, 2e-9, period))
    model = ARModel(s, R, MaugisDugdale(R, 50e9, 0.05), Cantilever(450e-6, 50e-6, 2.5e-6, 15e-6, 169e9, 0.27))
    x0, y0 = 3.0 * period / 4.0 + (2 * period if period < 40e-9 else 0.0), 48e-9  # a valley bottom
    t = model.step((x0, y0, 40e-9))
    z = 40e-9 - t.distance + R - 0.4e-9
    model.reset()
    x = x0 + 0.01e-9 * (np.arange(ticks) % 400 - 200)
    return s, model, np.column_stack([x, np.full(ticks, y0), np.full(ticks, z)])


def _rough_patch(ticks: int):
    """A 6 nm tip pressed 4 nm into a seeded power-law surface (0.5 nm rms, 2.8 nm correlation
    length, 0.28 nm pixels: the feel table's small-tip families) behind a 5 N/m coupling, sliding
    0.004 nm per tick: about ten minima in reach (9.6 on average, up to 11)."""
    r = 6e-9
    scan = rough((72, 72), 0.28e-9, rms=0.5e-9, correlation_length=2.8e-9, spectrum="power-law", seed=3)
    s = fit_surface(scan)
    model = ARModel(s, r, MaugisDugdale(r, 50e9, 0.05), Cantilever(450e-6, 50e-6, 2.5e-6, 15e-6, 169e9, 0.27),
                    coupling_stiffness=5.0)
    c = 36 * 0.28e-9
    z = float(scan.heights[28:44, 28:44].max()) + r - 4e-9
    x = c + 0.004e-9 * (np.arange(ticks) % 400 - 200)
    return s, model, np.column_stack([x, c + 0.3 * (x - c), np.full(ticks, z)])


def tick_parts(model: ARModel, points) -> dict:
    """Where a several-contact tick goes (medians, us): after each whole tick at a point, its parts
    called one by one from Python on a copy of the state the tick started from (each adds ~0.2 us of
    call): the collision (the global closest point), finding the contacts, weighing them, the lift
    behind the coupling and the sideways step."""
    from time import perf_counter_ns as clock

    from arsurf import model as am
    from arsurf.contact import projection as pj
    from arsurf.contact.maugis_dugdale import md_zone_from_depth_kernel

    a = dict(zip(am.MODEL_ARGS, model.kernel_args()))
    state, coll, ev, fr = a["model_state"], a["coll"], a["ev"], a["friction"]
    work = np.empty(mc.DISCOVERY_WORK)
    rest, ku, kv, law, r = a["live_rest"], a["ku"], a["kv"], model.contact.kernel_args, model.tip_radius
    m = am.CONTACT_MARGIN * law[0]
    t = {k: [] for k in ("tick", "collision", "find_contacts", "weigh_contacts", "lift", "sideways_step")}

    def timed(name, f, *args):
        t0 = clock()
        out = f(*args)
        t[name].append((clock() - t0) * 1e-3)
        return out

    for p in points:
        before = state.copy()
        timed("tick", model.tick, p)
        after = state.copy()
        state[:] = before
        x, y, z = (float(v) for v in p)
        timed("collision", pj.collide_any, a["proj"], x, y, z, r, state[am.S_HINT_U], state[am.S_HINT_V], coll)
        n = timed("find_contacts", mc.find_contacts_kernel, rest, ku, kv, ev, x, y, z, r, fr[am.F_JUMP_OUT] - m, m,
                  state[am.S_HINT_U], state[am.S_HINT_V], state, S_CONTACTS, coll, work)
        zone = md_zone_from_depth_kernel(coll[pj.OUT_DEPTH], *law)
        timed("weigh_contacts", mc.weigh_contacts_kernel, rest, ku, kv, ev, x, y, z, r, m, zone, fr[am.F_JUMP_OUT],
              state, S_CONTACTS, n)
        nx, ny, nz = mc.total_normal_kernel(state, S_CONTACTS, n, fr[am.F_JUMP_OUT], m)
        lift, _, fx, fy, fz = timed("lift", mc.coupled_lift_kernel, state, S_CONTACTS, n, nx, ny, nz, fr[am.F_COUPLING],
                                    True, state[S_CONTACTS + mc.T_LIFT], fr[am.F_JUMP_OUT], m, *law)[:5]
        timed("sideways_step", mc.coupled_offset_kernel, state, S_CONTACTS, n, nx, ny, nz, fr[am.F_COUPLING], lift,
              fx, fy, fz, fr[am.F_JUMP_OUT], m, *law)
        state[:] = after
    return {k: float(np.median(v)) for k, v in t.items()}


def multi_contact_row(rounds: int = 7, ticks: int = 2000) -> dict:
    """The model tick with several contacts vs one, and one VTK closest-point query, interleaved;
    and a tip resting on a rough patch's many minima (``many_contacts``)."""
    out = {}
    cases = {"one_contact": _slide(160e-9, ticks), "multi_contact": _slide(12e-9, ticks),
             "many_contacts": _rough_patch(ticks)}
    times = {k: [] for k in cases}
    vtk_times = []
    counts = {}
    for name, (s, model, pts) in cases.items():
        for p in pts[:50]:  # warm-up: compile, settle the contact
            model.tick(p)
        c = []
        for p in pts:
            model.tick(p)
            c.append(model.state[S_CONTACTS + mc.T_COUNT])
        counts[name] = {"mean_contacts": float(np.mean(c)), "max_contacts": int(np.max(c))}
    s, _, pts = cases["multi_contact"]
    _build, query, _one = vtk_locator(*surface_mesh(s))
    clock = __import__("time").perf_counter_ns
    for _ in range(rounds):
        for name, (_, model, p) in cases.items():
            dt = np.empty(len(p))
            for k, q in enumerate(p):
                t0 = clock()
                model.tick(q)
                dt[k] = clock() - t0
            times[name].append(dt * 1e-9)
        vtk_times.append(query(pts)[0])
    for name in cases:
        out[name] = {**best_round(times[name]), **counts[name]}
    out["vtk_closest_point"] = best_round(vtk_times)
    out["multi_over_one_contact"] = round_ratio(times["multi_contact"], times["one_contact"])
    out["multi_over_vtk"] = round_ratio(times["multi_contact"], vtk_times)
    out["many_over_one_contact"] = round_ratio(times["many_contacts"], times["one_contact"])
    _, model, pts = cases["many_contacts"]
    out["many_contacts_parts_us"] = tick_parts(model, pts)
    return out


def _timing_row(d: dict, rate: float) -> dict:
    """A scheduler's TimingStats as the bench reports them: times in us, the fractions of the goals."""
    for k in list(d):
        if k.startswith(("compute", "period", "jitter", "longest_gap", "spin_max", "margin_max")):
            d[k + "_us"] = d.pop(k) * 1e6
    nominal = rate * d["duration"]
    d["overrun_fraction"] = d["overruns"] / max(d["ticks"], 1)
    d["skipped_fraction_of_nominal"] = d["skipped"] / nominal
    d["overruns_and_skipped_fraction_of_nominal"] = (d["overruns"] + d["skipped"]) / nominal
    d["goal_met"] = d["overruns_and_skipped_fraction_of_nominal"] <= 1e-3 and d["longest_gap_us"] <= 1000.0
    return d


def scheduler_runs(seconds: float, configs=None) -> dict:
    """The Scheduler running the 512 x 512 tick (device read into one reused sample): 1 kHz and
    10 kHz under the ordinary policy, 10 kHz with the loop thread under SCHED_FIFO at the live
    loop's default priority (where granted: ``realtime_priority`` says). Issue 28's goal at
    10 kHz: overruns plus skipped slots <= 0.1 % of the nominal ticks and no gap between two
    ticks above 1 ms, under both policies; ``awake_max`` is the loop thread's largest share of
    a second awake (the kernel throttles a SCHED_FIFO thread above 0.95), ``cpu_share`` its CPU
    time over the run. ``configs``: (rate Hz, priority) pairs, default those three."""
    from arsurf.haptics.scheduler import DEFAULT_REALTIME_PRIORITY

    out = {}
    for rate, priority in configs or ((1000.0, 0), (10000.0, 0), (10000.0, DEFAULT_REALTIME_PRIORITY)):
        dev, loop = build(rate)
        loop.warm_up()
        sched = Scheduler(loop.scheduler_step, loop, rate=rate, source=partial(dev.read_state, DeviceState()),
                          sink=dev.command_force, priority=priority)
        d = _timing_row(sched.run_for(seconds).as_dict(), rate)
        out[f"scheduler_{int(rate)}Hz_{seconds:g}s_{'fifo' if priority else 'ordinary'}"] = d
        print(f"{rate:g} Hz priority {priority}: overruns+skipped {100 * d['overruns_and_skipped_fraction_of_nominal']:.3f} %,"
              f" longest gap {d['longest_gap_us']:.0f} us, worst second awake {d['awake_max']:.2f}, on the CPU "
              f"{d['cpu_max']:.2f}", file=sys.stderr)
    return out


def diagnose(seconds: float, rate: float = 10000.0, policies=("ordinary", "fifo"),
             workloads=("empty_step", "tick_no_dent", "tick_dent")) -> dict:
    """Where the lost slots and the long gaps come from: for each policy, ``seconds`` at
    ``rate`` of an empty step (what the machine and the pacer cost), of the 512 x 512 tick with
    the dent off and with it on, each with a per-tick trace (:func:`explain_trace`: every lost
    slot and every gap > 1 ms given one cause). Also checks that no cyclic garbage collection
    ran in the loop (the scheduler pauses the collector)."""
    import gc

    from arsurf.haptics.scheduler import DEFAULT_REALTIME_PRIORITY, explain_trace

    out = {}
    n = int(seconds * rate) + 1000
    for policy in policies:
        priority = DEFAULT_REALTIME_PRIORITY if policy == "fifo" else 0
        for what in workloads:
            if what == "empty_step":
                sched = Scheduler(lambda s, i, d: None, None, rate=rate, priority=priority, trace=n)
            else:
                dev, loop = build(rate, deform=what == "tick_dent")
                loop.warm_up()
                sched = Scheduler(loop.scheduler_step, loop, rate=rate, source=partial(dev.read_state, DeviceState()),
                                  sink=dev.command_force, priority=priority, trace=n)
            collections = sum(g["collections"] for g in gc.get_stats())
            d = _timing_row(sched.run_for(seconds).as_dict(), rate)
            row = {k: d[k] for k in ("realtime_priority", "ticks", "overruns", "skipped", "longest_gap_us",
                                     "overruns_and_skipped_fraction_of_nominal", "awake_max", "cpu_max", "goal_met")}
            row["gc_collections_during_run"] = sum(g["collections"] for g in gc.get_stats()) - collections
            row["trace"] = explain_trace(sched.trace, sched.pacer.period)
            out[f"{policy}_{what}"] = row
            t = row["trace"]
            print(f"{policy} {what}: lost {100 * d['overruns_and_skipped_fraction_of_nominal']:.3f} % {t['lost']}, "
                  f"gaps>1ms {t['gaps_over_1ms']}, longest {d['longest_gap_us']:.0f} us, work p99 "
                  f"{t['work']['p99_us']:.0f} us, oversleep p99 "
                  f"{(t['oversleep'] or {}).get('p99_us', 0):.0f} us", file=sys.stderr)
    return out


def fifo_lockup_check(seconds: float = 3.0) -> dict:
    """Can a SCHED_FIFO loop hold a core? Its step busy-waits 1.5 periods of a 1 kHz loop (it
    never fits), the loop thread pinned to one core: with the pacer's least sleep per period
    (``FIFO_IDLE_SHARE``) and without it (the wait before this change, which slept only when time
    was left). ``cpu_share`` is what the loop thread took of its core (the rest went to the
    machine's other work there); without the least sleep the kernel's throttling is what stops
    it, ~50 ms each second (``longest_gap_us``)."""
    import os
    import time

    from arsurf.haptics import scheduler as sched_mod

    out = {}
    for name, least in (("idle_share", sched_mod.FIFO_IDLE_SHARE), ("no_idle_share", 0.0)):
        pinned = []

        def step(state, inputs, dt):
            if not pinned:
                os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})  # this thread, one core
                pinned.append(True)
            end = time.perf_counter_ns() + 1_500_000
            while time.perf_counter_ns() < end:
                pass

        old = sched_mod.FIFO_IDLE_SHARE
        sched_mod.FIFO_IDLE_SHARE = least
        try:
            s = Scheduler(step, None, rate=1000.0, priority=sched_mod.DEFAULT_REALTIME_PRIORITY)
            d = s.run_for(seconds).as_dict()
        finally:
            sched_mod.FIFO_IDLE_SHARE = old
        out[name] = {k: d[k] for k in ("realtime_priority", "ticks", "overruns", "skipped", "awake_max", "cpu_max",
                                        "cpu_share")}
        out[name]["longest_gap_us"] = d["longest_gap"] * 1e6
        print(f"lockup check {name}: cpu share {d['cpu_share']:.3f} (worst second {d['cpu_max']:.3f}), "
              f"awake max {d['awake_max']:.3f}, "
              f"longest gap {d['longest_gap'] * 1e6:.0f} us", file=sys.stderr)
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--full", action="store_true", help="the whole pitch x tip x depth table (several minutes)")
    ap.add_argument("--no-table", action="store_true", help="skip the pitch x tip x depth table")
    ap.add_argument("--ticks", type=int, default=3000, help="ticks timed per table cell")
    ap.add_argument("--multi-only", action="store_true", help="only the multi-contact row (issue 27)")
    ap.add_argument("--pitches", help="table cells: pitches in nm, comma-separated (default the grid's)")
    ap.add_argument("--tips", help="table cells: tip radii in nm, comma-separated")
    ap.add_argument("--depths", help="table cells: depths in nm, comma-separated")
    ap.add_argument("--table-only", action="store_true", help="only the pitch x tip x depth table")
    ap.add_argument("--lockup-check", action="store_true", help="also run a SCHED_FIFO loop whose step never fits "
                    "its period, pinned to one core, with and without the least sleep per period (2 x 3 s)")
    ap.add_argument("--diagnose", action="store_true", help="only the traced runs (diagnose()): an empty step, the "
                    "tick without and with the dent, both policies, --seconds each, at --rate")
    ap.add_argument("--rate", type=float, default=10000.0, help="the rate of --diagnose, Hz")
    ap.add_argument("--policies", default="ordinary,fifo", help="the policies of --diagnose (ordinary, fifo)")
    ap.add_argument("--workloads", default="empty_step,tick_no_dent,tick_dent", help="the steps of --diagnose")
    args = ap.parse_args()
    if args.multi_only:
        emit("haptic_loop", {"multi_contact": multi_contact_row()})
        return
    if args.diagnose:
        emit("haptic_loop", {"diagnose": diagnose(args.seconds, args.rate, args.policies.split(","),
                                                  args.workloads.split(","))})
        return
    table = None if args.no_table else tick_table(
        args.full, args.ticks, tt.parse_cells(args.pitches, ()), tt.parse_cells(args.tips, ()),
        tt.parse_cells(args.depths, ()))
    if args.table_only:
        emit("haptic_loop", {"tick_table": table})
        return
    dev, loop = build(1000.0)
    st = dev.read_state()

    def tick():
        loop.step(st, st.timestamp)

    for _ in range(3000):  # warm-up on the real trajectory
        s = dev.read_state()
        dev.command_force(loop.step(s, s.timestamp))
    st = dev.read_state()
    results = {"tick_table": table, "multi_contact": multi_contact_row(), "tick_512x512_python_call": stats(time_calls(tick, 20000)),
               "in_contact_during_timing": bool(loop.out[L_F_PROBE + 2] > 0)}
    results.update(scheduler_runs(args.seconds))
    if args.lockup_check:
        results["fifo_lockup_check"] = fifo_lockup_check()
    emit("haptic_loop", results)


if __name__ == "__main__":
    main()
