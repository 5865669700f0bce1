"""Round-trip latency and jitter of the Nanonis link through the simulated controller at 1 kHz (JSON).

:func:`bench_nanonis` runs the simulated Nanonis controller (:mod:`arsurf.instrument.nanonis_sim`,
a virtual AFM behind it) in a child process - so the client does not share its interpreter - and
measures, on loopback:

* ``read``: one :meth:`NanonisAFM.read` (``Signals.ValsGet`` of X, Y, Z, deflection, torsion)
  issued every 1 ms by a paced 1 kHz loop: round trip (median, p99, max, microseconds), the period
  jitter of the loop (|period - 1 ms|, p99 and max) and the deadlines missed;
* ``move_and_read``: the live link's round, ``FolMe.XYPosSet`` then the read, every 1 ms;
* ``link``: the :class:`InstrumentLink` thread against the controller while a 1 kHz reader takes
  its newest sample: samples per second and the sample age the reader sees (median, p99);
* ``live_link``: the live loop's link with the shipped defaults (xyz, the controller's Tap, the
  sample-age limit derived from it) read by a 1 kHz loop: loop rate, p99 period, sample age
  (p99) against the limit, and the worst time a loop tick spent in the link (``latest`` +
  ``command``) over a run in which the link's replies are lost halfway (the link thread then waits
  its timeout; the loop never does: it sees the age grow and would stop at the limit);
* peers timed in the same run: ``tcp_echo`` - a bare request/reply of the same sizes to an echo
  server in the same child (the loopback floor) - and ``vendor_read`` - the same read with the
  vendor package's client ``nanonis_spm.Nanonis.Signals_ValsGet`` (when installed).

``bench/hardware.py`` merges :func:`bench_nanonis` into its report.

Run: ``python bench/hardware_nanonis.py [--seconds 3]``
"""
from __future__ import annotations

import argparse
import math
import multiprocessing as mp
import os
import socket
import sys
import threading
import time

import numpy as np

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from _timing import emit  # noqa: E402

from arsurf.instrument.interface import InstrumentLimits, InstrumentSample  # noqa: E402
from arsurf.instrument.link import InstrumentLink  # noqa: E402
from arsurf.instrument.nanonis import NanonisAFM  # noqa: E402

RATE = 1000.0
LIMITS = InstrumentLimits((0.0, 0.0, -5e-6), (20e-6, 20e-6, 5e-6), 100e-6)
REQUEST, REPLY = 60, 72  # bytes of a Signals.ValsGet request (5 indexes) and its reply


def _serve(conn) -> None:
    """Child process: the simulated controller and a TCP echo server; sends their ports, runs until told."""
    from arsurf.instrument.instrument import PhotodiodeNoise, VirtualAFM
    from arsurf.instrument.nanonis_sim import NanonisSimulator

    afm = VirtualAFM(0.0, probe_height=0.3e-6, tip_xy=(5e-6, 5e-6), noise=PhotodiodeNoise(peak_to_peak=1e-3),
                     keep_history=False)
    echo = socket.create_server(("127.0.0.1", 0))

    def echo_loop():
        c, _ = echo.accept()
        c.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        buf = bytearray(REQUEST)
        view = memoryview(buf)
        reply = bytes(REPLY)
        try:
            while True:
                got = 0
                while got < REQUEST:
                    k = c.recv_into(view[got:], REQUEST - got)
                    if k == 0:
                        return
                    got += k
                c.sendall(reply)
        except OSError:
            return

    threading.Thread(target=echo_loop, daemon=True).start()
    with NanonisSimulator(afm) as sim:
        conn.send((sim.address[1], echo.getsockname()[1]))
        while True:
            msg = conn.recv()
            if msg == "lose":  # the replies stop coming (the second connection's withdraw stalls too)
                sim.faults.stall_after = 0
            elif msg == "heal":
                sim.faults.stall_after = None
            else:
                return


def _paced(fn, seconds: float) -> dict:
    """Call ``fn`` every 1/RATE s for ``seconds`` (sleep, then spin the last 0.2 ms); the round trip
    of each call and the period jitter, microseconds."""
    period = 1.0 / RATE
    n = int(seconds * RATE)
    rt, starts = np.empty(n), np.empty(n)
    clock = time.perf_counter
    nxt = clock()
    missed = 0
    for i in range(n):
        while True:
            left = nxt - clock()
            if left <= 0:
                break
            if left > 2e-4:
                time.sleep(left - 2e-4)
        t0 = clock()
        fn()
        t1 = clock()
        starts[i], rt[i] = t0, t1 - t0
        nxt += period
        if t1 > nxt:
            missed += int((t1 - nxt) // period) + 1
            nxt = t1
    jit = np.abs(np.diff(starts) - period)
    us = 1e6
    return {"calls": n, "round_trip_median_us": float(np.median(rt) * us), "round_trip_p99_us":
            float(np.percentile(rt, 99) * us), "round_trip_max_us": float(rt.max() * us),
            "period_jitter_p99_us": float(np.percentile(jit, 99) * us), "period_jitter_max_us": float(jit.max() * us),
            "deadlines_missed": missed}


def _link(port: int, seconds: float) -> dict:
    afm = NanonisAFM("127.0.0.1", port, limits=LIMITS)
    s = InstrumentSample()
    ages = []
    with InstrumentLink(afm, rate=RATE, axes="xy") as link:
        link.wait_first()
        n0, t0 = link.samples, time.perf_counter()
        k = 0
        while time.perf_counter() - t0 < seconds:
            link.command(np.array([5e-6 + 1e-7 * math.sin(k * 1e-2), 5e-6, 0.0]))
            ages.append(link.latest(s))
            k += 1
            time.sleep(1.0 / RATE)
        rate = (link.samples - n0) / (time.perf_counter() - t0)
    a = np.array(ages) * 1e6
    return {"samples_per_s": float(rate), "moves": link.moves, "age_median_us": float(np.median(a)),
            "age_p99_us": float(np.percentile(a, 99)), "age_max_us": float(a.max()), "error": link.error}


def _live_link(port: int, seconds: float, pipe) -> dict:
    afm = NanonisAFM("127.0.0.1", port, limits=LIMITS)
    s = InstrumentSample()
    ages, block, starts = [], [], []
    clock = time.perf_counter
    with InstrumentLink(afm, rate=RATE, axes="xyz") as link:
        link.wait_first()
        limit = afm.sample_age_limit("xyz")
        tap, rtt = afm.acquisition_period, afm.round_trip
        t0 = nxt = clock()
        lost_at = None
        while clock() - t0 < seconds:
            while clock() < nxt:
                pass
            t = clock()
            starts.append(t)
            if lost_at is None and t - t0 > seconds / 2:
                pipe.send("lose")
                lost_at = len(starts) - 1
            link.command(np.array([5e-6, 5e-6, 0.1e-6]))
            ages.append(link.latest(s))
            block.append(clock() - t)
            nxt += 1.0 / RATE
        pipe.send("heal")
        error = link.error
    a, b = np.array(ages) * 1e3, np.array(block) * 1e6
    period = np.diff(starts) * 1e3
    good = a[:lost_at]
    return {"tap_ms": tap * 1e3, "round_trip_ms": rtt * 1e3, "max_age_limit_ms": limit * 1e3,
            "loop_rate_hz": float(len(starts) / (starts[-1] - starts[0])), "period_p99_ms": float(np.percentile(period, 99)),
            "sample_age_median_ms": float(np.median(good)), "sample_age_p99_ms": float(np.percentile(good, 99)),
            "sample_age_over_limit_before_loss": int((good > limit * 1e3).sum()),
            "tick_in_link_max_us": float(b.max()), "tick_in_link_max_after_loss_us": float(b[lost_at:].max()),
            "sample_age_at_end_ms": float(a[-1]), "link_error": error}


def bench_nanonis(seconds: float = 3.0) -> dict:
    """The Nanonis section of bench/hardware.py (see the module docstring)."""
    ctx = mp.get_context("spawn")
    here, there = ctx.Pipe()
    child = ctx.Process(target=_serve, args=(there,), daemon=True)
    child.start()
    try:
        port, echo_port = here.recv()
        out = {"rate_hz": RATE, "seconds_per_case": seconds,
               "simulator": "arsurf.instrument.nanonis_sim (virtual AFM), child process, loopback TCP"}
        with NanonisAFM("127.0.0.1", port, limits=LIMITS) as afm:
            sample = InstrumentSample()
            out["read"] = _paced(lambda: afm.read(sample), seconds)
            k = [0]

            def move_read():
                k[0] += 1
                afm.move_to((5e-6 + 1e-8 * (k[0] % 100), 5e-6, math.nan))
                afm.read(sample)

            out["move_and_read"] = _paced(move_read, seconds)
        out["link"] = _link(port, seconds)
        out["live_link"] = _live_link(port, seconds, here)
        e = socket.create_connection(("127.0.0.1", echo_port))
        e.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        req, buf = bytes(REQUEST), bytearray(REPLY)

        def echo():
            e.sendall(req)
            view, got = memoryview(buf), 0
            while got < REPLY:
                got += e.recv_into(view[got:], REPLY - got)

        out["tcp_echo"] = _paced(echo, seconds)
        e.close()
        try:
            import nanonis_spm
        except ImportError:
            out["vendor_read"] = "nanonis-spm not installed (pip install 'arsurf[nanonis]')"
        else:
            v = socket.create_connection(("127.0.0.1", port))
            v.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            client = nanonis_spm.Nanonis(v)
            with NanonisAFM("127.0.0.1", port, limits=LIMITS) as probe:
                idx = list(probe.signal_indexes)
            out["vendor_read"] = _paced(lambda: client.Signals_ValsGet(list(idx), 0), seconds)
            v.close()
        ours, floor = out["read"]["round_trip_median_us"], out["tcp_echo"]["round_trip_median_us"]
        out["read_over_tcp_echo"] = round(ours / floor, 2)
        if isinstance(out["vendor_read"], dict):
            out["vendor_over_read"] = round(out["vendor_read"]["round_trip_median_us"] / ours, 2)
        return out
    finally:
        here.send("stop")
        child.join(10.0)
        if child.is_alive():
            child.terminate()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=3.0, help="duration of each 1 kHz case, s")
    args = ap.parse_args()
    emit("hardware_nanonis", {"nanonis": bench_nanonis(args.seconds)})


if __name__ == "__main__":
    main()
