"""Benchmark of the haptic building blocks and the scheduler (prints JSON).

Per block: the cost of one call of its numba kernel inside a compiled loop (what a compiled
pipeline tick pays), and of one call of its Python API (what a Python tick pays), medians and p99
over batches, with the peers timed in the same run (scipy's per-sample ``sosfilt`` for the
filter). Then a chain of the blocks (device read -> position map -> filter -> force-position
coupling -> safety -> device command) per tick, in Python and as one compiled function. Then the
scheduler with a trivial step at 1 kHz and 10 kHz for ``--seconds`` each (default 3): achieved
rate, overruns, skipped slots, compute time and period jitter.

Run: ``python bench/haptic_blocks.py [--seconds 3] [--quick]``
"""
from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import time

import numpy as np
from numba import njit

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

from arsurf.haptics.coupling import ForcePositionCoupling, fp_step  # noqa: E402
from arsurf.haptics.gains import suggest_gains  # noqa: E402
from arsurf.haptics.filters import ButterworthLowPass, LowPass, lowpass1_step, sos_step  # noqa: E402
from arsurf.haptics.safety import SafetyLayer, safety_step  # noqa: E402
from arsurf.haptics.scaling import PositionScaling, position_map_step  # noqa: E402
from arsurf.haptics.scheduler import Scheduler  # noqa: E402
from arsurf.haptics.virtual_device import VirtualDevice, virtual_device_advance  # noqa: E402

DT = 1e-3
M, BV, AF, AD = 1 / 300, 1 / 30, 1e7, 1e5


def summary_ns(samples_ns) -> dict:
    a = np.asarray(samples_ns, dtype=np.float64)
    return {"median_ns": float(np.median(a)), "p99_ns": float(np.percentile(a, 99)), "n": int(a.size)}


def time_python(fn, n_batches: int, batch: int) -> dict:
    """Per-call time of ``fn()`` (Python call), batches of ``batch`` calls."""
    for _ in range(batch):
        fn()
    out = []
    pc = time.perf_counter_ns
    for _ in range(n_batches):
        t0 = pc()
        for _ in range(batch):
            fn()
        out.append((pc() - t0) / batch)
    return summary_ns(out)


def time_compiled(loop, n_batches: int, batch: int) -> dict:
    """Per-call time of a kernel inside a compiled loop ``loop(batch)``."""
    loop(10)
    out = []
    pc = time.perf_counter_ns
    for _ in range(n_batches):
        t0 = pc()
        loop(batch)
        out.append((pc() - t0) / batch)
    return summary_ns(out)


# -- compiled loops around each kernel (the state keeps evolving, inputs vary per call) -------
@njit(cache=True)
def _loop_lowpass(n, alpha, y, out):
    x = np.empty(3)
    s = 0
    for k in range(n):
        x[0] = math.sin(0.01 * k)
        x[1] = 1.0
        x[2] = -1.0
        s += lowpass1_step(alpha, y, x, out)
    return s


@njit(cache=True)
def _loop_sos(n, sos, zi, last, out):
    x = np.empty(3)
    s = 0
    for k in range(n):
        x[0] = math.sin(0.01 * k)
        x[1] = 1.0
        x[2] = -1.0
        s += sos_step(sos, zi, last, x, out)
    return s


@njit(cache=True)
def _loop_safety(n, params, state, out, t0):
    f = np.empty(3)
    s = 0
    for k in range(n):
        f[0] = 10.0 * math.sin(0.001 * k)
        f[1] = 2.0
        f[2] = -1.0
        s += safety_step(params, state, f, t0 + k * 1e-3, 0.0, 0, out)
    state[7] = math.nan  # next batch starts a fresh clock (no false deadline miss)
    return s


@njit(cache=True)
def _loop_fp(n, params, phi, gamma, state, force, probe):
    x = np.zeros(3)
    v = np.zeros(3)
    fe = np.zeros(3)
    s = 0
    for k in range(n):
        x[0] = 1e-3 * math.sin(0.01 * k)
        v[0] = 1e-5 * math.cos(0.01 * k)
        fe[0] = -1e-8 * math.sin(0.01 * k)
        s += fp_step(params, phi, gamma, state, x, v, fe, False, force, probe)
    return s


@njit(cache=True)
def _loop_map(n, params, state, out):
    x = np.zeros(3)
    s = 0
    for k in range(n):
        x[0] = 1e-3 * math.sin(0.01 * k)
        s += position_map_step(params, state, x, 0, 1, out)
    return s


@njit(cache=True)
def _loop_device(n, phi, gamma, z, r, f):
    for k in range(n):
        f[0] = 0.1 * math.sin(0.01 * k)
        virtual_device_advance(phi, gamma, z, r, f)
    return 0


@njit(cache=True)
def _chain_compiled(n, dphi, dgam, z, r, fdev, alpha, yf, fout, cparams, cphi, cgam, cstate, force, probe,
                    sparams, sstate, sout, t0):
    """n ticks of: device -> filter (probe force) -> FP coupling -> safety -> device, all compiled."""
    x = np.empty(3)
    v = np.empty(3)
    fe = np.empty(3)
    flags = 0
    for k in range(n):
        for j in range(3):
            x[j] = z[j, 2]
            v[j] = z[j, 3]
        pen = probe[0]
        fe[0] = -10.0 * pen if pen > 0.0 else 0.0
        fe[1] = 0.0
        fe[2] = 0.0
        flags |= lowpass1_step(alpha, yf, fe, fout)
        flags |= fp_step(cparams, cphi, cgam, cstate, x, v, fout, False, force, probe)
        flags |= safety_step(sparams, sstate, force, t0 + k * 1e-3, 0.0, 0, sout)
        for j in range(3):
            fdev[j] = sout[j] + 0.2  # + the operator's push
        virtual_device_advance(dphi, dgam, z, r, fdev)
    sstate[7] = math.nan
    return flags


def bench_blocks(quick: bool) -> dict:
    nb, batch = (40, 500) if quick else (200, 2000)
    nb_py, batch_py = (40, 100) if quick else (200, 500)
    res = {}
    # first-order filter
    lp = LowPass(cutoff=200.0, dt=DT)
    xin = np.array([0.3, 1.0, -1.0])
    out = np.zeros(3)
    res["lowpass1"] = {
        "compiled": time_compiled(lambda n: _loop_lowpass(n, lp.alpha, lp.state, out), nb, batch),
        "python_api": time_python(lambda: lp.step(xin, out), nb_py, batch_py),
    }
    # Butterworth biquad, and scipy's per-sample sosfilt as the peer
    from scipy import signal

    bw = ButterworthLowPass(cutoff=200.0, dt=DT)
    zi = [np.zeros((bw.sos.shape[0], 2, 3))]
    x1 = xin.reshape(1, 3)

    def scipy_step():
        _, zi[0] = signal.sosfilt(bw.sos, x1, axis=0, zi=zi[0])

    res["butterworth2"] = {
        "compiled": time_compiled(lambda n: _loop_sos(n, bw.sos, bw.state, bw.last, out), nb, batch),
        "python_api": time_python(lambda: bw.step(xin, out), nb_py, batch_py),
        "peer_scipy_sosfilt_per_sample": time_python(scipy_step, nb_py, batch_py),
    }
    # safety
    sl = SafetyLayer(max_force=7.9, dt=DT, ramp_time=0.0)
    fin = np.array([3.0, 9.0, -1.0])
    clock = [0.0]

    def safety_api():
        clock[0] += DT
        sl.step(fin, clock[0], 0.0, 0, out)

    res["safety"] = {
        "compiled": time_compiled(lambda n: _loop_safety(n, sl.params, sl.state, out, 0.0), nb, batch),
        "python_api": time_python(safety_api, nb_py, batch_py),
    }
    # force-position coupling
    g = suggest_gains(mass=M, damping=BV, dt=DT, A_f=AF, A_d=AD)
    fp = ForcePositionCoupling(**g, A_f=AF, A_d=AD, dt=DT, slave_tau=(1e-4, 2e-5))
    xm, vm, fe = np.array([1e-3, 0, 0]), np.zeros(3), np.array([-1e-8, 0, 0])
    res["force_position"] = {
        "compiled": time_compiled(lambda n: _loop_fp(n, fp.params, fp.phi, fp.gamma, fp.state, out, np.zeros(3)), nb, batch),
        "python_api": time_python(lambda: fp.hand_force(xm, vm, 0, fe, out), nb_py, batch_py),
    }
    # position map (direct coupling / scaling)
    ps = PositionScaling(1e-5)
    res["position_map"] = {
        "compiled": time_compiled(lambda n: _loop_map(n, ps.params, ps.state, out), nb, batch),
        "python_api": time_python(lambda: ps.map(xm, 0, out), nb_py, batch_py),
    }
    # virtual device tick
    dev = VirtualDevice(dt=DT).open()
    fz = np.zeros(3)
    st = dev.read_state()
    res["virtual_device"] = {
        "compiled": time_compiled(lambda n: _loop_device(n, dev.phi, dev.gamma, dev.z, np.zeros(3), np.zeros(3)), nb, batch),
        "python_api_read_and_command": time_python(lambda: (dev.read_state(st), dev.command_force(fz)), nb_py, batch_py),
    }
    for v in res.values():
        v["ratio_python_over_compiled"] = v.get("python_api", v.get("python_api_read_and_command"))["median_ns"] / v["compiled"]["median_ns"]
    res["butterworth2"]["ratio_scipy_over_python_api"] = (
        res["butterworth2"]["peer_scipy_sosfilt_per_sample"]["median_ns"] / res["butterworth2"]["python_api"]["median_ns"])
    return res


def bench_chain(quick: bool) -> dict:
    """One tick of the blocks (no collision): Python objects vs one compiled function."""
    n = 2000 if quick else 10000
    g = suggest_gains(mass=M, damping=BV, dt=DT, A_f=AF, A_d=AD, env_stiffness=10.0)

    def build():
        dev = VirtualDevice(dt=DT, external_force=lambda t: (0.2, 0.0, 0.0)).open()
        lp = LowPass(cutoff=200.0, dt=DT)
        fp = ForcePositionCoupling(**g, A_f=AF, A_d=AD, dt=DT, slave_tau=(1e-4, 2e-5))
        sl = SafetyLayer.for_device(dev.info, DT, ramp_time=0.05)
        return dev, lp, fp, sl

    dev, lp, fp, sl = build()
    st = dev.read_state()
    fe, ff, fh, fo = np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3)
    samples = np.empty(n)
    pc = time.perf_counter_ns
    for k in range(n):
        t0 = pc()
        dev.read_state(st)
        p = fp.probe_position(out=fo)
        fe[0] = -10.0 * p[0] if p[0] > 0 else 0.0
        lp.step(fe, ff)
        fp.hand_force(st.position, st.velocity, st.buttons, ff, fh)
        out = sl.step(fh, st.timestamp, 0.0, st.buttons, fo)
        dev.command_force(out)
        samples[k] = pc() - t0
    python = summary_ns(samples[n // 10:])
    final_python = dev.read_state().position.copy()

    dev, lp, fp, sl = build()
    z = dev.z
    args = (dev.phi, dev.gamma, z, z[:, 2].copy(), np.zeros(3), lp.alpha, lp.state, np.zeros(3),
            fp.params, fp.phi, fp.gamma, fp.state, np.zeros(3), np.zeros(3), sl.params, sl.state, np.zeros(3))
    _chain_compiled(1, *args, 0.0)
    dev, lp, fp, sl = build()
    z = dev.z
    args = (dev.phi, dev.gamma, z, z[:, 2].copy(), np.zeros(3), lp.alpha, lp.state, np.zeros(3),
            fp.params, fp.phi, fp.gamma, fp.state, np.zeros(3), np.zeros(3), sl.params, sl.state, np.zeros(3))
    per = []
    for k in range(n // 100):
        t0 = pc()
        _chain_compiled(100, *args, k * 0.1)
        per.append((pc() - t0) / 100)
    compiled = summary_ns(per)
    return {
        "ticks": n,
        "python_objects_per_tick": python,
        "compiled_per_tick": compiled,
        "ratio_python_over_compiled": python["median_ns"] / compiled["median_ns"],
        "python_final_master_x_m": float(final_python[0]),
        "compiled_final_master_x_m": float(z[0, 2]),
    }


def bench_scheduler(seconds: float) -> dict:
    res = {}
    for rate in (1000.0, 10000.0):
        sched = Scheduler(lambda s, i, dt: None, None, rate=rate)
        st = sched.run_for(seconds)
        d = st.as_dict()
        for k in ("compute_median", "compute_p99", "compute_max", "period_median", "jitter_p99", "jitter_max"):
            d[k + "_us"] = d.pop(k) * 1e6
        d["overrun_fraction"] = st.overruns / max(1, st.ticks)
        res[f"{int(rate)}Hz"] = d
    return res


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=3.0, help="scheduler run per rate, s")
    ap.add_argument("--quick", action="store_true", help="fewer samples (smoke run)")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    report = {
        "benchmark": "haptic_blocks",
        "machine": {"python": platform.python_version(), "cpus": os.cpu_count(), "platform": platform.platform()},
        "blocks_per_call": bench_blocks(args.quick),
        "chain_per_tick": bench_chain(args.quick),
        "scheduler_trivial_step": bench_scheduler(args.seconds),
    }
    report["wall_s"] = time.perf_counter() - t0
    print(json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
