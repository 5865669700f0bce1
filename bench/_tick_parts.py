"""Where a haptic tick's time goes: the parts of the model tick replayed in compiled loops.

For ``bench/feel.py --vtk-only --parts``: the slide of :func:`feel.vtk_ratio` (100 nm/s, blended
source) is run once through the loop (``HapticLoop.step`` from Python, as the bench times it);
its probe positions are then replayed on a fresh model of the same settings in compiled loops,
each call timed with the CPU's cycle counter (:func:`collision._cycles`): the whole model tick
(:func:`arsurf.model.model_tick_kernel`), the collision alone
(:func:`arsurf.contact.closest_point.collide_any`, warm-started from the previous answer), and
the contact behind the virtual coupling alone (:func:`arsurf.contact.proxy.coupled_depth_kernel`
on the inputs the model tick gave it, its memo kept from tick to tick as the model keeps it),
with one bare Maugis-Dugdale solve at the target depth for scale. Medians in us.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from collision import _cycles, _cycles_per_second

from arsurf.assembly import PRESETS, build_loop, make_model
from arsurf.contact import projection as pj
from arsurf.contact.maugis_dugdale import md_contact_hysteresis_kernel
from arsurf.contact.proxy import MD_MEMO, coupled_depth_kernel
from arsurf.feel_scenarios import clearance_height, run_scenario
from arsurf.haptics.virtual_device import VirtualDevice
from arsurf.model import (F_COUPLING, F_JUMP_OUT, F_ZERO_LOAD, MODEL_ARGS, S_INTERACTING, S_TIP_DEPTH,
                          SIGNALS_SYNTHESISED, model_tick_kernel)


@njit
def _model_loop(a, probes, inputs, cycles):
    """The model tick at each probe (cycles per call); ``inputs`` rows get what the coupling
    solve was given: the target depth, the previous tip depth, interacting (1/0), and the
    collision status."""
    state, coll = a[12], a[13]
    for k in range(probes.shape[0]):
        inputs[k, 1] = state[S_TIP_DEPTH]
        inputs[k, 2] = state[S_INTERACTING]
        t0 = _cycles()
        st = model_tick_kernel(a[0], a[1], a[2], a[3], a[4], a[5], a[6], a[7], a[8], a[9], a[10], a[11],
                               probes[k, 0], probes[k, 1], probes[k, 2], 0.0, 0.0, SIGNALS_SYNTHESISED,
                               a[12], a[13], a[14], a[15], a[16])
        cycles[k] = _cycles() - t0
        inputs[k, 0] = coll[pj.OUT_DEPTH]
        inputs[k, 3] = st


@njit
def _collision_loop(proj, probes, radius, coll, cycles):
    """The collision alone at each probe, warm-started from the previous answer."""
    hu = hv = math.nan
    for k in range(probes.shape[0]):
        t0 = _cycles()
        st = pj.collide_any(proj, probes[k, 0], probes[k, 1], probes[k, 2], radius, hu, hv, coll)
        cycles[k] = _cycles() - t0
        if st >= 0:
            hu = coll[pj.OUT_U]
            hv = coll[pj.OUT_V]


@njit
def _coupling_loop(inputs, k_c, jump_out, zero_load, law, memo, cycles, solve_cycles):
    """The contact behind the coupling on the recorded inputs (ticks with a collision answer),
    and one bare Maugis-Dugdale solve at each target depth."""
    for k in range(inputs.shape[0]):
        if inputs[k, 3] < 0:
            cycles[k] = -1
            solve_cycles[k] = -1
            continue
        start = inputs[k, 1] if inputs[k, 2] > 0.5 else math.nan
        t0 = _cycles()
        coupled_depth_kernel(inputs[k, 0], start, inputs[k, 2] > 0.5, k_c, jump_out, zero_load,
                             law[0], law[1], law[2], law[3], law[4], law[5], memo)
        cycles[k] = _cycles() - t0
        t0 = _cycles()
        md_contact_hysteresis_kernel(inputs[k, 0], True, law[0], law[1], law[2], law[3], law[4], law[5])
        solve_cycles[k] = _cycles() - t0


_HZ = []


def tick_parts(surface, seconds: float = 2.0) -> dict:
    """Median us per call of the loop's tick (from Python), the model tick, the collision and the
    contact behind the coupling (compiled loops), one Maugis-Dugdale solve; the share of ticks in
    contact."""
    if not _HZ:
        _HZ.append(_cycles_per_second())
    us = 1e6 / _HZ[0]
    run = run_scenario(surface, motion="slide-100", source="blended", seconds=seconds)
    probes = np.ascontiguousarray(run.probe)
    p = PRESETS["demo"]
    model = make_model(surface, tip_radius=p.tip_radius, effective_modulus=p.effective_modulus,
                       work_of_adhesion=p.work_of_adhesion, cantilever=p.cantilever, friction=p.friction)
    (u0, u1), (v0, v1) = surface.domain
    x, y = 0.5 * (u0 + u1), 0.5 * (v0 + v1)
    build_loop(model, {**p.haptics, "source": "blended", "rate": 1000.0}, VirtualDevice(dt=1e-3).info,
               (x, y, clearance_height(surface, x, y, p.tip_radius) + 2e-9))  # gives the model its coupling
    n = probes.shape[0]
    inputs, cyc = np.empty((n, 4)), np.empty(n, np.int64)
    try:
        args = model.kernel_args()
        _model_loop(args, probes, inputs, cyc)
        model_us = cyc * us
        model.reset()
        coll_cyc = np.empty(n, np.int64)
        coll = args[MODEL_ARGS.index("coll")]
        _collision_loop(args[0], probes, model.tip_radius, np.empty_like(coll), coll_cyc)
    finally:
        model.reset()
    f = model.kernel_args()[MODEL_ARGS.index("friction")]
    law = np.asarray(model.contact.kernel_args, float)
    md_cyc, solve_cyc = np.empty(n, np.int64), np.empty(n, np.int64)
    _coupling_loop(inputs, f[F_COUPLING], f[F_JUMP_OUT], f[F_ZERO_LOAD], law, MD_MEMO.full(np.nan), md_cyc, solve_cyc)
    ok = md_cyc >= 0
    return {"loop_tick_us": float(np.median(run.tick_ns)) * 1e-3,
            "model_tick_us": float(np.median(model_us)),
            "collision_us": float(np.median(coll_cyc * us)),
            "contact_behind_coupling_us": float(np.median(md_cyc[ok] * us)),
            "one_md_solve_us": float(np.median(solve_cyc[ok] * us)),
            "in_contact_share": float(np.mean(run.contact))}
