r"""The augmented-reality surface model: one tick of tip -> contact -> dent -> 3D force.

This is the part of the pipeline shared by the live haptic loop and offline replay
(docs/design.rst, "The pipeline"): given the target tip centre C (and, when an AFM is
attached or a session is replayed, the measured bending and torsion angles),

1. **collide** C (radius R) with the *rest* surface (Newton projection, :mod:`arsurf.contact.projection`):
   closest point, normal n, indentation depth δ = R − d. The rest surface is used because the
   dent is the model's own answer to δ: measuring δ on the dented net would feed the dent back
   into itself. A target pressed behind a thin wall's face keeps that face (:mod:`arsurf.contact.side`:
   no pop-through to the other face). The contact pushes along the resultant over its zone
   (:mod:`arsurf.contact.zone_normal`), the normal n from here on; several contacts in reach are
   each found and weighed (:mod:`arsurf.contact.multi_contact`);
2. **contact mechanics**: Maugis-Dugdale with approach/retract hysteresis under displacement
   control (:func:`arsurf.contact.maugis_dugdale.md_contact_hysteresis_kernel`): contact radius a
   and load P (> 0 compressive); with a material map (:mod:`arsurf.contact.material_map`) the law
   has the E* and w of the contact point;
3. **deform** the live surface's control net (:mod:`arsurf.contact.deformation`): the contact
   zone onto the tip, the elastic surface of the same (local) law around it. The tick records
   the dent (O(1), whatever the pitch); the net is moved to it when it is read
   (:meth:`~arsurf.spline.surface.BSplineSurface.sync`);
4. **force on the tip**: *simulated* F = P n + F_t, F_t the stick-slip friction of a proxy
   anchored where the tip stuck (:mod:`arsurf.contact.friction`: the tip's own tangential
   displacement, not the closest point's; stuck inside the static cone
   :math:`\mu_s N`, slipping to the kinetic cone :math:`\mu_k N` and sticking there again, with
   :math:`N = P + |P_c|` by default; no velocity in the law);
   *measured* F from the two angles by the contact-normal decoupling ([SplineAR];
   docs/design.rst, "Force from the two angles",
   :mod:`arsurf.force.decoupling`) with the proxy's slip direction as the friction direction; a
   stuck tip has none, and the decoupling takes its ``NO_MOTION`` fallback (force along n plus
   the torsion) steadily, tick after tick. The model reports both forces.

With a virtual coupling (``coupling_stiffness`` finite, :mod:`arsurf.contact.proxy`) the tip
centre is not the target C itself but the point on C's normal line where the contact load
balances the coupling spring; steps 2-4 use that tip, which the model reports (``tip``). Where
that balance jumps while the hand moves slowly (a snap over an asperity), the reported tip and
the simulated force follow the jump over the loop's blend time (:mod:`arsurf.contact.jump_blend`;
only once a loop has given the model its tick, :meth:`ARModel.set_jump_blend`), and the tick in which
it jumps, or a contact is found or lost, is run again in steps of a 10 kHz tick, so that a slower
loop meets the event as a 10 kHz loop does.

All of steps 1-4 run in one compiled call (:func:`model_tick_kernel`); :class:`ARModel` owns the
arrays, validates once, and turns the output vector into a :class:`ModelTick` record.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from arsurf import _validation
from arsurf._layout import Layout
from arsurf.contact import friction as fr
from arsurf.contact import jump_blend as jb
from arsurf.contact import projection as pj
from arsurf.contact.deformation import DENT_SIZE, record_dent_kernel
from arsurf.contact.material_map import (C_REF, H_DENT, H_FRICTION, H_HI_W, H_LO_E, H_OFF_E, H_OFF_W, contact_vector,
                                         deepest_well_kernel, local_law_kernel, local_pull_off_kernel)
from arsurf.contact import multi_contact as mc
from arsurf.contact import zone_energy as ze
from arsurf.contact.side import keep_side_kernel
from arsurf.contact.zone_normal import zone_normal_kernel
from arsurf.contact.maugis_dugdale import (MD_ARGS, A_DELTA_FOLD, A_DEPTH_SCALE, A_LAMBDA, A_LOAD_SCALE, A_RADIUS_SCALE,
                                           A_T_FOLD, MaugisDugdale, md_zone_from_depth_kernel, md_zone_radius)
from arsurf.contact.newton import EVALUATION_ROWS
from arsurf.contact.proxy import MD_MEMO, MEMO_SIZE, coupled_depth_kernel
from arsurf.errors import ContactError, PositionError
from arsurf.force import decoupling as dc
from arsurf.force.cantilever import Cantilever
from arsurf.force.decoupling import (MEASURED_SCRATCH, P_BENDING_COMPLIANCE, P_COUPLING,  # noqa: F401 (P_SIGNAL_NOISE:
                                     P_SIGNAL_NOISE, P_TORSION_COMPLIANCE, bending_only_kernel,  # the model's
                                     blended_decouple_kernel, decoupling_parameters)  # decoupling vector)
from arsurf.spline.surface import BSplineSurface
from arsurf.contact.mechanics import SMALL_CONTACT_LIMIT
from arsurf.status import BEYOND_MODEL, COHESIVE, CONTACT, SEPARATED, TEXT

#: the model output vector (``ARModel.out``): m, N, rad; statuses and counts as floats
MODEL_OUT = Layout("model output", [
    ("point", 3), ("normal", 3), ("uv", 2), ("distance", 1), ("depth", 1), ("contact_radius", 1), ("load", 1),
    ("simulated_force", 3), ("measured_force", 3), ("condition", 1), ("collide_status", 1), ("md_status", 1),
    ("decoupling_flags", 1), ("moved", 1), ("in_contact", 1), ("bending", 1), ("torsion", 1), ("tip", 3),
    ("slipping", 1), ("coupled", 1), ("model_flags", 1)])
# the offsets as the kernels use them
M_PX, M_NX, M_U = MODEL_OUT.offset("point"), MODEL_OUT.offset("normal"), MODEL_OUT.offset("uv")
M_PY, M_PZ, M_NY, M_NZ, M_V = M_PX + 1, M_PX + 2, M_NX + 1, M_NX + 2, M_U + 1
M_DISTANCE, M_DEPTH = MODEL_OUT.offset("distance"), MODEL_OUT.offset("depth")
M_RADIUS, M_LOAD = MODEL_OUT.offset("contact_radius"), MODEL_OUT.offset("load")
M_SIM_FX, M_MEAS_FX = MODEL_OUT.offset("simulated_force"), MODEL_OUT.offset("measured_force")
M_SIM_FY, M_SIM_FZ, M_MEAS_FY, M_MEAS_FZ = M_SIM_FX + 1, M_SIM_FX + 2, M_MEAS_FX + 1, M_MEAS_FX + 2
M_CONDITION, M_COLLIDE_STATUS = MODEL_OUT.offset("condition"), MODEL_OUT.offset("collide_status")
M_MD_STATUS, M_DECOUPLE_STATUS = MODEL_OUT.offset("md_status"), MODEL_OUT.offset("decoupling_flags")
M_MOVED, M_IN_CONTACT = MODEL_OUT.offset("moved"), MODEL_OUT.offset("in_contact")
M_BENDING, M_TORSION = MODEL_OUT.offset("bending"), MODEL_OUT.offset("torsion")
M_TIP, M_SLIPPING, M_COUPLED = MODEL_OUT.offset("tip"), MODEL_OUT.offset("slipping"), MODEL_OUT.offset("coupled")
M_MODEL_FLAGS = MODEL_OUT.offset("model_flags")
M_SIZE = MODEL_OUT.size
#: the model's arrays and settings in the order of :func:`model_tick_kernel`'s arguments (less the
#: per-tick target and signals): what :meth:`ARModel.kernel_args` returns, in the loop's struct by
#: these names (:data:`arsurf.haptics.loop.LOOP_FIELDS`)
MODEL_ARGS = ("proj", "zone_energy", "live_ctrl", "live_rest", "ku", "kv", "patch", "md_args", "dec_params",
              "tip_radius", "friction", "deform", "model_state", "coll", "dec", "ev", "mout")
# how the measured angles reach the model tick
SIGNALS_NONE, SIGNALS_GIVEN, SIGNALS_SYNTHESISED = 0, 1, 2
#: the model state vector (``ARModel.state``): the collision's warm-start hint (u, v), the
#: hysteresis memory (1: interacting), the tip's depth (m; NaN: none), the normal of the face the
#: target centre is behind (NaN: none; :mod:`arsurf.contact.side`), the contact table
#: (:data:`arsurf.contact.multi_contact.CONTACT_TABLE`), the friction anchor (:data:`arsurf.contact.friction.FRICTION_STATE`),
#: the coupling solve's memo (:data:`arsurf.contact.proxy.MD_MEMO`), the jump blend's
#: (:data:`arsurf.contact.jump_blend.JUMP_STATE`), the zone energy's tip (m; NaN: none)
MODEL_STATE = Layout("model state", [("hint_uv", 2), ("interacting", 1), ("tip_depth", 1), ("side", 3),
                                     ("contacts", mc.CONTACT_TABLE.size), ("friction", fr.STATE_SIZE),
                                     ("coupling_memo", MD_MEMO.size), ("jumps", jb.STATE_SIZE), ("zone_tip", 3)])
S_HINT_U, S_INTERACTING = MODEL_STATE.offset("hint_uv"), MODEL_STATE.offset("interacting")
S_HINT_V = S_HINT_U + 1
S_TIP_DEPTH, S_CONTACTS = MODEL_STATE.offset("tip_depth"), MODEL_STATE.offset("contacts")
S_FRICTION = MODEL_STATE.offset("friction")
S_SIDE = MODEL_STATE.offset("side")
S_MEMO = MODEL_STATE.offset("coupling_memo")
S_JUMPS = MODEL_STATE.offset("jumps")
S_ZONE_TIP = MODEL_STATE.offset("zone_tip")
S_SIZE = MODEL_STATE.size
#: the proxy parameter vector: mu_s, mu_k, tangential stiffness per contact radius (N/m per m,
#: Mindlin: ratio * 2 E*), coupling stiffness (N/m; inf: none), the contact law's jump-out and
#: zero-load depths (m), the friction law (a code of :data:`arsurf.contact.friction.LAW_NAMES`),
#: the law's pull-off force magnitude ``|P_c|`` (N), the interfacial shear strength (Pa, area law), and
#: the jump blend's time (s; 0: off) and hand speed (m/s) with the loop's tick (s; NaN: none,
#: :mod:`arsurf.contact.jump_blend`)
PROXY_PARAMS = Layout("proxy parameters", [
    ("static_friction", 1), ("kinetic_friction", 1), ("stiffness_per_radius", 1), ("coupling_stiffness", 1),
    ("jump_out_depth", 1), ("zero_load_depth", 1), ("friction_law", 1), ("pull_off_force", 1),
    ("shear_strength", 1), ("blend_time", 1), ("blend_speed", 1), ("tick_period", 1)])
F_MU_S, F_MU_K = PROXY_PARAMS.offset("static_friction"), PROXY_PARAMS.offset("kinetic_friction")
F_KT_PER_A, F_COUPLING = PROXY_PARAMS.offset("stiffness_per_radius"), PROXY_PARAMS.offset("coupling_stiffness")
F_JUMP_OUT, F_ZERO_LOAD = PROXY_PARAMS.offset("jump_out_depth"), PROXY_PARAMS.offset("zero_load_depth")
F_LAW, F_PULL_OFF = PROXY_PARAMS.offset("friction_law"), PROXY_PARAMS.offset("pull_off_force")
F_SHEAR = PROXY_PARAMS.offset("shear_strength")
F_BLEND_TIME, F_BLEND_SPEED = PROXY_PARAMS.offset("blend_time"), PROXY_PARAMS.offset("blend_speed")
F_PERIOD = PROXY_PARAMS.offset("tick_period")
#: the tick's scratch vector: the friction proxy's output (:data:`arsurf.contact.friction.FRICTION_OUT`),
#: then the measured force's (:data:`arsurf.force.decoupling.MEASURED_SCRATCH`, whose first field is
#: the blend, a decoupling output), in one place; the model state and the dent record from before
#: the tick, which a jump tick is run again from (:mod:`arsurf.contact.jump_blend`); the zone energy's
#: output (:data:`arsurf.contact.zone_energy.ZONE_OUT`) and the contacts' discovery's work
TICK_SCRATCH = Layout("tick scratch", [("outputs", max(fr.FRICTION_OUT.size, MEASURED_SCRATCH.size)),
                                       ("saved_state", MODEL_STATE.size), ("saved_dent", DENT_SIZE),
                                       ("zone", ze.Z_SIZE), ("discovery", mc.DISCOVERY_WORK)])
SCRATCH_SIZE = TICK_SCRATCH.size
_MEASURED = TICK_SCRATCH.offset("outputs") + MEASURED_SCRATCH.offset("blend")
_SAVED_STATE, _SAVED_DENT = TICK_SCRATCH.offset("saved_state"), TICK_SCRATCH.offset("saved_dent")
_ZONE, _DISCOVERY = TICK_SCRATCH.offset("zone"), TICK_SCRATCH.offset("discovery")
#: the margin m of the contacts' weights, in Maugis-Dugdale depth scales: a contact counts fully once the
#: pass between it and the closest point is m higher than it (:mod:`arsurf.contact.multi_contact`); contacts
#: are followed down to m below the jump-out depth
CONTACT_MARGIN = 0.5
#: the slip direction is a unit vector: its horizontal part must be at least this long to give the
#: decoupling a friction direction (a slip straight down a wall gives none)
MIN_SLIP_HORIZONTAL = 1e-3
#: Rms noise (rad) assumed on given signals of unknown noise (the measured force's ``signal_noise``,
#: :data:`arsurf.force.decoupling.FADE_CONDITION`): 1e-7 rad is ~30 pm of tip deflection on the
#: demo's 450 um lever (z = 2 l theta / 3), a typical optical-lever detection floor at a kHz
#: bandwidth; an over-estimate only moves the force towards the fallback, which reproduces the
#: angles as well. The loop's configured photodiode noise replaces it when the loop synthesises the
#: signals (metadata ``haptics.signal_noise``; 0 declares noise-free signals).
DEFAULT_SIGNAL_NOISE = 1e-7
#: the Maugis-Dugdale kernel arguments' length (a law in the contact vector)
_MD_SIZE = MD_ARGS.size


@njit(cache=True, inline="always")
def model_tick_kernel(proj,                                              # Projector.kernel_args() of the rest surface
                      zone_energy,                                       # the zone energy's (lattice, law), or None
                      live_ctrl, live_rest, ku, kv, patch,               # deformation of the live surface
                      md_args, dec_params, tip_radius, friction, deform,
                      cx, cy, cz, bending, torsion, signal_mode,
                      state, coll, scratch, ev, out):
    """One model tick for the target tip centre ``(cx, cy, cz)``: :func:`_one_tick_kernel` (its
    arguments and return), except that a tick in which the tip's balance behind the coupling jumps
    or a contact is found or lost (:func:`_to_run_again`) is run again from the state before it, in
    :func:`~arsurf.contact.jump_blend.redo_steps` steps of the target's straight path from the last
    tick's target, the signals given to the last step only: a slower loop meets the event as a
    10 kHz loop does (:mod:`arsurf.contact.jump_blend`, "A jump tick run again")."""
    period = friction[F_PERIOD]
    steps = jb.redo_steps(friction[F_BLEND_TIME], period) if friction[F_COUPLING] < math.inf else 1
    d0 = int(md_args[H_DENT])
    if steps > 1:  # the state before the tick, which a jump tick is run again from
        _keep_state(state, 0, scratch, _SAVED_STATE)
        _copy(md_args, d0, scratch, _SAVED_DENT, DENT_SIZE)
    st = _one_tick_kernel(proj, zone_energy, live_ctrl, live_rest, ku, kv, patch, md_args, dec_params, tip_radius,
                          friction, deform, cx, cy, cz, bending, torsion, signal_mode, state, coll, scratch, ev, out)
    if steps > 1 and _to_run_again(scratch, state):
        _keep_state(scratch, _SAVED_STATE, state, 0)  # run again from the state before the tick
        _copy(scratch, _SAVED_DENT, md_args, d0, DENT_SIZE)
        st = _run_again(proj, zone_energy, live_ctrl, live_rest, ku, kv, patch, md_args, dec_params, tip_radius,
                        friction, deform, cx, cy, cz, bending, torsion, signal_mode, state, coll, scratch, ev, out,
                        steps)
    return st


@njit(cache=True, inline="always")
def _to_run_again(scratch, state) -> bool:
    """Whether the tick that took the state kept in ``scratch`` to ``state`` is run again: the tip's
    balance jumped (:func:`~arsurf.contact.jump_blend.jumped_kernel`), or a contact was found or lost
    (the contact table's count changed) in a tick that has a last target to start from."""
    before = _SAVED_STATE + S_CONTACTS + mc.T_COUNT
    return jb.jumped_kernel(scratch, _SAVED_STATE + S_JUMPS, state, S_JUMPS) or (
        scratch[before] >= 1.0 and scratch[before] != state[S_CONTACTS + mc.T_COUNT]
        and math.isfinite(jb.last_target(scratch, _SAVED_STATE + S_JUMPS)[0]))


@njit(cache=True, _nrt=False)
def _run_again(proj, zone_energy, live_ctrl, live_rest, ku, kv, patch, md_args, dec_params, tip_radius, friction,
               deform, cx, cy, cz, bending, torsion, signal_mode, state, coll, scratch, ev, out, steps):
    """The tick to ``(cx, cy, cz)`` in ``steps`` ticks of the target's straight path from the last
    tick's target (in ``state``), each ``steps`` times shorter, the signals given to the last one."""
    period = friction[F_PERIOD]
    px, py, pz = jb.last_target(state, S_JUMPS)
    friction[F_PERIOD] = period / steps
    st = 0
    for k in range(1, steps + 1):
        w = k / steps
        last = k == steps
        st = _one_tick_kernel(proj, zone_energy, live_ctrl, live_rest, ku, kv, patch, md_args, dec_params, tip_radius,
                              friction, deform, cx if last else px + w * (cx - px), cy if last else py + w * (cy - py),
                              cz if last else pz + w * (cz - pz), bending, torsion,
                              signal_mode if last else SIGNALS_NONE, state, coll, scratch, ev, out)
    friction[F_PERIOD] = period
    return st


@njit(cache=True, inline="always")
def _keep_state(src, i, dst, j):
    """``dst[j:j + S_SIZE] = src[i:i + S_SIZE]`` (a model state) but the contact table's unused rows
    and its tracking starts, which the next tick writes before it reads them
    (:func:`~arsurf.contact.multi_contact.find_contacts_kernel`): about a third of the copy."""
    count = src[i + S_CONTACTS + mc.T_COUNT]
    rows = S_CONTACTS + mc.T_ROWS + (int(count) * mc.C_SIZE if count > 0.0 else 0)
    _copy(src, i, dst, j, rows)
    tail = S_CONTACTS + mc.T_SCANNED
    _copy(src, i + tail, dst, j + tail, S_SIZE - tail)


@njit(cache=True, inline="always")
def _copy(src, i, dst, j, size):
    """``dst[j:j + size] = src[i:i + size]``."""
    for m in range(size):
        dst[j + m] = src[i + m]


@njit(cache=True, _nrt=False)
def _one_tick_kernel(proj, zone_energy, live_ctrl, live_rest, ku, kv, patch, md_args, dec_params, tip_radius, friction,
                     deform, cx, cy, cz, bending, torsion, signal_mode, state, coll, scratch, ev, out):
    """One model tick for the target tip centre ``(cx, cy, cz)`` (module docstring, steps 1-4);
    writes ``out`` (:data:`MODEL_OUT`) and updates ``state`` (:data:`MODEL_STATE`). Returns the
    collision status (< 0: no answer; ``out`` then holds zero forces). ``md_args`` is the contact
    vector (:func:`~arsurf.contact.material_map.contact_vector`: the reference law, a material map,
    scratch space), ``dec_params`` the measured force's parameters
    (:data:`~arsurf.force.decoupling.MEASURED_PARAMS`), ``friction`` the proxy's (:data:`PROXY_PARAMS`);
    ``coll`` (:data:`~arsurf.contact.layout.COLLISION_OUT`), ``scratch`` (:data:`SCRATCH_SIZE`) and
    ``ev`` (:data:`~arsurf.contact.newton.EVALUATION_ROWS`, 3) are scratch arrays.

    ``signal_mode``: SIGNALS_NONE (no measured force), SIGNALS_GIVEN (``bending``, ``torsion``
    are the measured angles, rad), SIGNALS_SYNTHESISED (the angles are made from the simulated
    force through the cantilever model, ``bending``/``torsion`` being the noise added to them).
    Out of contact (MD separated) there is no contact normal to decouple with: the measured force
    is the classical reading F = (0, θ/c, α/g), flagged ``FALLBACK_DEGENERATE``."""
    _clear_output(out, cx, cy, cz)
    prev_u, prev_v = state[S_HINT_U], state[S_HINT_V]
    st = pj.collide_any(proj, cx, cy, cz, tip_radius, prev_u, prev_v, coll)  # 1. collide with the rest surface
    out[M_COLLIDE_STATUS] = st
    if st < 0:
        _forget_contact(state)
        return st
    # a target pressed through a thin wall stays on the side it came from (the god-object's memory)
    keep_side_kernel(live_rest, ku, kv, ev, cx, cy, cz, tip_radius, prev_u, prev_v, state, S_SIDE, coll)
    state[S_HINT_U], state[S_HINT_V] = coll[pj.OUT_U], coll[pj.OUT_V]
    # the contact law where the tip touches: a material map's local E* and w, else the reference
    at, stiffness, jump_out, zero_load, local = local_law_kernel(md_args, coll[pj.OUT_U], coll[pj.OUT_V])
    md = md_args[at:at + _MD_SIZE]
    if local:  # the pull-off: the local Maugis-Dugdale law's, or the zone law's 2 pi R w with the local w
        pull_off = local_pull_off_kernel(md_args, md) if zone_energy is None else \
            friction[F_PULL_OFF] * md[A_LOAD_SCALE] / md_args[C_REF + A_LOAD_SCALE]
        f0 = _local_proxy_params(md_args, friction, stiffness, jump_out, zero_load, pull_off)
        friction = md_args[f0:f0 + friction.size]
    margin = CONTACT_MARGIN * md[A_DEPTH_SCALE]
    floor = friction[F_JUMP_OUT] - margin
    if zone_energy is not None:  # the energy of the whole tip (arsurf.contact.zone_energy): one contact
        _copy_collision(coll, out)
        count = 1
        md_st, a, load, depth, rx, ry, rz = _zone_contact(zone_energy, md, friction, tip_radius, cx, cy, cz, state,
                                                          coll, scratch, out)
    else:
        count, md_st, a, load, depth, rx, ry, rz = _contacts_at_minima(
            live_rest, ku, kv, ev, md, friction, tip_radius, floor, margin, prev_u, prev_v, cx, cy, cz, state, coll,
            scratch, out)
    nx, ny, nz = out[M_NX], out[M_NY], out[M_NZ]
    if a > SMALL_CONTACT_LIMIT * tip_radius:  # the law assumes a << R (contact.mechanics.SMALL_CONTACT_LIMIT)
        out[M_MODEL_FLAGS] = BEYOND_MODEL
    if deform:  # 3. record the dent of the live net, O(1): the net moves to it when read (Deformer.sync)
        # the tip sphere's dent: the closest contact's zone along its own normal; the sphere's
        # no-interpenetration guard (out to R around the axis) presses the other contacts onto it
        zone = md_zone_radius(a, depth, md[A_DEPTH_SCALE], md[A_RADIUS_SCALE], md[A_LAMBDA])
        d0 = int(md_args[H_DENT])
        out[M_MOVED] = record_dent_kernel(md_args[d0:d0 + DENT_SIZE], ku, kv, out[M_TIP], out[M_TIP + 1],
                                          out[M_TIP + 2], tip_radius if md_st == CONTACT else 0.0, coll[pj.OUT_NX],
                                          coll[pj.OUT_NY], coll[pj.OUT_NZ], a, depth, zone)
    # 4. simulated force: normal load plus the stick-slip friction of the proxy anchored where the tip stuck
    sx, sy, strength, share_x, share_z, f_static = _simulated_force(md_st, a, load, cx, cy, cz, friction,
                                                                    state, scratch, out)
    out[M_SIM_FX] += rx  # the part of the summed normal force off the total normal (0 for one contact)
    out[M_SIM_FY] += ry
    out[M_SIM_FZ] += rz
    if friction[F_COUPLING] < math.inf:  # a jump of the tip behind the coupling and of its force, spread over
        _blend_jumps(friction, cx, cy, cz, state, out)  # the blend time
    if signal_mode != SIGNALS_NONE:  # 4. measured force from the two angles
        if signal_mode == SIGNALS_SYNTHESISED:  # the simulated force's angles (cantilever model) plus noise
            bending = dec_params[P_BENDING_COMPLIANCE] * (out[M_SIM_FZ] + dec_params[P_COUPLING] * out[M_SIM_FX]) \
                + bending
            torsion = dec_params[P_TORSION_COMPLIANCE] * out[M_SIM_FY] + torsion
        out[M_BENDING] = bending
        out[M_TORSION] = torsion
        if md_st == SEPARATED or md_st < 0:
            ds = bending_only_kernel(bending, torsion, dec_params, scratch)
        else:  # decoupled with the contact normal and the proxy's friction direction
            if count > 1:  # several contacts: the direction of their summed normal force
                nx, ny, nz, share_x, share_z = _summed_normal(nx, ny, nz, load, rx, ry, rz, md[A_LOAD_SCALE],
                                                              share_x, share_z)
            ds = blended_decouple_kernel(bending, torsion, nx, ny, nz, sx, sy, strength, share_x, share_z,
                                         f_static, out[M_SIM_FX], out[M_SIM_FY], out[M_SIM_FZ], dec_params, scratch)
        out[M_DECOUPLE_STATUS] = ds
        for j in range(3):
            out[M_MEAS_FX + j] = scratch[_MEASURED + dc.O_FORCE + j]
        out[M_CONDITION] = scratch[_MEASURED + dc.O_CONDITION]
    return st


@njit(cache=True, inline="always")
def _contacts_at_minima(live_rest, ku, kv, ev, md, friction, tip_radius, floor, margin, prev_u, prev_v, cx, cy, cz,
                        state, coll, scratch, out):
    """Steps 1-2 of the tick past the collision with the contacts at the minima of the distance
    (:mod:`arsurf.contact.multi_contact`): writes the collision, the total normal, the tip, depth,
    radius, status and load into ``out``; returns ``(count, status, a, load, depth)`` and the part of
    the summed normal force off the total normal (0 for one contact)."""
    # the closest contact's depth under the tip: the one contact's behind the coupling at this target
    # (a function of where the target is; last tick's lift, which the zone once used, fed the zone
    # back into the weights and the lift: a target held still got forces 0.3-1.5x apart tick to tick)
    coupled = coupled_depth_kernel(
        coll[pj.OUT_DEPTH], state[S_TIP_DEPTH], state[S_INTERACTING] > 0.5, friction[F_COUPLING],
        friction[F_JUMP_OUT], friction[F_ZERO_LOAD], md[A_DEPTH_SCALE], md[A_RADIUS_SCALE], md[A_LOAD_SCALE],
        md[A_LAMBDA], md[A_T_FOLD], md[A_DELTA_FOLD], state[S_MEMO:S_MEMO + MEMO_SIZE])
    d1 = coupled[3] if math.isfinite(coupled[3]) else coll[pj.OUT_DEPTH]
    # its Dugdale zone there, continuous where the contact radius reaches 0 (the cohesive zone holds the
    # tip down to the jump-out depth; a zone stepping from c to 0 there flipped the merge of the minima
    # inside it, and the force, every tick as the lift moved d1 by pm: 2781 reversals in a 3 s slide)
    # (in contact, in closed form from the contact radius there; on the cohesive branch by a solve)
    zone = md_zone_radius(coupled[1], d1, md[A_DEPTH_SCALE], md[A_RADIUS_SCALE], md[A_LAMBDA]) \
        if coupled[1] > 0.0 and d1 == coupled[3] else \
        md_zone_from_depth_kernel(d1, md[A_DEPTH_SCALE], md[A_RADIUS_SCALE], md[A_LOAD_SCALE], md[A_LAMBDA],
                                  md[A_T_FOLD], md[A_DELTA_FOLD])
    # the contact pushes along the resultant over its zone, not the normal at the closest point alone
    zone_normal_kernel(live_rest, ku, kv, ev, cx, cy, cz, tip_radius, floor, coll[pj.OUT_DEPTH], zone,
                       coll[pj.OUT_U], coll[pj.OUT_V], coll[pj.OUT_NX:pj.OUT_NX + 3])
    # every local minimum of the distance in reach: a tip wider than a valley rests on several asperities
    count = mc.find_contacts_kernel(live_rest, ku, kv, ev, cx, cy, cz, tip_radius, floor, margin, prev_u, prev_v,
                                    state, S_CONTACTS, coll, scratch[_DISCOVERY:_DISCOVERY + mc.DISCOVERY_WORK])
    _copy_collision(coll, out)
    if count > 1:  # weighed (minima inside the closest contact's disc are one contact); the tip moves
        # behind the coupling along the total normal; each contact pushes along the resultant over its zone
        mc.zone_normals_kernel(live_rest, ku, kv, ev, cx, cy, cz, tip_radius, floor, coll[pj.OUT_DEPTH] - d1,
                               md[A_DEPTH_SCALE], md[A_RADIUS_SCALE], md[A_LOAD_SCALE], md[A_LAMBDA], md[A_T_FOLD],
                               md[A_DELTA_FOLD], state, S_CONTACTS, count)
        mc.weigh_contacts_kernel(live_rest, ku, kv, ev, cx, cy, cz, tip_radius, margin, zone, friction[F_JUMP_OUT],
                                 state, S_CONTACTS, count)
        out[M_NX], out[M_NY], out[M_NZ] = mc.total_normal_kernel(state, S_CONTACTS, count, friction[F_JUMP_OUT],
                                                                   margin)
    # 2. contact mechanics with hysteresis, at the tip behind the coupling (on the target's normal line)
    rx = ry = rz = 0.0
    if count > 1:  # each contact's own law at its own depth under the one rigid tip, all behind the coupling
        md_st, a, load, depth, rx, ry, rz = _sum_contacts(md, friction, tip_radius, count, margin, cx, cy, cz,
                                                          state, out)
    else:
        md_st, a, load, depth = _contact_mechanics(coupled, coll[pj.OUT_DEPTH], tip_radius, cx, cy, cz, state, out)
        state[S_CONTACTS + mc.T_LIFT] = coll[pj.OUT_DEPTH] - depth
    return count, md_st, a, load, depth, rx, ry, rz


@njit(cache=True)
def _blend_jumps(friction, cx, cy, cz, state, out):
    """The tip and the simulated force moved by the excesses of :mod:`arsurf.contact.jump_blend`."""
    ex, ey, ez, gx, gy, gz = jb.blend_jumps_kernel(
        friction[F_BLEND_TIME], friction[F_BLEND_SPEED], friction[F_PERIOD], out[M_TIP], out[M_TIP + 1],
        out[M_TIP + 2], cx, cy, cz, out[M_SIM_FX], out[M_SIM_FY], out[M_SIM_FZ], state, S_JUMPS)
    out[M_TIP] += ex
    out[M_TIP + 1] += ey
    out[M_TIP + 2] += ez
    out[M_SIM_FX] += gx
    out[M_SIM_FY] += gy
    out[M_SIM_FZ] += gz


@njit(cache=True)
def _clear_output(out, cx, cy, cz):
    """Zeros; no angles (NaN); the tip at the target."""
    for k in range(M_SIZE):
        out[k] = 0.0
    out[M_BENDING] = math.nan
    out[M_TORSION] = math.nan
    out[M_TIP] = cx
    out[M_TIP + 1] = cy
    out[M_TIP + 2] = cz


@njit(cache=True)
def _forget_contact(state):
    """No collision answer: no tip depth, no contacts to follow, no friction anchor."""
    state[S_TIP_DEPTH] = math.nan
    for j in range(3):
        state[S_SIDE + j] = math.nan
    state[S_CONTACTS + mc.T_COUNT] = 0.0
    state[S_CONTACTS + mc.T_LIFT] = math.nan
    fr.release(state, S_FRICTION)
    jb.forget(state, S_JUMPS)
    for j in range(3):
        state[S_ZONE_TIP + j] = math.nan


@njit(cache=True, _nrt=False)
def _local_proxy_params(md_args, friction, stiffness, jump_out, zero_load, pull_off):
    """The proxy parameters under a material map's local law: the model's, with the local
    tangential stiffness, the local jump-out and zero-load depths and pull-off force magnitude,
    written in the contact vector's scratch section; returns their offset there."""
    f0 = int(md_args[H_FRICTION])
    for k in range(friction.size):
        md_args[f0 + k] = friction[k]
    md_args[f0 + F_KT_PER_A] = friction[F_KT_PER_A] * stiffness
    md_args[f0 + F_JUMP_OUT] = jump_out
    md_args[f0 + F_ZERO_LOAD] = zero_load
    md_args[f0 + F_PULL_OFF] = pull_off
    return f0


@njit(cache=True)
def _copy_collision(coll, out):
    """The collision's closest point, normal and (u, v) into the model output."""
    for j in range(3):
        out[M_PX + j] = coll[pj.OUT_PX + j]
    for j in range(3):
        out[M_NX + j] = coll[pj.OUT_NX + j]
    out[M_U] = coll[pj.OUT_U]
    out[M_V] = coll[pj.OUT_V]


@njit(cache=True)
def _contact_mechanics(answer, target_depth, tip_radius, cx, cy, cz, state, out):
    """Step 2: the Maugis-Dugdale contact of the tip behind the coupling, ``answer`` (that of
    :func:`~arsurf.contact.proxy.coupled_depth_kernel` at ``target_depth``), which sits
    ``target_depth - depth`` out along the normal from the target; updates the hysteresis memory
    and writes the tip, depth, radius, load and status. Returns ``(status, a, load, depth)``
    (a = load = 0 for a failed solve)."""
    md_st, a, load, depth, coupled = answer
    lift = target_depth - depth
    if md_st < 0:
        a = 0.0
        load = 0.0
    _record_contact(cx + lift * out[M_NX], cy + lift * out[M_NY], cz + lift * out[M_NZ], coupled, tip_radius, depth,
                    md_st, a, load, state, out)
    return md_st, a, load, depth


@njit(cache=True, inline="always")
def _record_contact(tx, ty, tz, coupled, tip_radius, depth, md_st, a, load, state, out):
    """Step 2's outputs: the tip (tx, ty, tz) m behind the coupling (``coupled``: the coupling
    equation solved), its depth (m), status, contact radius (m) and load (N) into ``out``, and the
    hysteresis memory (interacting: in contact or cohesive) into ``state``."""
    out[M_TIP] = tx
    out[M_TIP + 1] = ty
    out[M_TIP + 2] = tz
    out[M_COUPLED] = 1.0 if coupled else 0.0
    out[M_DISTANCE] = tip_radius - depth
    out[M_DEPTH] = depth
    out[M_MD_STATUS] = md_st
    out[M_RADIUS] = a
    out[M_LOAD] = load
    out[M_IN_CONTACT] = 1.0 if md_st == CONTACT else 0.0
    interacting = md_st == CONTACT or md_st == COHESIVE
    state[S_INTERACTING] = 1.0 if interacting else 0.0
    state[S_TIP_DEPTH] = depth if interacting else math.nan


@njit(cache=True)
def _zone_contact(zone_energy, md, friction, tip_radius, cx, cy, cz, state, coll, scratch, out):
    r"""Step 2 with the energy of the whole tip (:mod:`arsurf.contact.zone_energy`; ``zone_energy``
    its ``(lattice, (E*, sigma0, h0))``): the tip behind the coupling moved from where it was (the
    state's; at first the target, or out along the normal from the closest point when the target is
    within a tip radius of the surface) to the nearest minimum of
    :math:`E(T) + \tfrac12 k\lVert T - C\rVert^2` (:func:`~arsurf.contact.zone_energy.zone_proxy_kernel`;
    without a coupling the tip is the target), and the force on it, F. Its direction gives the
    normal, :func:`_summed_normal` of F about the closest point's normal n (n at no load); the tip's
    depth is the target's less the tip's lift along n; the status is contact below depth 0,
    cohesive where the law still pulls, separated where it gives nothing, and the contact radius the
    law's own (Hertz, :math:`a = \sqrt{R\delta}`). Writes the tip, depth, radius, status, normal
    and load (F along that normal) and the hysteresis state; returns ``(status, a, load, depth)``
    and the part of F off the normal, as :func:`_sum_contacts`."""
    lat, law = zone_energy
    e_star, sigma0, h0 = law[0], law[1], law[2]
    k = friction[F_COUPLING]
    nx, ny, nz = coll[pj.OUT_NX], coll[pj.OUT_NY], coll[pj.OUT_NZ]
    t = S_ZONE_TIP
    if not math.isfinite(state[t]):  # from outside the material
        lift = 0.0 if coll[pj.OUT_DISTANCE] >= tip_radius else tip_radius + h0 - coll[pj.OUT_DISTANCE]
        state[t], state[t + 1], state[t + 2] = cx + lift * nx, cy + lift * ny, cz + lift * nz
    zone = scratch[_ZONE:_ZONE + ze.Z_SIZE]
    if k < math.inf:
        ze.zone_proxy_kernel(lat, cx, cy, cz, k, tip_radius, e_star, sigma0, h0, state[t:t + 3], zone,
                             ze.TRACKING_REDUCTION)
    else:
        state[t], state[t + 1], state[t + 2] = cx, cy, cz
        ze.tip_energy_kernel(lat, cx, cy, cz, tip_radius, e_star, sigma0, h0, zone,
                             scratch[_ZONE:_ZONE].reshape((0, 0)))  # no Hessian
    fx, fy, fz = zone[ze.Z_FORCE], zone[ze.Z_FORCE + 1], zone[ze.Z_FORCE + 2]
    reached = fx != 0.0 or fy != 0.0 or fz != 0.0
    if not reached:  # out of reach: the coupled minimum is the target itself, exactly
        state[t], state[t + 1], state[t + 2] = cx, cy, cz  # (no rounding carried from the path to the contact)
    ox, oy, oz = state[t] - cx, state[t + 1] - cy, state[t + 2] - cz
    depth = coll[pj.OUT_DEPTH] - (ox * nx + oy * ny + oz * nz)
    along = fx * nx + fy * ny + fz * nz
    mx, my, mz, _, _ = _summed_normal(nx, ny, nz, along, fx - along * nx, fy - along * ny, fz - along * nz,
                                      md[A_LOAD_SCALE], 0.0, 0.0)
    load = fx * mx + fy * my + fz * mz
    if not reached:
        md_st, a = SEPARATED, 0.0
    elif depth > 0.0:
        md_st, a = CONTACT, math.sqrt(tip_radius * depth)
    else:
        md_st, a = COHESIVE, 0.0
    out[M_NX], out[M_NY], out[M_NZ] = mx, my, mz
    _record_contact(state[t], state[t + 1], state[t + 2], k < math.inf, tip_radius, depth, md_st, a, load, state, out)
    return md_st, a, load, depth, fx - load * mx, fy - load * my, fz - load * mz


@njit(cache=True)
def _sum_contacts(md, friction, tip_radius, count, margin, cx, cy, cz, state, out):
    r"""Step 2 with several contacts (:mod:`arsurf.contact.multi_contact`): the one rigid tip sits
    where the coupling balances the summed loads along the total normal n (``out``'s normal;
    :func:`~arsurf.contact.multi_contact.coupled_lift_kernel`), contact i
    :math:`\delta_i - \ell\,(n\cdot n_i)` deep with its weight and entry ramp. Writes the tip, the
    closest contact's depth, radius and status, the total load :math:`F_N\cdot n`, the hysteresis
    memory; returns ``(status, a, load, depth)`` like :func:`_contact_mechanics` and the part of
    :math:`F_N = \sum_i w_i e_i P_i n_i` off n."""
    nx, ny, nz = out[M_NX], out[M_NY], out[M_NZ]
    t = S_CONTACTS
    lift, coupled, fx, fy, fz, load, st0, a0, p0, d0 = mc.coupled_lift_kernel(
        state, t, count, nx, ny, nz, friction[F_COUPLING], state[S_INTERACTING] > 0.5, state[t + mc.T_LIFT],
        friction[F_JUMP_OUT], margin, md[A_DEPTH_SCALE], md[A_RADIUS_SCALE], md[A_LOAD_SCALE], md[A_LAMBDA],
        md[A_T_FOLD], md[A_DELTA_FOLD])
    state[t + mc.T_LIFT] = lift
    ox, oy, oz = lift * nx, lift * ny, lift * nz
    if coupled:  # held by the coupling sideways too
        ox, oy, oz, fx, fy, fz = mc.coupled_offset_kernel(
            state, t, count, nx, ny, nz, friction[F_COUPLING], lift, fx, fy, fz, friction[F_JUMP_OUT], margin,
            md[A_DEPTH_SCALE], md[A_RADIUS_SCALE], md[A_LOAD_SCALE], md[A_LAMBDA], md[A_T_FOLD], md[A_DELTA_FOLD])
    _record_contact(cx + ox, cy + oy, cz + oz, coupled, tip_radius, d0, st0, a0, load, state, out)
    return st0, a0, load, d0, fx - load * nx, fy - load * ny, fz - load * nz


@njit(cache=True)
def _summed_normal(nx, ny, nz, load, rx, ry, rz, load_scale, share_x, share_z):
    r"""The normal the decoupling takes with several contacts (docs/design.rst, "Several contacts
    at once"): the direction of the summed normal force :math:`F_N = L n + r` (L the load along
    the total normal n, r its part off n), on n's side,
    :math:`m = (n + r L/(L^2 + P_s^2)) / \lVert\cdot\rVert` (:math:`P_s` the law's load scale:
    :math:`F_N/L` once :math:`|L| \gg P_s`, n at zero load, continuous between), and the
    fallback's friction shares per unit load along m, :math:`F_t/(F_N\cdot m)` (0 unless that
    load is compressive). Returns ``(mx, my, mz, share_x, share_z)``."""
    k = load / (load * load + load_scale * load_scale)
    mx, my, mz = nx + k * rx, ny + k * ry, nz + k * rz
    mn = math.sqrt(mx * mx + my * my + mz * mz)
    mx, my, mz = mx / mn, my / mn, mz / mn
    along = load * (nx * mx + ny * my + nz * mz) + rx * mx + ry * my + rz * mz  # F_N . m
    scale = load / along if (load > 0.0 and along > 0.0) else 0.0
    return mx, my, mz, share_x * scale, share_z * scale


@njit(cache=True)
def _simulated_force(md_st, a, load, cx, cy, cz, friction, state, scratch, out):
    """Step 4, simulated: F = P n + F_t, the friction of the stick-slip proxy
    (:func:`~arsurf.contact.friction.stick_slip_kernel`) within the limits of the friction law
    (:func:`~arsurf.contact.friction.friction_limits`: by default ``mu (P + |P_c|)``, so an adhesive
    contact under tensile load resists sliding too) while in contact. Returns what the measured
    force needs of the friction: its direction (x, y), strength, components along x and z per unit
    load (zeros without friction or without a compressive load) and the static limit f_s (N)."""
    fx = load * out[M_NX]
    fy = load * out[M_NY]
    fz = load * out[M_NZ]
    sx = sy = strength = share_x = share_z = 0.0
    f_static, f_kinetic = fr.friction_limits(int(friction[F_LAW]), friction[F_MU_S], friction[F_MU_K], load,
                                             friction[F_PULL_OFF], friction[F_SHEAR], a)
    if md_st == CONTACT and f_static > 0.0 and a > 0.0:
        k_t = friction[F_KT_PER_A] * a
        kc = friction[F_COUPLING]
        if kc < math.inf:
            k_t = k_t * kc / (k_t + kc)  # the tangential contact in series with the coupling
        out[M_SLIPPING] = fr.stick_slip_kernel(cx, cy, cz, out[M_NX], out[M_NY], out[M_NZ], f_static, f_kinetic, k_t,
                                               state, S_FRICTION, scratch)
        fx += scratch[fr.O_FORCE]
        fy += scratch[fr.O_FORCE + 1]
        fz += scratch[fr.O_FORCE + 2]
        sx = scratch[fr.O_DIRECTION]
        sy = scratch[fr.O_DIRECTION + 1]
        strength = scratch[fr.O_STRENGTH]
        if load > 0.0:  # the fallback's F = N (n + share) needs a load to scale (blended_decouple_kernel)
            share_x = scratch[fr.O_FORCE] / load
            share_z = scratch[fr.O_FORCE + 2] / load
    else:
        fr.release(state, S_FRICTION)
    out[M_SIM_FX] = fx
    out[M_SIM_FY] = fy
    out[M_SIM_FZ] = fz
    return sx, sy, strength, share_x, share_z, f_static


@dataclass(frozen=True)
class ModelTick:
    """One tick of the model (SI units).

    ``point``, ``normal``, ``uv``, ``distance``, ``depth``: the collision on the rest surface;
    ``contact_radius``, ``load`` (N, > 0 compressive), ``in_contact``, ``md_status`` (0 contact,
    1 cohesive, 2 separated); ``simulated_force`` and ``measured_force`` (N, on the tip; the
    latter NaN without signals), ``decoupling_flags``, ``condition``; ``moved`` control points under the dent (its index
    box, the points it may move: the tick records the dent, the net moves to it when read);
    ``tip`` the tip centre behind the virtual coupling (the target without one), ``slipping``
    whether the friction proxy slid this tick, ``coupled`` whether the coupling equation was
    solved (False: the tip is at the target); ``model_flags`` the caveats of :mod:`arsurf.status`
    (``BEYOND_MODEL``: a contact wider than the law holds for, a > 0.4 R).
    """

    point: np.ndarray
    normal: np.ndarray
    uv: np.ndarray
    distance: float
    depth: float
    contact_radius: float
    load: float
    in_contact: bool
    md_status: int
    simulated_force: np.ndarray
    measured_force: np.ndarray
    decoupling_flags: int
    condition: float
    moved: int
    collide_status: int
    tip: np.ndarray
    slipping: bool
    coupled: bool
    model_flags: int = 0


class ARModel:
    """The live model: a surface, a spherical tip, a contact law and a cantilever.

    Parameters
    ----------
    surface : BSplineSurface
        The fitted surface; it is dented in place (``surface.reset()`` undoes it). A private rest
        copy is used for collision.
    tip_radius : float, metres
    contact : MaugisDugdale
        Contact law (its tip radius must equal ``tip_radius``).
    cantilever : Cantilever
        For the decoupling of measured signals and for simulated signals.
    friction : float
        Kinetic friction coefficient :math:`\\mu_k` (>= 0); the seeds give one coefficient, 0.2.
    static_friction : float, optional
        Static coefficient :math:`\\mu_s \\ge \\mu_k` of the stick-slip proxy
        (:mod:`arsurf.contact.friction`); default :math:`\\mu_k` (no stick-slip jump; above it a
        slide shows the saw-tooth of period :math:`(\\mu_s - \\mu_k) N / (k_t v)`).
    friction_law : {"adhesive", "area", "compressive"}
        The friction's normal (:func:`~arsurf.contact.friction.friction_limits`): ``"adhesive"``
        (default) :math:`N = P + |P_c|`, friction down to the pull-off; ``"area"``
        :math:`f_k = \\tau \\pi a^2`; ``"compressive"`` :math:`N = \\max(P, 0)` (sessions recorded
        before the law was recorded).
    shear_strength : float, Pa, optional
        Interfacial shear strength :math:`\\tau` of the ``"area"`` law (required there, > 0).
    coupling_stiffness : float, N/m, optional
        Stiffness of the virtual coupling between the target and the tip, at the probe's scale
        (:mod:`arsurf.contact.proxy`); ``inf`` (default): the tip is the target.
    deform : bool
        Dent the surface (False: only compute contacts and forces).
    material : MaterialMap, optional
        Per-location E* and w (:mod:`arsurf.contact.material_map`); ``contact`` is then the
        reference law (:meth:`~arsurf.contact.material_map.MaterialMap.contact_law`: same tip
        radius and Dugdale range). A uniform map gives exactly the model without one.
    signal_noise : float, rad rms, optional
        Noise on each measured angle; the measured force trusts the directional decoupling less
        as its noise gain grows (:data:`FADE_CONDITION`). Default :data:`DEFAULT_SIGNAL_NOISE`.
    zone_energy : bool
        The contact as the energy of the whole tip (:mod:`arsurf.contact.zone_energy`, the law's
        E*, w and Dugdale stress summed over the surface under the tip; the tip behind the
        coupling at the nearest minimum of that energy plus the coupling's, :func:`_zone_contact`)
        instead of the Maugis-Dugdale contacts at the minima of the distance. Default False
        (docs/feel.rst, "The energy of the whole tip": measured, not yet the default). With a
        material map each surface element sums its own local law (always the sum).
    zone_closed_form : bool
        With ``zone_energy``, the energy in closed form where its checks trust it, joined smoothly
        to the lattice's sum (:func:`~arsurf.contact.zone_energy.tip_energy_kernel`); a quarter of
        the sum's tick on smooth scans, the same runs of the feel tables passed (docs/feel.rst,
        "The energy of the whole tip in one term"). Default True; False sums the lattice
        everywhere.

    Examples
    --------
    >>> import numpy as np
    >>> from arsurf.spline.surface import BSplineSurface
    >>> from arsurf.force.cantilever import Cantilever
    >>> s = BSplineSurface.from_heights(np.zeros((40, 40)), (0, 148e-9), (0, 148e-9))
    >>> md = MaugisDugdale(20e-9, 50e9, 0.05)
    >>> m = ARModel(s, 20e-9, md, Cantilever(450e-6, 50e-6, 2.5e-6, 15e-6, 169e9, 0.27))
    >>> t = m.step((70e-9, 70e-9, 19.5e-9))
    >>> t.in_contact and t.load > 0 and s.is_deformed
    True
    """

    def __init__(self, surface: BSplineSurface, tip_radius: float, contact: MaugisDugdale,
                 cantilever: Cantilever, friction: float = 0.2, deform: bool = True, *,
                 static_friction: float | None = None, coupling_stiffness: float = math.inf, material=None,
                 signal_noise: float | None = None, friction_law: str = "adhesive",
                 shear_strength: float | None = None, zone_energy: bool = False, zone_closed_form: bool = True):
        if not isinstance(surface, BSplineSurface):
            raise ContactError(f"surface must be an arsurf BSplineSurface (got {type(surface).__name__})")
        tip_radius = float(tip_radius)
        if not (math.isfinite(tip_radius) and tip_radius > 0.0):
            raise ContactError(f"`tip_radius` must be positive (got {tip_radius!r} m); it is the tip sphere radius")
        if not isinstance(contact, MaugisDugdale):
            raise ContactError(f"contact must be an arsurf.MaugisDugdale (got {type(contact).__name__})")
        if not math.isclose(contact.tip_radius, tip_radius, rel_tol=1e-12):
            raise ContactError(
                f"the contact law's tip radius ({contact.tip_radius!r} m) differs from tip_radius ({tip_radius!r} m)")
        friction = _validation.non_negative(friction, "friction", ContactError, hint="the kinetic friction coefficient")
        static = friction if static_friction is None else _validation.non_negative(
            static_friction, "static_friction", ContactError, hint="the static friction coefficient")
        if static < friction:
            raise ContactError(f"static_friction ({static!r}) must be >= friction ({friction!r}): the static cone "
                               "contains the kinetic one")
        law = fr.LAW_NAMES.get(friction_law) if isinstance(friction_law, str) else None
        if law is None:
            raise ContactError(f"friction_law must be one of {sorted(fr.LAW_NAMES)} (got {friction_law!r})")
        if law == fr.LAW_AREA:
            shear_strength = _validation.non_negative(shear_strength, "shear_strength", ContactError,
                                                      hint="the interfacial shear strength of the area law, Pa")
            if not (shear_strength > 0.0 and friction > 0.0):
                raise ContactError(f"the area friction law needs shear_strength > 0 Pa and friction > 0 (got "
                                   f"{shear_strength!r} Pa, {friction!r}): its static limit is mu_s / mu_k times "
                                   "tau pi a^2")
        elif shear_strength is not None:
            raise ContactError(f"shear_strength is the area law's; friction_law is {friction_law!r}")
        signal_noise = DEFAULT_SIGNAL_NOISE if signal_noise is None else _validation.non_negative(
            signal_noise, "signal_noise", ContactError, hint="the rms noise of the measured angles, rad")
        coupling_stiffness = float(coupling_stiffness)
        if not coupling_stiffness > 0.0:
            raise ContactError(f"`coupling_stiffness` must be > 0 N/m or inf (got {coupling_stiffness!r})")
        from arsurf.contact.deformation import Deformer

        self.surface = surface
        nu, nv = surface.shape
        if surface.at_rest:  # the rest snapshot below is a copy of the whole net
            _validation.check_memory(24.0 * nu * nv, f"the rest copy of this {nu}x{nv} control net", ContactError,
                                     "fit a cropped scan or fewer control points")
        # collision runs on the rest net: the live surface's own rest snapshot, shared read-only
        # (no copy of the whole net: a 4096^2 net is 400 MB)
        live_ctrl, live_rest, ku, kv = surface.kernel_arrays()
        self.rest_surface = BSplineSurface.construct_fast(live_rest, ku, kv)
        self.tip_radius = tip_radius
        self.contact = contact
        self.cantilever = cantilever
        self.friction = friction
        self.static_friction = static
        self.friction_law = friction_law
        self.shear_strength = shear_strength
        self.signal_noise = signal_noise
        self.deform = bool(deform)
        proj = pj.projector(self.rest_surface)
        self._proj_args = proj.kernel_args()
        if not isinstance(zone_energy, bool):
            raise ContactError(f"`zone_energy` must be True or False (got {zone_energy!r})")
        self.zone_energy = zone_energy
        if not isinstance(zone_closed_form, bool):
            raise ContactError(f"`zone_closed_form` must be True or False (got {zone_closed_form!r})")
        # the measured force's parameters (MEASURED_PARAMS): the decoupling's, then the signal noise level
        self._dec = np.append(decoupling_parameters(cantilever, min_speed=MIN_SLIP_HORIZONTAL), signal_noise)
        self._friction = PROXY_PARAMS.pack({
            "static_friction": static, "kinetic_friction": friction,
            "stiffness_per_radius": fr.MINDLIN_RATIO * 2.0 * contact.effective_modulus,
            "coupling_stiffness": coupling_stiffness, "jump_out_depth": contact.jump_out_depth(),
            "zero_load_depth": float(contact.depth(0.0)), "friction_law": float(law),
            "pull_off_force": abs(contact.pull_off_force()),
            "shear_strength": 0.0 if shear_strength is None else shear_strength, "blend_time": 0.0,
            "blend_speed": jb.BLEND_SPEED, "tick_period": math.nan})
        zone_law = ze.ZoneLaw.from_law(contact)
        if zone_energy:  # the friction's adhesive normal mu (P + |P_c|) with the zone law's pull-off
            self._friction[F_PULL_OFF] = zone_law.pull_off_force()
        self.material = material
        self._deepest_well = None  # the map's deepest adhesive well (J): adhesion_energy, once
        # the contact vector: reference law, material map, scratch for a local friction vector and the dent's profile
        self._md_args = contact_vector(material, contact, self._friction.size, DENT_SIZE)
        # the energy of the whole tip as the contact (arsurf.contact.zone_energy), or none: (lattice, (E*, sigma0, h0)),
        # each sample with the map's local law
        self.zone_lattice = ze.lattice_for(self.rest_surface, tip_radius, zone_law.interaction_range,
                                           material=self._md_args,
                                           closed_form=zone_closed_form) if zone_energy else None
        self._zone_energy = (self.zone_lattice.arrays, np.array(zone_law.args[1:])) if zone_energy else None
        # validates the height-field rest net; the tick records its dent in the contact vector
        self._deformer = Deformer(surface, record=self._md_args, at=int(self._md_args[H_DENT]))
        self._live = (live_ctrl, live_rest, ku, kv, self._deformer.patch)
        self.state = MODEL_STATE.full(np.nan)
        self._clear_state()
        self._coll = np.empty(pj.OUT_SIZE)
        self._scratch = np.empty(SCRATCH_SIZE)
        self._ev = np.empty((EVALUATION_ROWS, 3))
        self.out = np.zeros(M_SIZE)

    @property
    def coupling_stiffness(self) -> float:
        """Stiffness (N/m, at the probe's scale) of the virtual coupling between the target and
        the tip (:mod:`arsurf.contact.proxy`); ``inf``: none, the tip is the target."""
        return float(self._friction[F_COUPLING])

    def set_coupling_stiffness(self, stiffness: float) -> None:
        """Give the model the virtual coupling ``stiffness`` (N/m at the probe's scale; ``inf``:
        none). A haptic loop calls it before its first tick, when it chooses the coupling from the
        device (:meth:`arsurf.haptics.loop.HapticLoop.direct`); the compiled tick reads it from
        the same vector."""
        stiffness = float(stiffness)
        if not stiffness > 0.0:
            raise ContactError(f"`coupling_stiffness` must be > 0 N/m or inf (got {stiffness!r})")
        self._friction[F_COUPLING] = stiffness
        self._deepest_well = None  # adhesion_energy's bound includes the coupling's stretch

    @property
    def jump_blend(self) -> float:
        """The blend time (s) over which the tip's jumps behind the coupling are rendered
        (:mod:`arsurf.contact.jump_blend`); 0: in one tick (off, and until a loop gives its tick)."""
        return float(self._friction[F_BLEND_TIME]) if math.isfinite(self._friction[F_PERIOD]) else 0.0

    def set_jump_blend(self, blend_time: float, period: float) -> None:
        """Render the tip's jumps over ``blend_time`` s (0: in one tick) in ticks of ``period`` s
        (:mod:`arsurf.contact.jump_blend`). A haptic loop calls it before its first tick with its
        own period (:class:`arsurf.haptics.loop.LoopConfig`'s ``jump_blend``); it needs the
        coupling, and a model ticked outside a loop renders its jumps as they are."""
        blend_time = _validation.non_negative(blend_time, "the jump blend time", ContactError, unit="s", hint="0: off")
        period = float(period)
        if not (math.isfinite(period) and period > 0.0):
            raise ContactError(f"the tick period must be a finite time > 0 s (got {period!r})")
        self._friction[F_BLEND_TIME] = blend_time
        self._friction[F_PERIOD] = period
        jb.forget(self.state, S_JUMPS)

    def adhesion_energy(self, with_map: bool = True) -> float:
        """Bound of the energy (J, at the probe) the adhesive contact gives back as a tip leaves it.

        Over the adhesive part of the contact curve the pull towards the surface is at most the
        pull-off force :math:`|P_c|` (load control, the tangent point of the MD curve), between the
        deepest depth where the tip can still be held, :math:`\\min(\\delta_{out}, -h_0)`, and the
        zero-load depth :math:`\\delta_0`; the virtual coupling stretches by at most
        :math:`|P_c|/k_c` more: :math:`E_0 = |P_c|\\,(\\delta_0 - \\min(\\delta_{out}, -h_0) + |P_c|/k_c)`.
        It is the store of a passive adhesive environment (:mod:`arsurf.haptics.passivity`). With
        the zone energy as the contact the law's own: its pull :math:`2\\pi R w` from the range's
        end to its zero-load depth (:class:`~arsurf.contact.zone_energy.ZoneLaw`); with a material
        map the law of its softest E* and largest w, whose energy lies below every element's.

        With a material map the well is the deepest of the local laws the tick can meet: the
        bound is taken over the map's pixels and the points half-way between them
        (:func:`~arsurf.contact.material_map.deepest_well_kernel`), computed once (~3 s for a
        1024² map) and kept; ``with_map=False`` gives the reference law's alone."""
        c = self.contact
        if self.zone_energy:  # the zone law's well on a flat: its pull 2 pi R w from -h0 to its zero-load depth
            z = ze.ZoneLaw.from_law(c)
            if self.material is not None and with_map:  # the softest E* and the largest w bound every element's
                cv = self._md_args
                soft = min(math.exp(cv[H_LO_E] + cv[H_OFF_E]), 1.0)
                sticky = max(math.exp(cv[H_HI_W] + cv[H_OFF_W]), 1.0)
                z = ze.ZoneLaw(z.tip_radius, z.effective_modulus * soft, z.work_of_adhesion * sticky,
                               z.dugdale_stress * sticky)
            pc = z.pull_off_force()
            return pc * (z.zero_load_depth() + z.interaction_range + pc / self.coupling_stiffness)
        pc = abs(c.pull_off_force())
        if pc == 0.0:
            return 0.0
        reach = float(c.depth(0.0)) - min(c.jump_out_depth(), c.jump_in_depth())
        e0 = pc * (reach + pc / self.coupling_stiffness)
        if self.material is None or not with_map:
            return e0
        if self._deepest_well is None:
            m = self.material
            ny, nx = m.fields["reduced_modulus"].pixels.shape
            self._deepest_well = deepest_well_kernel(
                self._md_args.copy(), m.offset[0], m.offset[1], 0.5 * m.spacing[0], 0.5 * m.spacing[1], 2 * nx - 1,
                2 * ny - 1, self.coupling_stiffness, c.interaction_range)
        return max(e0, self._deepest_well)

    def reset(self) -> None:
        """Forget the contact history and restore the surface to rest."""
        self._deformer.release()
        self.surface.reset()
        self._clear_state()

    def _clear_state(self) -> None:
        self.state[:] = np.nan
        self.state[S_INTERACTING] = 0.0
        self.state[S_FRICTION + fr.SLIPPING] = 0.0

    def kernel_args(self) -> tuple:
        """The model's arguments of the compiled tick (:func:`model_tick_kernel` and the loop
        kernels), in their order: the projector, the live net and dent patch, the contact law,
        the decoupling, tip radius, friction, deform, state and the scratch and output vectors.
        The arrays are the model's own (updated in place by every tick)."""
        live_ctrl, live_rest, ku, kv, patch = self._live
        values = {"proj": self._proj_args, "zone_energy": self._zone_energy, "live_ctrl": live_ctrl,
                  "live_rest": live_rest, "ku": ku, "kv": kv,
                  "patch": patch, "md_args": self._md_args, "dec_params": self._dec, "tip_radius": self.tip_radius,
                  "friction": self._friction, "deform": self.deform, "model_state": self.state, "coll": self._coll,
                  "dec": self._scratch, "ev": self._ev, "mout": self.out}
        return tuple(values[name] for name in MODEL_ARGS)

    def tick(self, center, signals=None) -> np.ndarray:
        """Unchecked fast path: run the kernel, return the output vector (M_SIZE,) (reused)."""
        cx, cy, cz = center
        if signals is None:
            b = t = 0.0
            mode = SIGNALS_NONE
        else:
            b, t = signals
            mode = SIGNALS_GIVEN
        live_ctrl, live_rest, ku, kv, patch = self._live
        model_tick_kernel(self._proj_args, self._zone_energy, live_ctrl, live_rest, ku, kv, patch,
                          self._md_args, self._dec, self.tip_radius, self._friction, self.deform,
                          float(cx), float(cy), float(cz), float(b), float(t), mode, self.state, self._coll,
                          self._scratch, self._ev, self.out)
        return self.out

    def force_jacobian(self, center, step: float = 1e-12) -> np.ndarray:
        r"""The force field's Jacobian :math:`J_{ij} = \partial F_i / \partial C_j` (N/m, (3, 3)) at
        the target tip centre ``center`` (m): the simulated force of :meth:`tick` differentiated by
        central differences of ``step`` m, every probe run from the model's present state, which is
        restored afterwards (contact history, friction anchor and recorded dent unchanged).

        :math:`-\tfrac12(J + J^T)` is the stiffness the tip meets (the hand feels it times the
        loop's force gain over its scale). A skew-symmetric part means the force is not the
        gradient of any potential: moved around a small loop of area A in the (i, j) plane the tip
        is given the work :math:`(J_{ji} - J_{ij})\,A` per turn (Stokes), energy that the haptic
        loop's passivity controller then has to take out (docs/feel-log.rst, "Where the rough runs'
        energy comes from")."""
        c = np.asarray(center, dtype=np.float64).reshape(-1)
        step = float(step)
        if c.shape != (3,) or not np.isfinite(c).all():
            raise PositionError(f"center must be 3 finite coordinates in metres (got {center!r})")
        if not (math.isfinite(step) and step > 0.0):
            raise ContactError(f"`step` must be a positive distance in metres (got {step!r})")
        patch = self._live[4]
        saved = (self.state.copy(), self._md_args.copy(), patch.copy())
        jac = np.empty((3, 3))
        try:
            for j in range(3):
                for sign in (1.0, -1.0):
                    self.state[:], self._md_args[:], patch[:] = saved
                    probe = c.copy()
                    probe[j] += sign * step
                    f = self.tick(probe)[M_SIM_FX:M_SIM_FX + 3]
                    jac[:, j] = f if sign > 0 else (jac[:, j] - f)
                jac[:, j] /= 2.0 * step
        finally:
            self.state[:], self._md_args[:], patch[:] = saved
        return jac

    def step(self, center, signals=None) -> ModelTick:
        """Validated tick: target tip centre (3,) m, optional measured (bending, torsion) rad."""
        c = np.asarray(center, dtype=np.float64).reshape(-1)
        if c.shape != (3,) or not np.isfinite(c).all():
            raise PositionError(f"center must be 3 finite coordinates in metres (got {center!r}); check the tip "
                                "position source")
        if signals is not None:
            sig = np.asarray(signals, dtype=np.float64).reshape(-1)
            if sig.shape != (2,) or not np.isfinite(sig).all():
                raise ContactError(f"`signals` must be (bending, torsion) in radians, finite (got {signals!r})")
            signals = (sig[0], sig[1])
        o = self.tick(c, signals)
        if o[M_COLLIDE_STATUS] < 0:
            raise ContactError(f"collision failed with status {int(o[M_COLLIDE_STATUS])} "
                               f"({TEXT.get(int(o[M_COLLIDE_STATUS]), '?')})")
        return self.record(o, have_signals=signals is not None)

    @staticmethod
    def record(o: np.ndarray, have_signals: bool = True) -> ModelTick:
        """The :class:`ModelTick` of an output vector."""
        meas = o[M_MEAS_FX:M_MEAS_FZ + 1].copy() if have_signals else np.full(3, np.nan)
        return ModelTick(
            point=o[M_PX:M_PZ + 1].copy(), normal=o[M_NX:M_NZ + 1].copy(), uv=o[M_U:M_V + 1].copy(),
            distance=float(o[M_DISTANCE]), depth=float(o[M_DEPTH]), contact_radius=float(o[M_RADIUS]),
            load=float(o[M_LOAD]), in_contact=bool(o[M_IN_CONTACT]), md_status=int(o[M_MD_STATUS]),
            simulated_force=o[M_SIM_FX:M_SIM_FZ + 1].copy(), measured_force=meas,
            decoupling_flags=int(o[M_DECOUPLE_STATUS]), condition=float(o[M_CONDITION]),
            moved=int(o[M_MOVED]), collide_status=int(o[M_COLLIDE_STATUS]), tip=o[M_TIP:M_TIP + 3].copy(),
            slipping=bool(o[M_SLIPPING]), coupled=bool(o[M_COUPLED]), model_flags=int(o[M_MODEL_FLAGS]),
        )
