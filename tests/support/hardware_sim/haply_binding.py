"""A stand-in for the ``HaplyHardwareAPI`` module on a modelled clock: the Haply adapter's timing
tested without a serial port and without real waiting.

What it models is the package's behaviour, not the adapter's: ``haplyhardwareapi`` 0.1.13 on a
pseudo-terminal (traced with strace) writes the 13-byte force command, then busy-polls the port
(``ioctl FIONREAD``) for the reply's header until its read timeout, then for the 24-byte body until
the read timeout again, and returns zeros for a reply that did not come (it prints an error and
never raises); ``flush_input`` drains the input at once. The Inverse3 answers only a command, each
with its state (Haply's Inverse Service documentation: to read the position "you must send a force
value to the device"), ``latency`` s later. So an exchange costs its caller ``latency``, and a lost
reply ``2 * read_timeout``: that time is charged to the thread that made the call
(:attr:`FakeInverse3.calls`), so a test reads who waited, and how long, deterministically. The
clock (:class:`ModelClock`) is the test's: it moves only when the test advances it (the adapter's
link thread exchanges on its own, so its calls must not move the test's time).

``lose(n)`` loses the replies to the next ``n`` commands (the device applied the force, the host
never heard back); ``lose(n, late=True)`` makes them late instead: such a reply lands while the
next exchange waits (after any flush before it), and the package, which reads whatever bytes come
first (the protocol has no sequence number), returns it as that exchange's reply, leaving the
exchange's own reply in the input for the one after (:attr:`Call.answer_to` says whose state each
call returned); ``hold()`` makes the next exchange wait, for real, until ``release()`` (a reply
still on its way while the loop goes on).
"""
from __future__ import annotations

import threading
import uuid
from dataclasses import dataclass

REST = (0.04, -0.15, 0.15)  # m, Inverse3 frame: where the handle rests, in front of the base
UUID_BYTES = bytes(range(0x10, 0x20))


class ModelClock:
    """Seconds that pass only when told (:meth:`advance`); callable like ``time.perf_counter``."""

    def __init__(self, t0: float = 100.0) -> None:
        self.t = float(t0)
        self._lock = threading.Lock()

    def __call__(self) -> float:
        return self.t

    def advance(self, dt: float) -> None:
        with self._lock:
            self.t += float(dt)


@dataclass
class Call:
    """One ``end_effector_force``: the calling thread, the force (N), the modelled time it took (s),
    whether its reply was lost, and the index of the call whose reply it returned (None: zeros)."""

    thread: int
    force: tuple
    cost: float
    lost: bool
    answer_to: int | None = None


class FakeInverse3:
    """The ``Inverse3`` object of the package, on a :class:`ModelClock`."""

    def __init__(self, clock: ModelClock, latency: float = 1e-4) -> None:
        self.clock = clock
        self.latency = float(latency)
        self.read_timeout = 5.0  # the package's default, until set_read_timeout
        self.calls: list[Call] = []
        self.position = list(REST)
        self.velocity = [0.0, 0.0, 1e-3]
        self._lose = 0
        self._late = False
        self._landing = []  # late replies that land during the next exchange's wait: (index, state)
        self._input = []  # replies waiting in the input: (index, state)
        self._gate = threading.Event()
        self._gate.set()
        self.holding = threading.Event()  # an exchange is waiting in hold()
        self.flushes = 0

    # -- the package's API, as the adapter calls it ------------------------------------------------
    def device_wakeup_dict(self) -> dict:
        return {"device_id": 0x2A2A, "device_model_number": 3, "hardware_version": 1, "firmware_version": 7,
                "device_id_ext": uuid.UUID(bytes=UUID_BYTES)}

    def set_read_timeout(self, t: float) -> None:
        self.read_timeout = float(t)

    def end_effector_force(self, force=(0.0, 0.0, 0.0)):
        if not self._gate.is_set():
            self.holding.set()
            self._gate.wait(30.0)
            self.holding.clear()
        k = len(self.calls)
        lost = self._lose > 0
        self._lose -= lost
        own = (k, (list(self.position), list(self.velocity)))
        self._input += self._landing  # a late reply lands while this exchange waits
        self._landing = []
        if lost and self._late:
            self._landing.append(own)
        elif not lost:
            self._input.append(own)
        got = self._input.pop(0) if self._input else None
        cost = self.latency if got is not None else 2.0 * self.read_timeout  # header wait, then body wait
        self.calls.append(Call(threading.get_ident(), tuple(float(f) for f in force), cost, got is None,
                               None if got is None else got[0]))
        if got is None:
            return [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]
        return got[1]

    def flush_input(self) -> None:
        self.flushes += 1
        self._input.clear()

    # -- the test's controls --------------------------------------------------------------------------
    def lose(self, n: int = 1, late: bool = False) -> None:
        """Lose the replies to the next ``n`` commands (``late``: they land during the next exchange)."""
        self._lose, self._late = int(n), bool(late)

    def hold(self) -> None:
        """The next exchange waits (for real, at most 30 s) until :meth:`release`."""
        self._gate.clear()

    def release(self) -> None:
        self._gate.set()


class FakeHaplyBinding:
    """The module: ``SerialStream``, ``Inverse3`` (always :attr:`inverse3`), the detection calls."""

    def __init__(self, clock: ModelClock, port: str, latency: float = 1e-4) -> None:
        self.port = port
        self.inverse3 = FakeInverse3(clock, latency)

    def SerialStream(self, port: str):  # noqa: N802 - the package's name
        if port != self.port:
            raise RuntimeError(f"no device on {port}")
        return object()

    def Inverse3(self, stream, timeout: float = 5.0):  # noqa: N802 - the package's name
        return self.inverse3

    def detect_inverse3s(self) -> list[str]:
        return [self.port]

    def detect_handles(self) -> list[str]:
        return []


__all__ = ["Call", "FakeHaplyBinding", "FakeInverse3", "ModelClock", "REST"]
