"""The servo-loop scheduler: runs ``step(state, inputs, dt)`` at a fixed rate in its own thread.

The loop is split in two (CHAI3D's habit): a pure, deterministic ``step`` that tests run
thousands of times without sleeping (:meth:`Scheduler.run_ticks`), and this scheduler, which owns
the thread, the clock and the timing statistics. The scheduler knows nothing of devices or
physics; per tick it does::

    inputs = source()                 # e.g. partial(device.read_state, DeviceState())   (None: inputs = None)
    output = step(state, inputs, dt)  # the pipeline tick, dt is the nominal period
    sink(output)                      # e.g. device.command_force (None: ignored)
    publish snapshot(state, inputs, output) for the viewer   (at most snapshot_rate per second)

**Timing.** Deadlines are absolute, :math:`t_k = t_0 + k\\,T` on :func:`time.perf_counter_ns`, so
errors do not accumulate. The wait before a deadline is hybrid: ``time.sleep`` until ``spin``
seconds before it (the OS wakes a sleeper tens of microseconds late), then a busy spin on the
clock. A tick whose work ends after its own deadline is an *overrun*; deadlines that passed
entirely are *skipped* (the grid is kept: the next tick starts at once, less than one period late,
and there is no burst of catch-up ticks). Under ``SCHED_FIFO`` the spin's margin is learned from
how late the sleeps end, and the thread keeps :data:`FIFO_IDLE_SHARE` of its time off the CPU
over a window (a budget on its own CPU clock, what the kernel counts), so it never meets the
kernel's real-time throttling; :class:`Pacer` keeps this discipline, on an injectable clock
(docs/scheduler.rst). Statistics are kept in
preallocated ring buffers: compute time per tick, start-to-start period, and jitter (period minus
nominal).

**Snapshot.** The viewer (30-60 Hz, another thread) reads a consistent copy of what the step
published: the loop copies the arrays returned by ``snapshot`` into a preallocated buffer under a
lock, and :meth:`Scheduler.snapshot` copies them out under the same lock, so a reader never sees
half of one tick and half of the next. The loop only *tries* the lock: if the viewer is copying,
that tick's publication is skipped (the servo thread never waits for the viewer).

Python caveat: the loop holds the GIL while it runs Python code, and another busy Python thread can
delay it by up to the interpreter's switch interval (5 ms by default). The scheduler lowers
:func:`sys.setswitchinterval` to a quarter of the period while it runs (restored on stop), and the
step should spend its time in compiled kernels, which is what makes 1-10 kHz reachable.

Examples
--------
>>> import numpy as np
>>> def step(state, inputs, dt):
...     state["x"] += dt
...     return state["x"]
>>> sched = Scheduler(step, {"x": 0.0}, rate=1000.0, snapshot=lambda s, i, o: {"x": np.array([s["x"]])})
>>> sched.run_ticks(500)            # deterministic, no sleeping
>>> snap = sched.snapshot()
>>> snap.tick, round(float(snap.values["x"][0]), 9)
(499, 0.5)
"""
from __future__ import annotations

import gc
import math
import os
import sys
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from arsurf.errors import HapticsError, LoopError

__all__ = ["DEFAULT_REALTIME_PRIORITY", "LoopError", "Pacer", "RealtimeChoice", "Scheduler", "Snapshot",
           "TickTrace", "TimingStats", "choose_realtime", "explain_trace"]

#: least wake margin (s) before each deadline when the loop thread runs under SCHED_FIFO: the
#: margin is learned from how late the thread's sleeps end (a real-time sleeper on bare metal
#: wakes within ~10 us, on the virtual machine of the benches 23-35 us late at the median and up
#: to ~100 us, ``bench/haptic_loop.py --diagnose``), and shrinks toward this when the CPU
#: budget runs low
FIFO_SPIN = 5e-6

#: least share of its time a real-time loop thread is off the CPU, whatever its step costs, on
#: the thread's own CPU clock (what the kernel's real-time throttling counts; on a virtual
#: machine each sleep's timer and context switch cost the thread ~25 us of CPU, so a thread
#: that "sleeps" briefly every period can still be on the CPU 99 % of a second): it is then on
#: the CPU at most 90 % of any second plus the bucket, below the kernel's 95 % budget, so the
#: throttling (a ~50 ms stop of the thread) is never reached
FIFO_IDLE_SHARE = 0.1

#: CPU time (ns) a real-time loop may run ahead of :data:`FIFO_IDLE_SHARE`, the size of its
#: budget's bucket: a one-off stall of a few ms is not paid back at once, and the worst second
#: stays at 90 % + 1 % on the CPU
FIFO_IDLE_BURST_NS = 10_000_000

#: wall time (ns) between two readings of the thread's CPU clock for the budget (a system call)
BUDGET_STEP_NS = 1_000_000

#: longest sleep (ns) the budget forces at once: the rest is owed to the next ticks, so the
#: budget alone never makes a gap between two ticks longer than this plus two periods
MAX_FORCED_NAP_NS = 500_000

#: ticks per block of the learned wake-up lateness: the margin is the largest lateness of the
#: sleeps of the last one to two blocks (~ its 99.9th percentile; 0.1-0.2 s at 10 kHz)
LATENESS_BLOCK = 1024

#: short sleeps :meth:`Pacer.start` takes to guess the wake-up lateness before the first tick
CALIBRATION_SLEEPS = 16

#: the window (ns) of :attr:`Pacer.awake_max` and :attr:`Pacer.cpu_max`: the kernel's real-time period
_AWAKE_WINDOW_NS = 1_000_000_000


class Pacer:
    """The loop's time-keeping: an absolute deadline grid, overruns and skipped slots, and the
    wait before each deadline, a sleep then a spin of a wake margin.

    Deadlines are :math:`t_k = t_0 + k\\,T`. After the tick's work, :meth:`wait` sleeps until a
    *wake margin* before the next deadline, then spins on the clock to the deadline. The margin
    is ``spin_ns``, or, with ``spin_max_ns`` above it, *learned*: the largest lateness of the
    sleeps of the last one to two blocks of :data:`LATENESS_BLOCK` ticks (how much later than
    asked the thread was awake again; ~ its 99.9th percentile), between ``spin_ns`` and
    ``spin_max_ns``: it starts from :data:`CALIBRATION_SLEEPS` short sleeps, grows at the
    first later wake-up, and forgets a block later.

    **The idle share** :math:`s` (``idle_share``, real-time threads) is a budget on the thread's
    CPU clock, a bucket of ``burst_ns``: it earns :math:`(1 - s)` ns of CPU per ns of wall time,
    spends what ``cpu_clock`` says (read every :data:`BUDGET_STEP_NS`). While the bucket holds
    more than half its size the margin is the learned one; below, the margin shrinks linearly
    toward the least that lets a tick of the last one's cost, woken as late as learned, still end
    a tenth of a period before the next deadline (longer sleeps each period; late starts, but no
    overrun);
    an empty bucket forces a sleep of what is owed, in whole slots (skipped: the next tick is on
    the grid) and at most :data:`MAX_FORCED_NAP_NS` at a time (never a long gap). So the thread is on the CPU at most :math:`(1 - s) L` +
    ``burst_ns`` + :data:`BUDGET_STEP_NS` of any span :math:`L`, whatever its step costs and
    whatever its sleeps cost in system time; the kernel stops a real-time thread on the CPU
    more than 95 % of a second (``sched_rt_runtime_us``).

    A tick whose work ends after the next deadline is an *overrun*; deadlines that passed
    entirely are *skipped* (the grid is kept: no burst of catch-up ticks; the next tick starts
    at once). Statistics: :attr:`longest_gap` between two tick starts, :attr:`spin_max`,
    :attr:`margin_max` (the largest margin used), :attr:`forced_naps`, the largest share of a
    second awake (:attr:`awake_max`: everything but the sleeps here) and on the CPU
    (:attr:`cpu_max`, from ``cpu_clock``).

    ``clock`` (ns, monotonic), ``sleep`` (s) and ``cpu_clock`` (ns) are injectable: tests drive
    the pacer with a scripted clock, no timing involved; ``trace`` (a :class:`TickTrace`)
    records each tick's timeline.

    Examples
    --------
    A 10 kHz grid on a scripted clock (each reading takes 1 us; each sleep wakes 5 us late):

    >>> t = [0]
    >>> def clock():
    ...     t[0] += 1_000
    ...     return t[0]
    >>> def sleep(s):
    ...     t[0] += round(s * 1e9) + 5_000
    >>> p = Pacer(100_000, spin_ns=30_000, idle_share=0.1, burst_ns=1_000_000, clock=clock, sleep=sleep)
    >>> for work in (20_000, 20_000, 250_000, 20_000):     # the third tick takes 2.5 periods
    ...     _ = p.begin(); t[0] += work; p.wait()
    >>> p.overruns, p.skipped, p.longest_gap, p.spin_max <= 30_000
    (1, 1, 252000, True)
    """

    def __init__(self, period_ns: int, spin_ns: int, idle_share: float = 0.0, burst_ns: int = 0, *,
                 spin_max_ns: int | None = None, clock: Callable[[], int] = time.perf_counter_ns,
                 sleep: Callable[[float], Any] = time.sleep, cpu_clock: Callable[[], int] = time.thread_time_ns,
                 trace: "TickTrace | None" = None) -> None:
        self.trace = trace
        self.period = int(period_ns)
        self.spin = int(spin_ns)
        self.spin_cap = max(self.spin, int(spin_ns if spin_max_ns is None else spin_max_ns))
        if not 0.0 <= idle_share < 1.0:
            raise HapticsError(f"idle_share must be in [0, 1) (got {idle_share!r})")
        self.share = float(idle_share)
        self.burst = int(burst_ns)
        self.clock, self.sleep, self.cpu_clock = clock, sleep, cpu_clock
        self.start(clock())

    def start(self, t0: int | None = None) -> int:
        """Put the grid's origin at ``t0`` (default now) and clear the counts; returns ``t0``."""
        t0 = self.clock() if t0 is None else int(t0)
        self.t0 = self.deadline = self._awake_since = t0
        self._last_start = None
        self.overruns = self.skipped = self.forced_naps = 0
        self.longest_gap = 0          # ns between two tick starts
        self.spin_max = 0             # ns, the longest spin before a deadline
        self.margin_max = 0           # ns, the largest wake margin used
        self.awake = 0                # ns awake, whole run
        self.awake_max = 0.0          # the largest share of a whole second spent awake
        self._window_end = t0 + _AWAKE_WINDOW_NS
        self._window_awake = 0
        self.cpu_max = 0.0            # the largest share of a second the thread spent on the CPU
        cpu = self.cpu_clock()
        self._cpu_mark = (t0, cpu)
        self._credit = float(self.burst)  # ns of CPU the budget allows ahead of the idle share
        self._budget_mark = (t0, cpu)
        # the learned wake-up lateness (ns), the largest of the previous and the current block
        self._late_prev, self._late_cur, self._late_n = 0, 0, 0
        if self.spin_cap > self.spin:  # a first guess from a few short sleeps (~1 ms at most)
            for _ in range(CALIBRATION_SLEEPS):
                a = self.clock()
                self.sleep(self.spin * 1e-9)
                self._late_cur = max(self._late_cur, self.clock() - a - self.spin)
            t0 = self.deadline = self._awake_since = self.clock()
            self._cpu_mark = self._budget_mark = (t0, self.cpu_clock())
            self._window_end = t0 + _AWAKE_WINDOW_NS
            self.t0 = t0
        return t0

    def begin(self) -> int:
        """A tick starts now: returns the time, ns, and the gap since the previous start (0 first)."""
        start = self.clock()
        if self.trace is not None:
            self.trace.begin(self.deadline, start, self.cpu_clock())
        gap = 0 if self._last_start is None else start - self._last_start
        if gap > self.longest_gap:
            self.longest_gap = gap
        self._last_start = start
        self.last_gap = gap
        return start

    def _count_awake(self, a: int, b: int) -> None:
        self.awake += b - a
        if b > self._window_end:  # once a second: the thread's CPU time (what the kernel budgets)
            t, c = b, self.cpu_clock()
            self.cpu_max = max(self.cpu_max, (c - self._cpu_mark[1]) / max(1, t - self._cpu_mark[0]))
            self._cpu_mark = (t, c)
        while b > self._window_end:  # close the windows that ended, each with its own share
            if a < self._window_end:
                self._window_awake += self._window_end - a
                a = self._window_end
            self.awake_max = max(self.awake_max, self._window_awake / _AWAKE_WINDOW_NS)
            self._window_awake = 0
            self._window_end += _AWAKE_WINDOW_NS
        self._window_awake += b - a

    def awake_share(self) -> float:
        """The largest share of a second the thread spent awake: :attr:`awake_max` over the
        whole seconds so far, or the share of the run when it is shorter than one second."""
        if self.awake_max > 0.0:
            return self.awake_max
        span = self._awake_since - self.t0
        return self._window_awake / span if span > 0 else 0.0

    def _refill(self, now: int) -> None:
        """The budget: earn (1 - s) of the wall time since the last reading, spend the CPU time."""
        cpu = self.cpu_clock()
        t_prev, cpu_prev = self._budget_mark
        self._credit = min(float(self.burst), self._credit + (1.0 - self.share) * (now - t_prev) - (cpu - cpu_prev))
        self._budget_mark = (now, cpu)

    def margin(self) -> int:
        """The wake margin (ns) the next wait will use before the budget: the learned lateness
        between ``spin_ns`` and ``spin_max_ns``."""
        return min(self.spin_cap, max(self.spin, self._late_prev, self._late_cur))

    def wait(self) -> None:
        """The tick's work is done: count an overrun and skipped slots, then sleep and spin to
        the next deadline."""
        clock, period = self.clock, self.period
        self.deadline += period
        now = clock()
        trace = self.trace
        if trace is not None:
            trace.work_done(now, self.cpu_clock())
        if now > self.deadline:  # this tick ended after the next one should have started
            self.overruns += 1
            missed = (now - self.deadline) // period
            if missed:  # whole periods lost: skip those slots, stay on the grid
                self.skipped += int(missed)
                self.deadline += missed * period
        margin = self.margin()
        forced = False
        if self.share:  # the real-time budget on the thread's CPU clock
            if now - self._budget_mark[0] >= BUDGET_STEP_NS:
                self._refill(now)
            credit, half = self._credit, 0.5 * self.burst
            if credit < half:  # running low: shorter margins, longer sleeps each period, as far as a
                # wake-up as late as the learned one still lets a tick like this one end in its period
                work = now - (self._last_start if self._last_start is not None else now)
                floor = max(self.spin, min(margin, margin + work - period + period // 10))
                margin = floor + int((margin - floor) * max(0.0, credit) / half) if half > 0 else floor
            owed = -credit / (1.0 - self.share)  # ns off the CPU that would empty the debt
            if credit < 0.0 and owed > self.deadline - now - margin:  # this period's sleep does not pay
                # the debt: skip whole slots
                slots = min(-(-(int(owed) - (self.deadline - now - margin)) // period),
                            max(1, MAX_FORCED_NAP_NS // period))
                self.deadline += slots * period
                self.skipped += slots
                self.forced_naps += 1
                forced = True
        nap = self.deadline - now - margin
        if margin > self.margin_max:
            self.margin_max = margin
        if nap > 0:
            self._count_awake(self._awake_since, now)
            self.sleep(nap * 1e-9)
            woke = clock()
            if trace is not None:
                trace.slept(nap, woke)
            late = woke - now - nap  # learn how late the thread is awake again
            if late > self._late_cur:
                self._late_cur = late
            if forced:
                self._refill(woke)
            now = self._awake_since = woke
        self._late_n += 1
        if self._late_n == LATENESS_BLOCK:  # a block of ticks without a sleep forgets what it learned
            self._late_prev, self._late_cur, self._late_n = self._late_cur, 0, 0
        spin_from = now
        while now < self.deadline:
            now = clock()
        if now - spin_from > self.spin_max:
            self.spin_max = now - spin_from

    def finish(self) -> None:
        """The loop ended: count its last time awake."""
        self._count_awake(self._awake_since, self.clock())
        self._awake_since = self.clock()


class TickTrace:
    """The timeline of the last ``n`` ticks of a :class:`Pacer` (ns), to find where slots are lost.

    Per tick (:data:`TRACE_FIELDS`): the deadline it was due at, its start, the thread's CPU
    clock at its start, the end of its work (when :meth:`Pacer.wait` was called) and the CPU clock
    then, the sleep the wait asked for (0: none) and when the thread was awake again (the end of
    its work when it did not sleep). Preallocated; recording costs two reads of the thread's CPU
    clock per tick (~1 us), so it is off unless asked (``Scheduler(trace=n)``).
    """

    def __init__(self, n: int) -> None:
        if not isinstance(n, int) or n < 1:
            raise HapticsError(f"a trace keeps n >= 1 ticks (got {n!r})")
        self.rows = np.zeros((n, len(TRACE_FIELDS)), dtype=np.int64)
        self.n = n
        self.ticks = 0
        self._row = self.rows[0]

    def begin(self, deadline: int, start: int, cpu: int) -> None:
        row = self._row = self.rows[self.ticks % self.n]
        row[0], row[1], row[2] = deadline, start, cpu
        self.ticks += 1

    def work_done(self, now: int, cpu: int) -> None:
        row = self._row
        row[3], row[4], row[5], row[6] = now, cpu, 0, now

    def slept(self, nap: int, woke: int) -> None:
        row = self._row
        row[5], row[6] = nap, woke

    def columns(self) -> dict[str, np.ndarray]:
        """The recorded ticks in order, oldest first, one array per field."""
        k = min(self.ticks, self.n)
        first = self.ticks % self.n if self.ticks > self.n else 0
        ordered = np.roll(self.rows, -first, axis=0)[:k]
        return {name: ordered[:, i].copy() for i, name in enumerate(TRACE_FIELDS)}


#: the fields of a :class:`TickTrace` row, ns
TRACE_FIELDS = ("deadline", "start", "cpu_start", "work_end", "cpu_end", "nap", "woke")

#: the causes :func:`explain_trace` gives a lost slot
LOST_CAUSES = ("step", "preempted_in_step", "idle_share", "late_wake_up", "preempted_in_spin")


def explain_trace(trace: TickTrace, period_ns: int) -> dict:
    """Where a run's lost slots and long gaps come from, from its :class:`TickTrace`.

    A tick :math:`j` *overruns* when its work ends after :math:`d_j + T` (its deadline plus one
    period); with the whole periods it also covered (skipped) those are the lost slots, each
    given one cause (:data:`LOST_CAUSES`):

    - its work took more than a period: ``step`` when the thread was on the CPU at least half of
      that time, else ``preempted_in_step`` (another thread or process ran);
    - it started late (the work itself fitted): ``idle_share`` when the previous wait's sleep was
      asked to end after the deadline (the real-time idle share), ``late_wake_up`` when the
      sleep was asked to end before it but the thread woke after it, else
      ``preempted_in_spin``;
    - it started late because the tick before it ended after its deadline: that tick's cause.

    The same causes are given to each gap between two tick starts longer than ``gap_ns``
    (1 ms), by the part of the gap that is longest. Returns the counts and the distributions
    (us): work, its CPU share, lateness of the starts, and oversleep (woke minus asked).
    """
    c = trace.columns()
    dl, start, work_end = c["deadline"], c["start"], c["work_end"]
    work = work_end - start
    cpu = c["cpu_end"] - c["cpu_start"]
    nap, woke = c["nap"], c["woke"]
    asked_end = work_end + nap
    oversleep = np.where(nap > 0, woke - asked_end, 0)
    n = dl.size
    lost = {name: 0 for name in LOST_CAUSES}
    gaps = {name: 0 for name in LOST_CAUSES}
    if n < 2:
        return {"ticks": int(n), "lost": lost, "gaps_over_1ms": gaps}
    late = start - dl

    def cause(j: int) -> str:
        """Why tick j ran past its slot (j >= 1: the wait before it is in the trace); a tick that
        started late because the one before it ended after its deadline has that one's cause."""
        while j >= 2 and work[j] <= period_ns and work_end[j - 1] >= dl[j]:
            j -= 1
        if work[j] > period_ns:
            return "step" if cpu[j] >= 0.5 * work[j] else "preempted_in_step"
        i = j - 1
        if nap[i] > 0 and asked_end[i] > dl[j]:
            return "idle_share"
        if nap[i] > 0 and woke[i] > dl[j]:
            return "late_wake_up"
        return "preempted_in_spin"

    overran = np.flatnonzero(work_end[:-1] > dl[:-1] + period_ns)
    for j in overran:
        skipped = max(0, int((dl[j + 1] - dl[j]) // period_ns) - 1)
        if j >= 1:
            lost[cause(int(j))] += 1 + skipped
    gap = np.diff(start)
    for k in np.flatnonzero(gap > 1_000_000) + 1:  # tick k started > 1 ms after tick k-1
        i = k - 1
        if work[i] >= gap[k - 1] / 2:
            gaps["step" if cpu[i] >= 0.5 * work[i] else "preempted_in_step"] += 1
        elif nap[i] > 0 and asked_end[i] > dl[k]:
            gaps["idle_share"] += 1
        elif nap[i] > 0 and oversleep[i] >= gap[k - 1] / 2:
            gaps["late_wake_up"] += 1
        else:
            gaps["preempted_in_spin"] += 1

    def q(x) -> dict:
        x = np.asarray(x, dtype=float) * 1e-3
        return {"median_us": float(np.median(x)), "p99_us": float(np.percentile(x, 99)),
                "p999_us": float(np.percentile(x, 99.9)), "max_us": float(x.max())}

    slept = nap > 0
    return {"ticks": int(n), "overruns": int(overran.size), "lost": lost, "gaps_over_1ms": gaps,
            "work": q(work), "work_cpu_share_p1": float(np.percentile(cpu / np.maximum(work, 1), 1)),
            "start_late": q(late), "oversleep": q(oversleep[slept]) if slept.any() else None,
            "slept_share_of_ticks": float(slept.mean())}


@dataclass(frozen=True)
class Snapshot:
    """A consistent copy of what one tick published.

    Attributes
    ----------
    tick : int
        Index of the tick that published it.
    time : float, s
        Loop time of that tick (seconds since start; ``tick * dt`` in :meth:`Scheduler.run_ticks`).
    values : dict[str, np.ndarray]
        Copies of the published arrays.
    """

    tick: int
    time: float
    values: dict[str, np.ndarray]


@dataclass(frozen=True)
class TimingStats:
    """Timing of a scheduler run (over the last ``history`` ticks for the distributions).

    Times in seconds. ``rate`` is the achieved tick rate over the whole run;
    ``realtime_priority`` the ``SCHED_FIFO`` priority the loop thread got (0: none);
    ``longest_gap`` the longest time between two tick starts over the whole run (the hand's
    longest wait for a new force; the period distributions cover the last ``history`` ticks);
    ``spin_max`` the longest busy wait before a deadline; ``awake_max`` the largest share of one
    second the loop thread spent awake, running or runnable (:class:`Pacer`; under
    ``SCHED_FIFO`` the kernel throttles a thread above 0.95); ``cpu_max`` the largest share of
    a second it spent on the CPU (what the kernel counts: it includes the sleeps' own system
    time; 0 in runs shorter than a second); ``cpu_share`` its CPU time over the run's duration
    (after the run); ``margin_max`` the largest wake margin the pacer used (learned under
    ``SCHED_FIFO``), ``forced_naps`` how often its CPU budget made it skip slots.
    """

    ticks: int
    duration: float
    rate: float
    nominal_rate: float
    compute_median: float
    compute_p99: float
    compute_max: float
    period_median: float
    jitter_p99: float
    jitter_max: float
    overruns: int
    skipped: int
    snapshots_published: int
    snapshots_skipped: int
    realtime_priority: int = 0
    longest_gap: float = 0.0
    spin_max: float = 0.0
    awake_max: float = 0.0
    cpu_max: float = 0.0
    cpu_share: float = 0.0
    margin_max: float = 0.0
    forced_naps: int = 0

    def as_dict(self) -> dict[str, float | int]:
        return dict(self.__dict__)


def _tight_timer_slack() -> None:
    """Ask Linux to wake this thread's sleeps on time: ``prctl(PR_SET_TIMERSLACK, 1)`` (1 ns; the
    default slack of 50 us lets ``time.sleep`` end up to 50 us late, half a 10 kHz period). Best
    effort: other systems, or a failing call, keep their default."""
    if not sys.platform.startswith("linux"):
        return
    try:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(29, 1, 0, 0, 0)  # PR_SET_TIMERSLACK = 29
    except (OSError, AttributeError):  # pragma: no cover - no libc symbol
        pass


def _try_realtime(priority: int) -> tuple[int, str]:
    """Put the calling thread under ``SCHED_FIFO`` at ``priority``: (the priority granted, 0 when
    refused or unavailable; why not, "" when granted)."""
    if priority <= 0:
        return 0, "not asked"
    if not hasattr(os, "sched_setscheduler"):
        return 0, "this OS has no SCHED_FIFO"
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))  # 0: this thread
    except (OSError, AttributeError) as exc:
        return 0, f"SCHED_FIFO refused ({exc})"
    return priority, ""


def _realtime_priority(priority: int) -> int:
    """Put the calling thread under the real-time policy ``SCHED_FIFO`` at ``priority`` (1-99):
    it then preempts every ordinary thread at once when its sleep ends, instead of waiting for
    the time-sharing scheduler's turn (tens to hundreds of microseconds on a busy machine, a
    missed deadline at 10 kHz). Linux with CAP_SYS_NICE or an ``rtprio`` limit; best effort:
    returns the priority granted, 0 when refused or unavailable (the thread then keeps the
    ordinary policy). The :class:`Pacer` sleeps at least :data:`FIFO_IDLE_SHARE` of the time, and the kernel's RT throttling (95 % of each second) still bounds a step that never
    returns; the thread's policy ends with the thread."""
    return _try_realtime(priority)[0]


#: the ``SCHED_FIFO`` priority the live loop and the bridge ask for by default: above every
#: ordinary thread, below the 50 of Linux's interrupt threads (the device's and the network's)
DEFAULT_REALTIME_PRIORITY = 10

_RT_RUNTIME = "/proc/sys/kernel/sched_rt_runtime_us"


@dataclass(frozen=True)
class RealtimeChoice:
    """The loop thread's scheduling policy, decided before the loop starts and recorded in the
    session (``realtime`` of the metadata): ``asked`` the priority asked for (0: none, the
    operator's ``--no-realtime-priority`` or a device that answers from a thread of this
    process), ``priority`` the one this process may have (0: the ordinary policy), ``reason``
    why it is what it is."""

    asked: int
    priority: int
    reason: str

    @property
    def policy(self) -> str:
        return "SCHED_FIFO" if self.priority else "ordinary"

    def to_metadata(self) -> dict:
        """The session's ``realtime`` record."""
        return {"policy": self.policy, "priority": self.priority, "asked": self.asked, "reason": self.reason}

    def describe(self) -> str:
        """One line for the CLI."""
        if self.priority:
            return f"loop thread under SCHED_FIFO priority {self.priority} ({self.reason})"
        return f"loop thread under the ordinary policy ({self.reason})"


def choose_realtime(priority: int | None = None, *, device_thread: bool = False) -> RealtimeChoice:
    """Decide the loop thread's policy: ``priority`` None is the default (SCHED_FIFO at
    :data:`DEFAULT_REALTIME_PRIORITY` where the OS permits it and the kernel's real-time
    throttling is on; else the ordinary policy, with the reason), 0 the ordinary policy (opted
    out), N asks SCHED_FIFO at N. ``device_thread``: the device or the instrument answers from a
    thread of this process (Haply, OpenHaptics, the instrument link), which a real-time loop
    thread would delay on a busy core: the default is then the ordinary policy. Permission is tried in a short-lived thread (its
    policy ends with it); the loop thread asks again and reports what it got
    (:attr:`TimingStats.realtime_priority`).

    Examples
    --------
    >>> choose_realtime(0).to_metadata()
    {'policy': 'ordinary', 'priority': 0, 'asked': 0, 'reason': 'turned off (--no-realtime-priority)'}
    """
    if priority == 0:
        return RealtimeChoice(0, 0, "turned off (--no-realtime-priority)")
    if priority is None:
        if device_thread:
            return RealtimeChoice(0, 0, "the device or instrument answers from a thread of this process, which a "
                                        "real-time loop would delay; ask with --realtime-priority N")
        try:
            with open(_RT_RUNTIME) as f:
                unthrottled = f.read().strip() == "-1"
        except OSError:
            unthrottled = False
        if unthrottled:
            return RealtimeChoice(0, 0, f"the kernel's real-time throttling is off ({_RT_RUNTIME} = -1): a "
                                        "stalled step could hold a core; ask with --realtime-priority N")
        priority, how = DEFAULT_REALTIME_PRIORITY, "the default"
    else:
        how = "asked"
    got: list[tuple[int, str]] = []
    probe = threading.Thread(target=lambda: got.append(_try_realtime(priority)), name="arsurf-rt-probe")
    probe.start()
    probe.join()
    granted, why = got[0] if got else (0, "the probe thread failed")
    if granted:
        return RealtimeChoice(priority, granted, how)
    return RealtimeChoice(priority, 0, f"{why}; needs root, CAP_SYS_NICE or an rtprio limit")


class Scheduler:
    """Run ``step(state, inputs, dt)`` at a fixed rate in a thread, with statistics and snapshots.

    Parameters
    ----------
    step : callable
        ``step(state, inputs, dt) -> output``; may mutate ``state`` in place.
    state : object
        Passed to every call of ``step`` (and to ``snapshot``).
    rate : float, Hz
        Tick rate, 1 to 20000 (default 1000; the seeds' loops run at 1-10 kHz).
    source : callable, optional
        ``source() -> inputs`` called at the start of each tick (e.g.
        ``functools.partial(device.read_state, DeviceState())``: one sample filled in place, no
        allocation per tick).
    sink : callable, optional
        ``sink(output)`` called after each step (e.g. ``device.command_force``).
    snapshot : callable, optional
        ``snapshot(state, inputs, output) -> {name: array}``: what the viewer may read. Names and
        shapes are fixed by the first call; the arrays are copied, never kept.
    snapshot_rate : float, Hz
        Largest publication rate (default 240: enough for a 60 Hz viewer).
    on_stop : callable, optional
        ``on_stop()`` called in the loop thread when the loop ends (normally or on an error),
        e.g. to command zero force.
    spin : float, s, optional
        Busy-wait margin before each deadline (default: 2e-4 s, at most three quarters of a
        period, under the ordinary policy; :data:`FIFO_SPIN`, at most a quarter of a period,
        when the thread got ``SCHED_FIFO``, the least of a margin learned from the sleeps'
        lateness up to the ordinary one, within the CPU budget: a thread on the CPU most of
        each second meets Linux's real-time throttling - 950 ms of every second by default -
        and stops for ~50 ms each second). A sleep here ends up to ~50-100 µs late, so at 10 kHz a half-period margin
        missed 0.17-0.35 % of the deadlines and a three-quarter one 0.03-0.09 % (``bench/haptic_loop.py``).
        Spinning a whole period is counter-productive on a shared machine: the OS scheduler then
        preempts the spinner for milliseconds (measured in ``bench/haptic_blocks.py``).
    history : int
        Ticks kept for the timing distributions (default 65536).
    pause_gc : bool
        Freeze the objects alive at start (``gc.freeze``) and keep Python's cyclic garbage
        collector off while the loop runs (default True): a full collection stops every thread
        for milliseconds, a missed deadline at 10 kHz. The tick allocates nothing that needs it
        (reference counting frees its temporaries); the collector is restored at the end.
    trace : int
        Keep the timeline of the last ``trace`` ticks (:class:`TickTrace`, :attr:`trace`; read it
        with :func:`explain_trace`); 0 (default): none.
    priority : int
        Real-time priority of the loop thread, ``SCHED_FIFO`` 1-99 where the OS grants it
        (:data:`DEFAULT_REALTIME_PRIORITY`, 10, is what ``arsurf live`` asks for; keep it below
        the 50 of Linux's interrupt threads), or 0 (default here): the ordinary policy; the
        CLI decides with :func:`choose_realtime`. What was granted is
        :attr:`TimingStats.realtime_priority`. A real-time loop thread keeps the machine's
        other work from delaying a tick, but it also runs before this process's other threads
        on its core: a device whose driver answers from a thread of this process (the simulated
        Haply's reader) then went unanswered for 0.4 s. It keeps
        :data:`FIFO_IDLE_SHARE` of its time off the CPU (:meth:`pacer_for`). At 10 kHz over 60 s on the
        2-core machine shared by eight jobs (load 11) it kept 9,944 ticks/s, 0.56 % of the
        slots skipped and a 7.1 ms longest gap; the ordinary policy 2,806 ticks/s
        (``bench/haptic_loop.py`` times both).

    Examples
    --------
    >>> sched = Scheduler(lambda s, i, dt: None, None, rate=1000.0)
    >>> stats = sched.run_for(0.2)
    >>> stats.ticks > 150, stats.nominal_rate
    (True, 1000.0)
    """

    def __init__(self, step: Callable[[Any, Any, float], Any], state: Any = None, *, rate: float = 1000.0,
                 source: Callable[[], Any] | None = None, sink: Callable[[Any], Any] | None = None,
                 snapshot: Callable[[Any, Any, Any], Mapping[str, Any]] | None = None,
                 snapshot_rate: float = 240.0, on_stop: Callable[[], Any] | None = None,
                 spin: float | None = None, history: int = 65536, pause_gc: bool = True,
                 priority: int = 0, trace: int = 0) -> None:
        if not callable(step):
            raise HapticsError(f"step must be a callable step(state, inputs, dt) (got {type(step).__name__})")
        for name, f in (("source", source), ("sink", sink), ("snapshot", snapshot), ("on_stop", on_stop)):
            if f is not None and not callable(f):
                raise HapticsError(f"{name} must be callable or None (got {type(f).__name__})")
        try:
            rate = float(rate)
        except (TypeError, ValueError) as exc:
            raise HapticsError(f"rate must be a number of ticks per second (got {rate!r})") from exc
        if not (1.0 <= rate <= 20000.0):
            raise HapticsError(f"rate must be between 1 and 20000 Hz (got {rate!r}); the servo loop runs at 1-10 kHz")
        snapshot_rate = float(snapshot_rate)
        if not (snapshot_rate > 0.0 and math.isfinite(snapshot_rate)):
            raise HapticsError(f"snapshot_rate must be a positive rate in Hz (got {snapshot_rate!r})")
        self._spin_given = spin is not None
        if spin is None:
            spin = min(2e-4, 0.75 / rate)
        try:
            spin = float(spin)
        except (TypeError, ValueError) as exc:
            raise HapticsError(f"spin must be a time in seconds or None (got {spin!r})") from exc
        if not (0.0 <= spin <= 0.01):
            raise HapticsError(f"spin must be between 0 and 0.01 s (got {spin!r})")
        if not isinstance(history, int) or history < 16:
            raise HapticsError(f"history must be an integer >= 16 (got {history!r})")
        if not isinstance(priority, int) or isinstance(priority, bool) or not 0 <= priority <= 99:
            raise HapticsError(f"priority must be an integer in [0, 99] (got {priority!r}); 0: no real-time policy")
        if not isinstance(trace, int) or isinstance(trace, bool) or trace < 0:
            raise HapticsError(f"trace must be a number of ticks >= 0 (got {trace!r}); 0: no trace")
        self._trace_n = trace
        self.trace: TickTrace | None = None
        self.priority = priority
        self.realtime_priority = 0
        self.step, self.state = step, state
        self.source, self.sink, self.snapshot_fn, self.on_stop = source, sink, snapshot, on_stop
        self.rate = rate
        self.dt = 1.0 / rate
        self._period_ns = int(round(1e9 / rate))
        self._spin_ns = int(spin * 1e9)
        self.pause_gc = bool(pause_gc)
        self._snap_every_ns = int(1e9 / snapshot_rate)
        self._history = history
        self._compute = np.zeros(history, dtype=np.int64)
        self._period = np.zeros(history, dtype=np.int64)
        self._lock = threading.Lock()
        self._snap_buf: dict[str, np.ndarray] | None = None
        self._snap_tick = -1
        self._snap_time = math.nan
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self.error: BaseException | None = None
        self._reset_counters()

    def _reset_counters(self) -> None:
        self.ticks = 0
        self.pacer: Pacer | None = None
        self.trace = TickTrace(self._trace_n) if self._trace_n else None
        self.cpu_ns = 0
        self.snapshots_published = 0
        self.snapshots_skipped = 0
        self._t_start = 0
        self._t_end = 0
        self._last_snap_ns = None
        self._n_period = 0

    # -- snapshot ---------------------------------------------------------------------------
    def _publish(self, inputs, output, tick: int, t: float, blocking: bool) -> None:
        values = self.snapshot_fn(self.state, inputs, output)
        if not self._lock.acquire(blocking=blocking):
            self.snapshots_skipped += 1
            return
        try:
            buf = self._snap_buf
            if buf is None:
                buf = {}
                for k, v in values.items():
                    buf[k] = np.array(v, copy=True)
                self._snap_buf = buf
            else:
                for k, v in values.items():
                    dst = buf[k]
                    dst[...] = v
            self._snap_tick = tick
            self._snap_time = t
            self.snapshots_published += 1
        finally:
            self._lock.release()

    def snapshot(self) -> Snapshot | None:
        """A consistent copy of the last published values (None before the first publication)."""
        with self._lock:
            if self._snap_buf is None:
                return None
            return Snapshot(self._snap_tick, self._snap_time, {k: v.copy() for k, v in self._snap_buf.items()})

    # -- deterministic run --------------------------------------------------------------------
    def run_ticks(self, n: int) -> None:
        """Run ``n`` ticks back to back in the calling thread, no clock, no sleeping.

        Every tick publishes its snapshot (time ``tick * dt``). Exceptions from ``step`` propagate.
        """
        if self.is_running:
            raise HapticsError("the scheduler thread is running; stop() it before run_ticks()")
        if not isinstance(n, (int, np.integer)) or n < 0:
            raise HapticsError(f"n must be a non-negative integer (got {n!r})")
        step, dt, source, sink = self.step, self.dt, self.source, self.sink
        for _ in range(int(n)):
            inputs = source() if source is not None else None
            out = step(self.state, inputs, dt)
            if sink is not None:
                sink(out)
            if self.snapshot_fn is not None:
                self._publish(inputs, out, self.ticks, self.ticks * dt, blocking=True)
            self.ticks += 1

    # -- threaded run -------------------------------------------------------------------------
    @property
    def is_running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def start(self) -> "Scheduler":
        """Start the loop thread (statistics restart from zero)."""
        if self.is_running:
            raise HapticsError("the scheduler is already running")
        self._reset_counters()
        self.error = None
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="arsurf-servo", daemon=True)
        self._thread.start()
        return self

    def stop(self, timeout: float = 2.0) -> TimingStats:
        """Stop the loop and return its statistics; raises :class:`LoopError` if ``step`` failed."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
            if self._thread.is_alive():
                raise HapticsError(f"the servo thread did not stop within {timeout} s (a step is blocking)")
            self._thread = None
        if self.error is not None:
            err, self.error = self.error, None
            raise LoopError(f"step raised {type(err).__name__}: {err}; the servo loop stopped") from err
        return self.stats()

    def run_for(self, seconds: float) -> TimingStats:
        """Start, let the loop run for ``seconds`` of wall time, stop; returns the statistics."""
        try:
            seconds = float(seconds)
        except (TypeError, ValueError) as exc:
            raise HapticsError(f"seconds must be a duration in seconds (got {seconds!r})") from exc
        if not (math.isfinite(seconds) and seconds >= 0.0):
            raise HapticsError(f"seconds must be a finite duration >= 0 s (got {seconds!r})")
        self.start()
        try:
            # one blocking wait, no polling: a waking caller takes the GIL from the loop thread
            # (up to the switch interval), which made ticks late at 10 kHz
            self._thread.join(seconds)
        finally:
            stats = self.stop()
        return stats

    def __enter__(self) -> "Scheduler":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def elapsed(self) -> float:
        """Seconds since the loop started (the loop's clock)."""
        return (time.perf_counter_ns() - self._t_start) * 1e-9

    def pacer_for(self, realtime: bool, *, clock: Callable[[], int] = time.perf_counter_ns,
                  sleep: Callable[[float], Any] = time.sleep,
                  cpu_clock: Callable[[], int] = time.thread_time_ns) -> Pacer:
        """The :class:`Pacer` the loop thread keeps time with, under ``SCHED_FIFO`` when
        ``realtime``: a wake margin learned between :data:`FIFO_SPIN` (at most a quarter of a
        period) and the ordinary policy's margin (a given ``spin`` is kept as is), and an idle
        share of :data:`FIFO_IDLE_SHARE` on the thread's CPU clock; under the ordinary policy
        the ``spin`` margin and no idle share (an ordinary thread is not throttled, and the
        time-sharing scheduler preempts it anyway)."""
        spin = spin_max = self._spin_ns
        idle = 0.0
        if realtime:
            if not self._spin_given:
                spin = int(min(FIFO_SPIN, 0.25 * self.dt) * 1e9)
            idle = FIFO_IDLE_SHARE
        return Pacer(self._period_ns, spin, idle, FIFO_IDLE_BURST_NS if realtime else 0, spin_max_ns=spin_max,
                     clock=clock, sleep=sleep, cpu_clock=cpu_clock, trace=self.trace)

    def _run(self) -> None:
        _tight_timer_slack()
        self.realtime_priority = _realtime_priority(self.priority)
        gc_was_on = gc.isenabled()
        if self.pause_gc:
            gc.freeze()
            gc.disable()
        old_switch = sys.getswitchinterval()
        sys.setswitchinterval(min(old_switch, max(1e-5, self.dt / 4.0)))
        clock = time.perf_counter_ns
        pacer = self.pacer = self.pacer_for(bool(self.realtime_priority))
        step, dt, source, sink = self.step, self.dt, self.source, self.sink
        publish = self.snapshot_fn is not None
        hist = self._history
        compute, periods = self._compute, self._period
        cpu0 = time.thread_time_ns()
        try:
            t0 = pacer.start()
            self._t_start = t0
            k = 0
            while not self._stop.is_set():
                start = pacer.begin()
                if k:
                    periods[self._n_period % hist] = pacer.last_gap
                    self._n_period += 1
                inputs = source() if source is not None else None
                out = step(self.state, inputs, dt)
                if sink is not None:
                    sink(out)
                end = clock()
                compute[k % hist] = end - start
                if publish and (self._last_snap_ns is None or end - self._last_snap_ns >= self._snap_every_ns):
                    self._publish(inputs, out, k, (start - t0) * 1e-9, blocking=False)
                    self._last_snap_ns = end
                k += 1
                self.ticks = k
                pacer.wait()
        except BaseException as exc:  # reported by stop()
            self.error = exc
        finally:
            pacer.finish()
            self._t_end = clock()
            self.cpu_ns = time.thread_time_ns() - cpu0
            sys.setswitchinterval(old_switch)
            if self.pause_gc:
                gc.unfreeze()
                if gc_was_on:
                    gc.enable()
            if self.on_stop is not None:
                try:
                    self.on_stop()
                except BaseException as exc:  # pragma: no cover - reported, never swallowed
                    if self.error is None:
                        self.error = exc

    # -- statistics ---------------------------------------------------------------------------
    def stats(self) -> TimingStats:
        """Timing statistics of the current or last run."""
        k = self.ticks
        end = self._t_end if not self.is_running and self._t_end else time.perf_counter_ns()
        duration = max(0.0, (end - self._t_start) * 1e-9) if self._t_start else 0.0
        nc = min(k, self._history)
        npd = min(self._n_period, self._history)
        comp = self._compute[:nc] * 1e-9 if nc else np.zeros(1)
        per = self._period[:npd] * 1e-9 if npd else np.full(1, self.dt)
        jit = np.abs(per - self.dt)
        p = self.pacer
        return TimingStats(
            ticks=k,
            duration=duration,
            rate=(k / duration) if duration > 0 else 0.0,
            nominal_rate=self.rate,
            compute_median=float(np.median(comp)),
            compute_p99=float(np.percentile(comp, 99)),
            compute_max=float(comp.max()),
            period_median=float(np.median(per)),
            jitter_p99=float(np.percentile(jit, 99)),
            jitter_max=float(jit.max()),
            overruns=p.overruns if p else 0,
            skipped=p.skipped if p else 0,
            snapshots_published=self.snapshots_published,
            snapshots_skipped=self.snapshots_skipped,
            realtime_priority=self.realtime_priority,
            longest_gap=p.longest_gap * 1e-9 if p else 0.0,
            spin_max=p.spin_max * 1e-9 if p else 0.0,
            awake_max=p.awake_share() if p else 0.0,
            cpu_max=p.cpu_max if p else 0.0,
            cpu_share=(self.cpu_ns * 1e-9 / duration) if duration > 0 and not self.is_running else 0.0,
            margin_max=p.margin_max * 1e-9 if p else 0.0,
            forced_naps=p.forced_naps if p else 0,
        )
