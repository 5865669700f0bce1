"""A simulated haptic device held by a modelled hand: the default device and the test fixture.

The master is a mass with viscous damping per axis, [Bolopion] Eq. 15,

.. math:: H_m(s) = \\frac{V_m(s)}{F(s)} = \\frac{1}{B_v + M_v s},

driven by the commanded force and by the operator. The operator is a hand that holds the stylus
through a spring-damper (stiffness :math:`K_h`, damping :math:`B_h`) and moves its own set point
:math:`p` along a scripted trajectory :math:`r(t)` through a critically damped second-order
filter of bandwidth :math:`f_h` (about 10 Hz: the human hand cannot move the stylus faster, seed
001 section 4.3, Figs. 4.15-4.17):

.. math::

    \\ddot p = \\omega_h^2 (r - p) - 2\\omega_h \\dot p, \\qquad
    M_v \\ddot x = F_{cmd} + F_{ext} - B_v \\dot x + K_h (p - x) + B_h (\\dot p - \\dot x),
    \\qquad \\omega_h = 2\\pi f_h .

Per axis this is a linear system in :math:`z = (p, \\dot p, x, \\dot x)` with inputs
:math:`u = (r, F_{cmd} + F_{ext})`. The inputs are held over a tick (zero-order hold, as a real
device holds its force between servo ticks) and the state is advanced *exactly*:
:math:`z_{k+1} = \\Phi z_k + \\Gamma u_k` with :math:`\\Phi = e^{A\\,\\Delta t}` and
:math:`\\Gamma = \\int_0^{\\Delta t} e^{A s}\\,ds\\,B`, computed once per device. The simulation is
deterministic: the clock is the tick count times ``dt``, never the wall clock.

Default parameters. [Alabdulmuhsin] Eq. 30 fits the hand-held stylus (hand + Touch X) by
:math:`H(s) = 300/(s^2 + 100 s + 10000)` m/N (force to position): a total mass of 1/300 kg,
damping 1/3 N s/m and hand stiffness 100/3 N/m (:math:`\\omega_n` = 100 rad/s, 16 Hz, :math:`\\zeta`
= 0.5). The defaults reproduce it exactly; how the damping splits between device (:math:`B_v`,
10 %) and hand (:math:`B_h`, 90 %) is a choice the seed does not make.

Examples
--------
>>> import numpy as np
>>> dev = VirtualDevice(dt=1e-3, hand=HandModel(trajectory=lambda t: [0.01 * np.sin(2 * np.pi * t), 0, 0]))
>>> with dev:
...     for _ in range(250):
...         dev.command_force([0.0, 0.0, 0.0])
...     round(float(dev.read_state().position[0]), 4)   # a quarter period later: ~0.01 m, lagging
0.0097
"""
from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from numba import njit
from scipy.linalg import expm

from arsurf.errors import HapticsError
from arsurf.haptics.device import Device, DeviceInfo, DeviceState, TOUCH_X, _vec3

__all__ = [
    "DEFAULT_DAMPING",
    "DEFAULT_HAND_DAMPING",
    "DEFAULT_HAND_STIFFNESS",
    "DEFAULT_MASS",
    "HAND_BANDWIDTH",
    "HandModel",
    "VirtualDevice",
    "discretize_zoh",
]

# [Alabdulmuhsin] Eq. 30: H(s) = 300 / (s^2 + 100 s + 10000) m/N for the hand-held stylus, i.e.
# 1 / (M s^2 + B s + K) with M = 1/300 kg, B = 100/300 N s/m, K = 10000/300 N/m.
DEFAULT_MASS = 1.0 / 300.0  # kg, all of the fitted mass is given to the device
DEFAULT_DAMPING = 0.1 * (100.0 / 300.0)  # N s/m, device share of the fitted damping (a choice)
DEFAULT_HAND_DAMPING = 0.9 * (100.0 / 300.0)  # N s/m, hand share of the fitted damping
DEFAULT_HAND_STIFFNESS = 10000.0 / 300.0  # N/m, the fitted stiffness is the hand's grip
HAND_BANDWIDTH = 10.0  # Hz, human hand bandwidth, [Alabdulmuhsin] section 4.3 (ref. [32] there)


def discretize_zoh(A, B, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact zero-order-hold discretisation of :math:`\\dot z = A z + B u`.

    .. math:: \\Phi = e^{A\\Delta t}, \\quad \\Gamma = \\int_0^{\\Delta t} e^{As}\\,ds\\;B,

    both read off one matrix exponential of the block matrix [[A, B], [0, 0]] (Van Loan).

    Parameters
    ----------
    A : (n, n) float
    B : (n, m) float
    dt : float, s

    Returns
    -------
    Phi : (n, n) float
    Gamma : (n, m) float

    Examples
    --------
    >>> Phi, Gamma = discretize_zoh([[0.0, 1.0], [0.0, 0.0]], [[0.0], [1.0]], 0.1)
    >>> Phi.tolist(), Gamma.ravel().round(6).tolist()
    ([[1.0, 0.1], [0.0, 1.0]], [0.005, 0.1])
    """
    A = np.asarray(A, dtype=np.float64)
    B = np.asarray(B, dtype=np.float64)
    n, m = A.shape[0], B.shape[1]
    M = np.zeros((n + m, n + m))
    M[:n, :n] = A
    M[:n, n:] = B
    E = expm(M * dt)
    return np.ascontiguousarray(E[:n, :n]), np.ascontiguousarray(E[:n, n:])


@njit(cache=True)
def _read_kernel(z, position, velocity):
    for a in range(3):
        position[a] = z[a, 2]
        velocity[a] = z[a, 3]


@njit(cache=True)
def virtual_device_advance(phi, gamma, z, r, f):
    """Advance the per-axis state ``z`` (3, 4) by one tick: z <- Phi z + Gamma (r, f). No allocation."""
    for a in range(3):
        z0 = z[a, 0]
        z1 = z[a, 1]
        z2 = z[a, 2]
        z3 = z[a, 3]
        for i in range(4):
            z[a, i] = (
                phi[a, i, 0] * z0
                + phi[a, i, 1] * z1
                + phi[a, i, 2] * z2
                + phi[a, i, 3] * z3
                + gamma[a, i, 0] * r[a]
                + gamma[a, i, 1] * f[a]
            )


def _trajectory_function(trajectory) -> Callable[[float, np.ndarray], None] | None:
    """Normalise a trajectory spec to ``fill(t, out)`` (None: hold the initial position)."""
    if trajectory is None:
        return None
    if callable(trajectory):
        def fill(t, out, _f=trajectory):
            out[:] = _f(t)
        return fill
    try:
        times, points = trajectory
    except (TypeError, ValueError) as exc:
        raise HapticsError(
            "trajectory must be None, a callable t -> (3,) position in metres, or a pair "
            f"(times (n,), positions (n, 3)) (got {type(trajectory).__name__})"
        ) from exc
    times = np.asarray(times, dtype=np.float64)
    points = np.asarray(points, dtype=np.float64)
    if times.ndim != 1 or points.shape != (times.size, 3) or times.size < 1:
        raise HapticsError(
            f"trajectory arrays must be times (n,) and positions (n, 3) (got {times.shape} and {points.shape})"
        )
    if not (np.isfinite(times).all() and np.isfinite(points).all()):
        raise HapticsError("trajectory times and positions must be finite (NaN/inf found)")
    if times.size > 1 and not (np.diff(times) > 0).all():
        raise HapticsError("trajectory times must be strictly increasing")

    def fill(t, out, _t=times, _p=points):
        i = int(np.searchsorted(_t, t, side="right"))
        if i <= 0:
            out[:] = _p[0]
        elif i >= _t.size:
            out[:] = _p[-1]
        else:
            w = (t - _t[i - 1]) / (_t[i] - _t[i - 1])
            out[:] = (1.0 - w) * _p[i - 1] + w * _p[i]
    return fill


class HandModel:
    """The operator's hand: a spring-damper grip whose set point follows a trajectory at ~10 Hz.

    Parameters
    ----------
    trajectory : None, callable or (times, positions)
        Where the hand wants the stylus, metres in the device frame: ``None`` holds the device's
        initial position, a callable ``t -> (3,)`` gives it at time ``t`` (s), or arrays
        ``times (n,)``, ``positions (n, 3)`` are interpolated linearly (held at both ends).
    stiffness : float or (3,), N/m
        Grip stiffness :math:`K_h` (default 100/3 N/m, [Alabdulmuhsin] Eq. 30).
    damping : float or (3,), N s/m
        Grip damping :math:`B_h` (default 0.3 N s/m, with the device's 1/30 the seed's 1/3).
    bandwidth : float, Hz
        Bandwidth :math:`f_h` of the critically damped filter between the trajectory and the hand
        set point (default 10 Hz, [Alabdulmuhsin] section 4.3).

    Examples
    --------
    >>> HandModel(bandwidth=10.0).bandwidth
    10.0
    """

    def __init__(self, trajectory=None, stiffness=DEFAULT_HAND_STIFFNESS, damping=DEFAULT_HAND_DAMPING,
                 bandwidth: float = HAND_BANDWIDTH) -> None:
        self.stiffness = _vec3(stiffness, "hand stiffness")
        self.damping = _vec3(damping, "hand damping")
        if (self.stiffness < 0).any() or (self.damping < 0).any():
            raise HapticsError(
                f"hand stiffness and damping must be >= 0 (got {self.stiffness.tolist()} N/m, "
                f"{self.damping.tolist()} N s/m)"
            )
        bandwidth = float(bandwidth)
        if not (bandwidth > 0.0 and math.isfinite(bandwidth)):
            raise HapticsError(f"hand bandwidth must be a positive frequency in Hz (got {bandwidth!r})")
        self.bandwidth = bandwidth
        self.trajectory = trajectory
        self._fill = _trajectory_function(trajectory)


_DEFAULT_HAND = object()  # sentinel: "a HandModel() holding still"


class VirtualDevice(Device):
    """A simulated master (mass + damping per axis) held by a :class:`HandModel`.

    Each :meth:`command_force` holds the force for one tick of ``dt`` seconds and advances the
    simulation exactly by that tick (see the module docstring); :meth:`read_state` returns the
    state at the current simulated time. Deterministic: the same script gives the same numbers.

    Parameters
    ----------
    dt : float, s
        Tick period (1e-3 for 1 kHz).
    mass : float or (3,), kg
        Master inertia :math:`M_v` (default 1/300 kg, [Alabdulmuhsin] Eq. 30).
    damping : float or (3,), N s/m
        Master damping :math:`B_v` (default 1/30 N s/m).
    hand : HandModel or None
        The operator's hand (default: a :class:`HandModel` holding the initial position);
        ``None`` leaves the stylus free (no grip).
    external_force : callable, optional
        ``t -> (3,)`` force (N) applied by the operator on top of the grip, e.g. the sinusoidal
        force of [Alabdulmuhsin] Eq. 29.
    buttons : int or callable, optional
        Button bitmask, constant or ``t -> int``.
    initial_position : (3,) float, m
        Start position (the hand holds it when ``hand.trajectory`` is None).
    max_force : float, N
        Saturation of :attr:`info` (default 7.9 N, Touch X); ``inf`` keeps simulations linear.
    workspace : (3,) float, m
        Workspace extents for :attr:`info` (default: Touch X).

    Attributes
    ----------
    phi : (3, 4, 4) float64
        Per-axis transition matrices :math:`\\Phi` of :math:`z = (p, \\dot p, x, \\dot x)`.
    gamma : (3, 4, 2) float64
        Per-axis input matrices :math:`\\Gamma` for :math:`u = (r, F)`.
    z : (3, 4) float64
        The state; with ``phi`` and ``gamma`` the arguments of :func:`virtual_device_advance`
        for a compiled simulation loop.

    Notes
    -----
    ``info.max_stiffness`` is :math:`4 M_v/\\Delta t^2` and ``info.max_damping`` is
    :math:`2 M_v/\\Delta t - B_v`: the stiffness and damping that a sampled coupling can render on
    this mass at this rate (corrected Table II of [Bolopion], see :mod:`arsurf.haptics.coupling`).

    Examples
    --------
    >>> dev = VirtualDevice(dt=1e-3, hand=None).open()
    >>> for _ in range(100):
    ...     dev.command_force([1.0, 0.0, 0.0])      # push a free mass for 0.1 s
    >>> s = dev.read_state(); dev.close()
    >>> round(s.timestamp, 6), bool(s.velocity[0] > 0)
    (0.1, True)
    """

    def __init__(self, dt: float = 1e-3, mass=DEFAULT_MASS, damping=DEFAULT_DAMPING,
                 hand: HandModel | None = _DEFAULT_HAND, external_force: Callable | None = None,
                 buttons=0, initial_position=(0.0, 0.0, 0.0), max_force: float = TOUCH_X.max_force,
                 workspace=TOUCH_X.workspace, name: str = "virtual") -> None:
        super().__init__()
        dt = float(dt)
        if not (dt > 0.0 and math.isfinite(dt)):
            raise HapticsError(f"dt must be a positive tick period in seconds (got {dt!r}); 1e-3 is 1 kHz")
        self.dt = dt
        self.mass = _vec3(mass, "mass")
        self.damping = _vec3(damping, "damping")
        if (self.mass <= 0).any():
            raise HapticsError(f"mass must be positive (got {self.mass.tolist()} kg)")
        if (self.damping < 0).any():
            raise HapticsError(f"damping must be >= 0 (got {self.damping.tolist()} N s/m)")
        if hand is _DEFAULT_HAND:
            hand = HandModel()
        elif hand is not None and not isinstance(hand, HandModel):
            raise HapticsError(f"hand must be a HandModel or None for a free stylus (got {type(hand).__name__})")
        self.hand = hand
        if external_force is not None and not callable(external_force):
            raise HapticsError("external_force must be a callable t -> (3,) force in newtons, or None")
        self.external_force = external_force
        if not (callable(buttons) or isinstance(buttons, (int, np.integer))):
            raise HapticsError(f"buttons must be an int bitmask or a callable t -> int (got {buttons!r})")
        self.buttons = buttons if callable(buttons) else int(buttons)
        self.initial_position = _vec3(initial_position, "initial_position")
        self._info = DeviceInfo(
            name=name,
            max_force=max_force,
            workspace=workspace,
            max_stiffness=4.0 * self.mass / dt**2,
            max_damping=np.maximum(2.0 * self.mass / dt - self.damping, 0.0),
            damping=self.damping,
        )
        self.phi = np.empty((3, 4, 4))
        self.gamma = np.empty((3, 4, 2))
        kh = self.hand.stiffness if self.hand is not None else np.zeros(3)
        bh = self.hand.damping if self.hand is not None else np.zeros(3)
        wh = 2.0 * math.pi * (self.hand.bandwidth if self.hand is not None else HAND_BANDWIDTH)
        for a in range(3):
            m, b = self.mass[a], self.damping[a]
            A = np.array([
                [0.0, 1.0, 0.0, 0.0],
                [-wh * wh, -2.0 * wh, 0.0, 0.0],
                [0.0, 0.0, 0.0, 1.0],
                [kh[a] / m, bh[a] / m, -kh[a] / m, -(b + bh[a]) / m],
            ])
            B = np.array([[0.0, 0.0], [wh * wh, 0.0], [0.0, 0.0], [0.0, 1.0 / m]])
            self.phi[a], self.gamma[a] = discretize_zoh(A, B, dt)
        self.z = np.zeros((3, 4))
        self._r = np.empty(3)
        self._f = np.zeros(3)
        self.ticks = 0
        self.reset()

    @property
    def info(self) -> DeviceInfo:
        return self._info

    def now(self) -> float:
        """Simulated time, s (ticks x dt)."""
        return self.ticks * self.dt

    def reset(self, position=None) -> None:
        """Back to rest at ``position`` (default: the initial position), time 0."""
        p = self.initial_position if position is None else _vec3(position, "position")
        self.z[:, 0] = p
        self.z[:, 1] = 0.0
        self.z[:, 2] = p
        self.z[:, 3] = 0.0
        self._r[:] = p  # the hand set point when no trajectory is given
        self.ticks = 0

    def _open(self) -> None:
        pass

    def _close(self) -> None:
        pass

    def _read(self, out: DeviceState) -> None:
        _read_kernel(self.z, out.position, out.velocity)
        t = self.ticks * self.dt
        b = self.buttons
        out.buttons = int(b(t)) if callable(b) else b
        out.timestamp = t

    def _apply_force(self, force: np.ndarray) -> None:
        t = self.ticks * self.dt
        r = self._r
        hand = self.hand
        if hand is not None and hand._fill is not None:
            hand._fill(t, r)  # otherwise r holds the initial position (set by reset)
        if self.external_force is not None:
            f = self._f
            f[:] = force
            f += np.asarray(self.external_force(t), dtype=np.float64)
        else:
            f = force
        virtual_device_advance(self.phi, self.gamma, self.z, r, f)
        self.ticks += 1
