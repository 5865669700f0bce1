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
and there is no burst of catch-up ticks). Under ``SCHED_FIFO`` the spin is short
(:data:`FIFO_SPIN`) and the thread sleeps at least :data:`FIFO_IDLE_SHARE` of its time, even
after an overrun, so it is never awake long enough to meet the kernel's real-time throttling;
:class:`Pacer` keeps this discipline, on an injectable clock. Statistics are kept in
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
           "TimingStats", "choose_realtime"]

#: busy-wait margin (s) before each deadline when the loop thread runs under SCHED_FIFO: a
#: real-time thread's sleep ends within tens of microseconds, and the short spin keeps the thread
#: idle most of each period, below Linux's real-time throttling (sched_rt_runtime_us 950000 of
#: every 1000000: a thread spinning ~all of each period was stopped ~50 ms each second)
FIFO_SPIN = 3e-5

#: least share of its time a real-time loop thread sleeps, whatever its step costs (after each
#: tick it sleeps at least 1/9 of the time it was awake): it is then awake at most 90 % of any
#: second, below the kernel's 95 % real-time budget, so the throttling (a ~50 ms stop of the
#: thread) is never reached, and ordinary threads on its core always get 10 %
FIFO_IDLE_SHARE = 0.1

#: awake time (ns) a real-time loop may run ahead of :data:`FIFO_IDLE_SHARE` before it must
#: sleep: a one-off stall of a few ms is not paid back at once (that would lengthen the gap),
#: and the worst second stays at 90 % + 1 % awake
FIFO_IDLE_BURST_NS = 10_000_000

#: the window (ns) of :attr:`Pacer.awake_max`: the kernel's real-time period
_AWAKE_WINDOW_NS = 1_000_000_000


class Pacer:
    """The loop's time-keeping: an absolute deadline grid, overruns and skipped slots, and the
    wait before each deadline, a sleep then a spin of at most ``spin_ns``.

    Deadlines are :math:`t_k = t_0 + k\\,T`. After the tick's work, :meth:`wait` sleeps until
    ``spin_ns`` before the next deadline, then spins on the clock to the deadline. With an
    ``idle_share`` :math:`s`, each time awake :math:`a` owes a sleep of :math:`a\\,s/(1-s)` and
    each sleep pays its length back; when the debt exceeds ``burst_ns`` the thread sleeps it off
    even after a late tick, so it is awake at most :math:`1 - s` of any second plus ``burst_ns``
    (a step that never fits its period runs at the rate that allows). A tick whose work ends after the next deadline is an *overrun*; deadlines that
    passed entirely are *skipped* (the grid is kept: no burst of catch-up ticks). It also counts
    the time the thread is awake - running or runnable, everything but its sleeps here - per
    second of the kernel's real-time accounting (:attr:`awake_max`), and the thread's CPU time
    per second (:attr:`cpu_max`, from ``cpu_clock`` read once a second; it also counts the
    kernel's work for the sleeps themselves): under ``SCHED_FIFO`` the kernel stops a thread that
    ran more than 95 % of a second (``sched_rt_runtime_us``).

    ``clock`` (ns, monotonic), ``sleep`` (s) and ``cpu_clock`` (ns) are injectable: tests drive
    the pacer with a scripted clock, no timing involved.

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
                 clock: Callable[[], int] = time.perf_counter_ns, sleep: Callable[[float], Any] = time.sleep,
                 cpu_clock: Callable[[], int] = time.thread_time_ns) -> None:
        self.period = int(period_ns)
        self.spin = int(spin_ns)
        if not 0.0 <= idle_share < 1.0:
            raise HapticsError(f"idle_share must be in [0, 1) (got {idle_share!r})")
        self.idle_ratio = idle_share / (1.0 - idle_share)  # sleep owed per unit of time awake
        self.burst = int(burst_ns)
        self.clock, self.sleep, self.cpu_clock = clock, sleep, cpu_clock
        self.start(clock())

    def start(self, t0: int | None = None) -> int:
        """Put the grid's origin at ``t0`` (default now) and clear the counts; returns ``t0``."""
        t0 = self.clock() if t0 is None else int(t0)
        self.t0 = self.deadline = self._awake_since = t0
        self._last_start = None
        self.overruns = self.skipped = 0
        self.longest_gap = 0          # ns between two tick starts
        self.spin_max = 0             # ns, the longest spin before a deadline
        self.awake = 0                # ns awake, whole run
        self.awake_max = 0.0          # the largest share of a whole second spent awake
        self._window_end = t0 + _AWAKE_WINDOW_NS
        self._window_awake = 0
        self._debt = 0.0              # ns of sleep owed
        self.cpu_max = 0.0            # the largest share of a second the thread spent on the CPU
        self._cpu_mark = (t0, self.cpu_clock())
        return t0

    def begin(self) -> int:
        """A tick starts now: returns the time, ns, and the gap since the previous start (0 first)."""
        start = self.clock()
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

    def wait(self) -> None:
        """The tick's work is done: count an overrun and skipped slots, then sleep and spin to
        the next deadline."""
        clock, period = self.clock, self.period
        self.deadline += period
        now = clock()
        if now > self.deadline:  # this tick ended after the next one should have started
            self.overruns += 1
            missed = (now - self.deadline) // period
            if missed:  # whole periods lost: skip those slots, stay on the grid
                self.skipped += int(missed)
                self.deadline += missed * period
        self._debt += self.idle_ratio * (now - self._awake_since)
        nap = max(self.deadline - now - self.spin, int(self._debt) - self.burst)
        if nap > 0:
            self._count_awake(self._awake_since, now)
            self.sleep(nap * 1e-9)
            woke = clock()
            self._debt = max(0.0, self._debt - (woke - now))
            now = self._awake_since = woke
        spin_from = now
        while now < self.deadline:
            now = clock()
        if now - spin_from > self.spin_max:
            self.spin_max = now - spin_from

    def finish(self) -> None:
        """The loop ended: count its last time awake."""
        self._count_awake(self._awake_since, self.clock())
        self._awake_since = self.clock()


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
    (after the run).
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
        when the thread got ``SCHED_FIFO``: a real-time sleeper is woken on time, and a thread
        that spins most of each period meets Linux's real-time throttling - 950 ms of every
        second by default - and stops for ~50 ms each second). A sleep here ends up to ~50-100 µs late, so at 10 kHz a half-period margin
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
    priority : int
        Real-time priority of the loop thread, ``SCHED_FIFO`` 1-99 where the OS grants it
        (:data:`DEFAULT_REALTIME_PRIORITY`, 10, is what ``arsurf live`` asks for; keep it below
        the 50 of Linux's interrupt threads), or 0 (default here): the ordinary policy; the
        CLI decides with :func:`choose_realtime`. What was granted is
        :attr:`TimingStats.realtime_priority`. A real-time loop thread keeps the machine's
        other work from delaying a tick, but it also runs before this process's other threads
        on its core: a device whose driver answers from a thread of this process (the simulated
        Haply's reader) then went unanswered for 0.4 s. It sleeps at least
        :data:`FIFO_IDLE_SHARE` of its time (:meth:`pacer_for`). At 10 kHz over 60 s on the
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
                 priority: int = 0) -> None:
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
        ``realtime``: a spin of :data:`FIFO_SPIN` (at most a quarter of a period; a given
        ``spin`` is kept) and a sleep of at least :data:`FIFO_IDLE_SHARE` of its time; under
        the ordinary policy the ``spin`` margin and no least sleep (an ordinary thread is not
        throttled, and the time-sharing scheduler preempts it anyway)."""
        spin, idle = self._spin_ns, 0.0
        if realtime:
            if not self._spin_given:
                spin = int(min(FIFO_SPIN, 0.25 * self.dt) * 1e9)
            idle = FIFO_IDLE_SHARE
        return Pacer(self._period_ns, spin, idle, FIFO_IDLE_BURST_NS if realtime else 0, clock=clock, sleep=sleep,
                     cpu_clock=cpu_clock)

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
        )
