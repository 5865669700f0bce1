r"""A jump of the tip behind the coupling, rendered over the blend time instead of in one tick.

The tip behind the virtual coupling (:mod:`arsurf.contact.proxy`, :mod:`arsurf.contact.multi_contact`)
is where the contact balances the coupling at the hand's target: a function of the target, with no
time in it. Where the hand drives the target into a thin asperity, the balance on the face the tip
rests on ends at the asperity's top and the tip lands on the far face in one tick. A real tip on a
soft lever snaps the same way (Prandtl 1928; Tomlinson 1929: the stick-slip of friction force
microscopy), but a real tip has mass and damping, and its snap takes time. Rendered in one tick, the
jump is a step of the force at the hand: on the feel table's rough surfaces (``bench/feel.py``),
slides of 10 nm/s under 2-7 nm tips jumped 0.26-3.2 nm in one tick, steps of 11-40 mN at the hand,
with 1-27 reversals and up to 6 % of the force above 100 Hz.

The rendered tip is :math:`T = T^* + e`, :math:`T^*` the balance and e an *excess* that takes up
the part of the balance's move faster than the hand's and then decays with the blend time
:math:`\tau`. In a tick of length :math:`\Delta t` where the balance moves by :math:`\Delta T^*` and
the target by :math:`\Delta C`,

.. math:: e_k = e_{k-1}\, e^{-\Delta t/\tau} - \varphi\, j_k, \qquad
          j_k = \Delta T^*\left(1 - \frac{r\,|\Delta C|}{|\Delta T^*|}\right)
          \text{ where } |\Delta T^*| > r\,|\Delta C|, \text{ else } 0,

with :math:`r` = :data:`JUMP_SPEED_RATIO`: a balance that follows the hand (a tip riding over the
surface moves at most :math:`\sqrt{1+s^2}` times the hand on a slope s, within twice it up to
60 degrees) is rendered as it is, and a jump (the hand moves pm, the balance nm) is spread over
:math:`\tau`. Every force the tip carries (the contacts' loads, the friction) moves with it: the
hand gets :math:`F = F^* + E`, the force's excess E taking up the same share :math:`\varphi\,(1 -
r|\Delta C|/|\Delta T^*|)` of the force's change in that tick and decaying alike (behind the
coupling alone, :math:`E = k_c e`). The force goes from the old balance's to the new one's as
:math:`1 - e^{-t/\tau}` from the tick of the jump, with no step and no reversal, the same function
of time at any loop rate (the decay is exact in :math:`\Delta t`). The excess is the coupling
still pulling the tip back where it was, the way a damped tip's does during its snap; the energy
the observer measures (:mod:`arsurf.haptics.passivity`) on the feel table is in docs/feel-log.rst.

Only a slow hand's jumps are blended: :math:`\varphi = 1/(1 + (|\bar v|/v_b)^4)`, :math:`\bar v`
the hand's velocity averaged over :math:`\tau` (exact first-order average: noise of the target
averages out, and at any rate the same) and :math:`v_b` = :data:`BLEND_SPEED`. A jump can be told
from the hand's motion only while the hand moves less than the jump in a tick: at 1000 nm/s a
1 kHz tick is 1 nm, as large as the jumps, and a blend would then take a share of them that
depends on the loop rate (on the feel table, 1 and 10 kHz runs of 100-1000 nm/s slides grew
5-34 % apart; their force is texture, judged by rate convergence, not by its smoothness).

A hop while the last ones are still being blended is blended less: its share is multiplied by
:math:`\max(1 - |e|/(h\,|\Delta T^*|), 0)`, e the excess left and h = :data:`HOP_EXCESS`, so the
excess never piles up beyond h times the largest jump. Without it, a press on a contact set that
keeps hopping (a minimum lost at a fold and reborn between two scans) never settled: each hop's
force came 15 ms late, the hand's answer made the next hop, and the cycle gave the hand energy
(the feel table's seed 1: a still press at -5.28 E0, excess on 2 067 of 3 000 ticks; -0.54 E0 and
at rest after 1.5 s without the blend). With it that press is at rest after 1 s, no reversal (28
without the blend).

**A jump tick run again.** The share :math:`1 - r|\Delta C|/|\Delta T^*|` and the hand's
velocity are measured over the tick, so a jump taken in one 1 ms tick is blended differently from
the same jump met in ten 0.1 ms ticks: where the hand's answer to the force feeds back into the
target, the 1 and 10 kHz paths part (on the feel table's seed 1, a 1000 nm/s circle caught in a pit
gave a 1 kHz force 109 % away from the 10 kHz one, and the hand -12.9 E0). The model therefore runs
a tick in which the balance jumps (:func:`jumped_kernel`) again from its state before the tick, in
:func:`redo_steps` steps of at most :data:`REDO_STEP` (a 10 kHz tick) along the target's straight
path from the last tick's target (:func:`arsurf.model.model_tick_kernel`): a 1 kHz loop then meets
each jump as a 10 kHz loop does, to the last bit when the two start from the same state. A tick in
which a contact is found or lost (the contact table's count changes,
:mod:`arsurf.contact.multi_contact`) is an event of the same kind, met in one 1 ms step, and is run
again alike. Only those ticks are run again (a few in a thousand on the feel table), so the median
tick cost is unchanged.

Off (the tip is the balance) without a coupling, with :math:`\tau = 0`, or without the loop's
tick period (a model ticked outside a haptic loop:
:meth:`~arsurf.model.ARModel.set_jump_blend`).
"""
from __future__ import annotations

import math

from numba import njit

from arsurf._layout import Layout

__all__ = ["BLEND_SPEED", "BLEND_TIME", "HOP_EXCESS", "JUMP_SPEED_RATIO", "JUMP_STATE", "REDO_STEP", "blend_jumps_kernel",
           "forget", "jumped_kernel", "last_target", "redo_steps"]

#: the blend time tau (s) a haptic loop gives its model (``haptics.jump_blend``): 15 ms puts the
#: corner of the exponential at 1/(2 pi tau) = 11 Hz, a step's content above 100 Hz down ~10x
BLEND_TIME = 0.015
#: the hand speed v_b (m/s, at the probe) at which half a jump is blended (module docstring):
#: above the feel table's slow slides (<= 10 nm/s, whose target moves up to 60 nm/s as the hand
#: reacts to the force) and below its fast ones (>= 100 nm/s: a tenth of a nm per 1 kHz tick)
BLEND_SPEED = 100e-9
#: the balance moving more than this many times the target in a tick is a jump (module docstring)
JUMP_SPEED_RATIO = 2.0
#: the longest step (s) in which a jump tick is run again (module docstring): a 10 kHz loop's tick
REDO_STEP = 1e-4
#: at most this many steps in one tick (a 312 Hz loop's tick at :data:`REDO_STEP`)
REDO_MAX_STEPS = 32
#: a hop while the excess of the last ones is still this many times the hop is rendered as it is
#: (module docstring): the excess never exceeds it times the largest jump
HOP_EXCESS = 1.5
#: the blend's state (in the model state): the excesses of the tip e (m) and of the force E (N), the
#: last balance T* (m), target C (m) and force F* (N) (NaN: none) and the hand's velocity averaged
#: over the blend time (m/s)
JUMP_STATE = Layout("jump blend state", [("excess", 3), ("force_excess", 3), ("last_tip", 3), ("last_target", 3),
                                         ("last_force", 3), ("hand_velocity", 3)])
_E, _G, _T, _C, _F, _V = (JUMP_STATE.offset("excess"), JUMP_STATE.offset("force_excess"),
                          JUMP_STATE.offset("last_tip"), JUMP_STATE.offset("last_target"),
                          JUMP_STATE.offset("last_force"), JUMP_STATE.offset("hand_velocity"))
STATE_SIZE = JUMP_STATE.size


@njit(cache=True)
def forget(state, at) -> None:
    """No excess, no last balance: the next tick renders its balance as it is."""
    for j in range(STATE_SIZE):
        state[at + j] = math.nan


@njit(cache=True)
def redo_steps(blend_time, period) -> int:
    """The steps a jump tick of ``period`` s is run again in (module docstring): ceil(period /
    :data:`REDO_STEP`), at most :data:`REDO_MAX_STEPS`; 1 (no redo) with the blend off."""
    if not (blend_time > 0.0 and period > REDO_STEP):
        return 1
    return min(int(math.ceil(period / REDO_STEP - 1e-9)), REDO_MAX_STEPS)  # a rounding above an integer


@njit(cache=True, inline="always")
def _is_jump(moved, target_moved) -> bool:
    """The balance moved by ``moved`` while the target moved ``target_moved`` (m): a jump."""
    return moved > JUMP_SPEED_RATIO * target_moved


@njit(cache=True)
def last_target(state, at):
    """The last tick's target ``(x, y, z)`` (m; NaN: none) in the blend state ``state[at:]``."""
    return state[at + _C], state[at + _C + 1], state[at + _C + 2]


@njit(cache=True)
def jumped_kernel(before, at_before, state, at) -> bool:
    """Whether the tick that took the blend state from ``before[at_before:]`` to ``state[at:]``
    (:data:`JUMP_STATE`) saw a jump: its balance moved more than :data:`JUMP_SPEED_RATIO` times
    its target. False when either tick had no balance."""
    moved = target_moved = 0.0
    for j in range(3):
        moved += (state[at + _T + j] - before[at_before + _T + j]) ** 2
        target_moved += (state[at + _C + j] - before[at_before + _C + j]) ** 2
    return math.isfinite(moved) and math.isfinite(target_moved) and _is_jump(math.sqrt(moved), math.sqrt(target_moved))


@njit(cache=True)
def blend_jumps_kernel(blend_time, blend_speed, period, tx, ty, tz, cx, cy, cz, fx, fy, fz, state, at):
    r"""The excesses to add to the balance (``tx, ty, tz``, m) of the target (``cx, cy, cz``, m)
    and to its force (``fx, fy, fz``, N) this tick (module docstring): ``blend_time`` :math:`\tau`
    (s; 0: off), ``blend_speed`` :math:`v_b` (m/s), ``period`` the tick's :math:`\Delta t` (s; NaN:
    off). Updates ``state[at:at + STATE_SIZE]`` (:data:`JUMP_STATE`). Returns ``(ex, ey, ez, gx, gy,
    gz)``, the tip's e (m) and the force's E (N); zeros when off, on the first tick and once the
    excesses have decayed."""
    if not (blend_time > 0.0 and period > 0.0):
        if math.isfinite(state[at + _T]):  # clear once, not on each tick of a model outside a loop
            forget(state, at)
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    decay = math.exp(-period / blend_time)
    ex, ey, ez = state[at + _E], state[at + _E + 1], state[at + _E + 2]
    gx, gy, gz = state[at + _G], state[at + _G + 1], state[at + _G + 2]
    if not (math.isfinite(ex) and math.isfinite(gx)):
        ex = ey = ez = gx = gy = gz = 0.0
    ex, ey, ez, gx, gy, gz = ex * decay, ey * decay, ez * decay, gx * decay, gy * decay, gz * decay
    if math.isfinite(state[at + _T]):
        jx, jy, jz = tx - state[at + _T], ty - state[at + _T + 1], tz - state[at + _T + 2]
        hx, hy, hz = cx - state[at + _C], cy - state[at + _C + 1], cz - state[at + _C + 2]
        vx, vy, vz = state[at + _V], state[at + _V + 1], state[at + _V + 2]
        if not math.isfinite(vx):
            vx, vy, vz = hx / period, hy / period, hz / period
        vx += (1.0 - decay) * (hx / period - vx)
        vy += (1.0 - decay) * (hy / period - vy)
        vz += (1.0 - decay) * (hz / period - vz)
        state[at + _V], state[at + _V + 1], state[at + _V + 2] = vx, vy, vz
        moved = math.sqrt(jx * jx + jy * jy + jz * jz)
        target_moved = math.sqrt(hx * hx + hy * hy + hz * hz)
        if _is_jump(moved, target_moved):
            allowed = JUMP_SPEED_RATIO * target_moved
            q = (vx * vx + vy * vy + vz * vz) / (blend_speed * blend_speed)
            share = (1.0 - allowed / moved) / (1.0 + q * q)
            left = math.sqrt(ex * ex + ey * ey + ez * ez) / moved  # a hop while the last one is still blended
            share *= max(1.0 - left / HOP_EXCESS, 0.0)
            ex -= share * jx
            ey -= share * jy
            ez -= share * jz
            gx -= share * (fx - state[at + _F])  # every force the tip carries moves with it
            gy -= share * (fy - state[at + _F + 1])
            gz -= share * (fz - state[at + _F + 2])
    state[at + _E], state[at + _E + 1], state[at + _E + 2] = ex, ey, ez
    state[at + _G], state[at + _G + 1], state[at + _G + 2] = gx, gy, gz
    state[at + _T], state[at + _T + 1], state[at + _T + 2] = tx, ty, tz
    state[at + _C], state[at + _C + 1], state[at + _C + 2] = cx, cy, cz
    state[at + _F], state[at + _F + 1], state[at + _F + 2] = fx, fy, fz
    return ex, ey, ez, gx, gy, gz
