"""A simulated Haply Inverse3 (and VerseGrip handle) on a pseudo-terminal.

The serial protocol is the one ``HaplyHardwareAPI`` 0.1.x speaks, read off the package itself (the
bytes it writes to a pty, traced, and the replies it accepts), not off arsurf's adapter: a command
byte, then little-endian ``float32`` fields. The Inverse3 answers the wake-up ``0A`` with ``0B`` and
its identity, each force command ``2A fx fy fz`` with ``2B`` and its position and velocity, and
nothing unasked (Haply's Inverse Service documentation: to read the position "you must send a force
value to the device", even zero); it answers as soon as its thread runs (Haply gives no latency
figure; its service streams states at "multi-kHz" rates, so well under a 1 ms period); the handle
answers ``0A`` with ``D0`` + 6 bytes and each status request ``DA`` with ``DA`` + status + user
data (first byte: buttons). The handle's dynamics are those of ``sim_handle.h`` (mass, damping,
a hand spring to a set point), advanced on the wall clock (5 kHz steps) by a thread of its own, in the Inverse3's
frame (metres; the handle rests around (0.04, -0.15, 0.15) m, in front of the base).

``unplug()`` closes the pty's master side: the package's writes then fail and its reads time out,
as when the USB cable is pulled. ``lose(n, late)`` loses the replies to the next ``n`` force
commands (``late`` s: they arrive that late instead, as a reply stuck behind a USB hiccup does;
None: never), the way a serial link does: the device applied the force, the host never heard back.
Every force command is logged (``commands_log``: host time s, force N) so a test can see what was
sent after a lost reply.
"""
from __future__ import annotations

import os
import pty
import select
import struct
import collections
import threading
import time
import tty

import numpy as np

REST = np.array([0.04, -0.15, 0.15])
UUID = bytes(range(0x10, 0x20))


class _Pty:
    def __init__(self) -> None:
        self.master, self.slave = pty.openpty()
        tty.setraw(self.master)
        self.path = os.ttyname(self.slave)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self.alive = True
        self.commands = 0

    def start(self):
        self._thread.start()
        return self

    def _serve(self) -> None:
        buf = b""
        while not self._stop.is_set():
            try:
                r, _, _ = select.select([self.master], [], [], 0.01)
                if not r:
                    continue
                buf += os.read(self.master, 4096)
            except OSError:
                return
            buf = self._handle(buf)

    def _reply(self, data: bytes) -> None:
        try:
            os.write(self.master, data)
        except OSError:
            pass

    def unplug(self) -> None:
        self.alive = False
        self._stop.set()
        self._thread.join(timeout=1.0)
        os.close(self.master)

    def close(self) -> None:
        if self.alive:
            self.unplug()
        try:
            os.close(self.slave)
        except OSError:
            pass


class Inverse3Pty(_Pty):
    """The Inverse3 end of the cable. Attributes: ``x``, ``v`` (m, m/s), ``force`` (N, applied),
    ``hand`` (the set point the operator holds, m), ``max_force_seen`` (N, largest commanded)."""

    def __init__(self, mass=0.2, damping=2.0, hand_k=200.0, hand_b=5.0, fmax_hw=10.0) -> None:
        super().__init__()
        self.m, self.b, self.kh, self.bh, self.fmax_hw = mass, damping, hand_k, hand_b, fmax_hw
        self.hand = REST.copy()
        self.x = REST.copy()
        self.v = np.zeros(3)
        self.force = np.zeros(3)
        self.max_force_seen = 0.0
        self.commands_log = collections.deque(maxlen=200_000)
        self._lose = 0
        self._lose_above = 0.0
        self._late = None
        self.lost_at = []  # indexes in commands_log of the commands whose reply was lost
        self.t = time.perf_counter()
        self.lock = threading.Lock()
        self._physics = threading.Thread(target=self._run_physics, daemon=True)

    def start(self):
        super().start()
        self._physics.start()
        return self

    def _run_physics(self) -> None:
        while not self._stop.is_set():
            with self.lock:
                self._advance()
            time.sleep(0.001)

    def lose(self, n: int = 1, late: float | None = None, above: float = 0.0) -> None:
        """Lose the replies to the next ``n`` force commands larger than ``above`` N (``late`` s:
        send them that late)."""
        with self.lock:
            self._lose, self._late, self._lose_above = int(n), late, float(above)

    def _advance(self) -> None:
        now = time.perf_counter()
        step = 2e-4  # 5 kHz; the physics thread keeps it current, so a reply never waits long on it
        self.t = max(self.t, now - 0.2)
        while self.t + step <= now:
            acc = (self.force - self.b * self.v + self.kh * (self.hand - self.x) - self.bh * self.v) / self.m
            self.v += step * acc
            self.x += step * self.v
            self.t += step

    def _handle(self, buf: bytes) -> bytes:
        while buf:
            code = buf[0]
            if code == 0x0A:
                self._reply(b"\x0b" + struct.pack("<HBBB", 0x2A2A, 3, 1, 7) + UUID)
                buf = buf[1:]
            elif code == 0x2A:
                if len(buf) < 13:
                    return buf
                f = np.array(struct.unpack("<3f", buf[1:13]), dtype=np.float64)
                buf = buf[13:]
                with self.lock:
                    self._advance()
                    n = float(np.linalg.norm(f))
                    self.max_force_seen = max(self.max_force_seen, n)
                    self.force = f * (min(1.0, self.fmax_hw / n) if n > 0 else 1.0)
                    state = struct.pack("<6f", *self.x, *self.v)
                    self.commands_log.append((time.perf_counter(), f))
                    lost, late = self._lose > 0 and n > self._lose_above, self._late
                    self._lose -= lost
                    if lost:
                        self.lost_at.append(len(self.commands_log) - 1)
                self.commands += 1
                if not lost:
                    self._reply(b"\x2b" + state)
                elif late is not None:
                    threading.Timer(late, self._reply, (b"\x2b" + state,)).start()
            else:  # a byte this device does not know: dropped, as the firmware does
                buf = buf[1:]
        return buf

    def state(self):
        with self.lock:
            self._advance()
            return self.x.copy(), self.v.copy(), self.force.copy()


class HandlePty(_Pty):
    """The VerseGrip end: ``buttons`` is the first user-data byte of every status."""

    def __init__(self) -> None:
        super().__init__()
        self.buttons = 0

    def _handle(self, buf: bytes) -> bytes:
        for code in buf:
            if code == 0x0A:
                self._reply(bytes([0xD0, 0, 0, 7, 2, 1, 3]))
            elif code == 0xDA:
                status = struct.pack("<HBB4fB", 0x0207, 0, 40, 1.0, 0.0, 0.0, 0.0, 2) + bytes([self.buttons, 90])
                self._reply(b"\xda" + status)
        return b""


def close_all(*ptys) -> None:
    for p in ptys:
        if p is not None:
            p.close()


__all__ = ["HandlePty", "Inverse3Pty", "REST", "close_all"]
