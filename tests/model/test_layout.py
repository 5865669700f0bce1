"""Every kernel vector is a Layout: the kernels write exactly their layouts, the objects allocate
them, the haptic loop's struct and the model's arguments come from one declaration each, and no
hand-counted size or offset is left in the engine's source."""
from __future__ import annotations

import ast
import inspect
import math
import re
from pathlib import Path

import numpy as np
import pytest

from arsurf import status
from arsurf._layout import Layout
from arsurf.contact import friction as fr
from arsurf.contact import layout as cl
from arsurf.contact.maugis_dugdale import MD_ARGS, MaugisDugdale
from arsurf.contact.projection import Projector, collide_kernel
from arsurf.force import decoupling as dc
from arsurf.force.cantilever import Cantilever
from arsurf.haptics import loop as lp
from arsurf.haptics.coupling import FP_PARAMS, FP_STATE, ForcePositionCoupling, fp_step
from arsurf.haptics.passivity import PASSIVITY_PARAMS, PASSIVITY_STATE, PassivityController, passivity_observe_control
from arsurf.haptics.safety import SAFETY_PARAMS, SAFETY_STATE, SafetyLayer, safety_step
from arsurf.haptics.scaling import POSITION_PARAMS, POSITION_STATE, PositionScaling, position_map_step
from arsurf.model import MODEL_ARGS, MODEL_OUT, MODEL_STATE, PROXY_PARAMS, SCRATCH_SIZE, ARModel, model_tick_kernel
from arsurf.spline.surface import BSplineSurface

ENGINE = Path(__file__).resolve().parents[2] / "arsurf"
LEVER = Cantilever(450e-6, 50e-6, 2.5e-6, 15e-6, 169e9, 0.27)
R = 20e-9
PAD = 5  # elements after a vector that a kernel must never touch
SENTINEL = -1.234e300


def padded(layout_or_size, fill=SENTINEL):
    """A vector of the layout's size (``fill``) followed by PAD sentinels, and the view a kernel is given."""
    n = layout_or_size.size if isinstance(layout_or_size, Layout) else int(layout_or_size)
    v = np.full(n + PAD, SENTINEL)
    v[:n] = fill
    return v, v[:n]


def untouched(v, n):
    return bool(np.all(v[n:] == SENTINEL))


def test_layout_offsets_and_allocation():
    lay = Layout("t", [("a", 3), ("b", 1), ("c", 2)])
    assert (lay.size, lay.offset("b"), lay.offset("c"), lay.width("c")) == (6, 3, 4, 2)
    assert lay.extended("t2", [("d", 1)]).offset("d") == 6 and lay.extended("t2", [("d", 1)]).items()[:3] == lay.items()
    assert lay.pack({"c": (5.0, 6.0), "a": (1.0, 2.0, 3.0), "b": 4.0}).tolist() == [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]
    with pytest.raises(ValueError, match="fields are"):
        lay.pack({"a": (1.0, 2.0, 3.0)})
    with pytest.raises(ValueError, match="repeated"):
        Layout("bad", [("a", 1), ("a", 2)])


def test_the_objects_allocate_their_layouts():
    assert PositionScaling(1e-5).params.size == POSITION_PARAMS.size
    assert PositionScaling(1e-5).state.size == POSITION_STATE.size
    fp = ForcePositionCoupling(K_fp=3000.0, B_fp=4.0, G_n=5.0, A_f=1e7, A_d=1e5, dt=1e-3, check=False)
    assert fp.params.size == FP_PARAMS.size and fp.state.size == FP_STATE.size
    assert fp.params[FP_PARAMS.offset("dt")] == 1e-3                        # the field holds what its name says
    s = SafetyLayer(max_force=6.0, dt=1e-3)
    assert s.params.size == SAFETY_PARAMS.size and s.state.size == SAFETY_STATE.size
    assert SAFETY_STATE.width("counts") == len(s.counts)
    pc = PassivityController(1e-3, 5.0, reserve=2e-9)
    assert pc.params.size == PASSIVITY_PARAMS.size and pc.state.size == PASSIVITY_STATE.size
    assert PASSIVITY_PARAMS.get(pc.params, "reserve") == pc.reserve == 2e-9
    md = MaugisDugdale(R, 50e9, 0.05)
    assert len(md.kernel_args) == MD_ARGS.size
    assert MD_ARGS.get(np.array(md.kernel_args), "load_scale") == md.load_scale
    assert len(dc.decoupling_parameters(LEVER)) == dc.DECOUPLING_PARAMS.size


def _model(**kw):
    s = BSplineSurface.from_heights(np.zeros((40, 40)), (0, 148e-9), (0, 148e-9))
    return ARModel(s, R, MaugisDugdale(R, 50e9, 0.05), LEVER, static_friction=0.3, **kw)


def test_the_model_arrays_are_its_layouts():
    m = _model(coupling_stiffness=5.0, signal_noise=3e-7)
    args = dict(zip(MODEL_ARGS, m.kernel_args()))
    assert len(MODEL_ARGS) == len(m.kernel_args())
    assert args["mout"].size == MODEL_OUT.size and args["model_state"].size == MODEL_STATE.size
    assert args["coll"].size == cl.COLLISION_OUT.size and args["dec"].size == SCRATCH_SIZE
    assert SCRATCH_SIZE >= max(fr.FRICTION_OUT.size, dc.MEASURED_SCRATCH.size)
    assert args["friction"].size == PROXY_PARAMS.size and PROXY_PARAMS.get(args["friction"], "coupling_stiffness") == 5.0
    assert args["dec_params"].size == dc.MEASURED_PARAMS.size
    assert dc.MEASURED_PARAMS.get(args["dec_params"], "signal_noise") == 3e-7
    assert MODEL_STATE.width("friction") == fr.FRICTION_STATE.size


@pytest.mark.parametrize("zone_energy", [False, True])
def test_the_model_tick_writes_exactly_its_layouts(zone_energy):
    """The tick (collision, friction, measured force) writes every element of its output and
    stays inside each vector: padding after each one keeps its sentinel over a pressing, sliding
    stroke with synthesised signals (the contacts at the minima of the distance, or the energy of
    the whole tip)."""
    m = _model(coupling_stiffness=5.0, zone_energy=zone_energy)
    a = dict(zip(MODEL_ARGS, m.kernel_args()))
    out_p, out = padded(MODEL_OUT)
    st_p, state = padded(MODEL_STATE, np.nan)
    state[MODEL_STATE.offset("interacting")] = 0.0
    state[MODEL_STATE.offset("friction") + fr.SLIPPING] = 0.0
    coll_p, coll = padded(cl.COLLISION_OUT)
    sc_p, scratch = padded(SCRATCH_SIZE)
    slid = False
    for k in range(200):
        out[:] = SENTINEL
        x = 70e-9 + 0.2e-9 * k
        st = model_tick_kernel(a["proj"], a["zone_energy"], a["live_ctrl"], a["live_rest"], a["ku"], a["kv"], a["patch"], a["md_args"],
                               a["dec_params"], a["tip_radius"], a["friction"], a["deform"], x, 70e-9, 19.0e-9,
                               1e-8, -1e-8, 2, state, coll, scratch, a["ev"], out)
        assert st >= 0 and not np.any(out == SENTINEL)                      # every field written
        slid |= out[MODEL_OUT.offset("slipping")] > 0
    assert slid and out[MODEL_OUT.offset("in_contact")] == 1.0
    for v, n in ((out_p, MODEL_OUT.size), (st_p, MODEL_STATE.size), (coll_p, cl.COLLISION_OUT.size),
                 (sc_p, SCRATCH_SIZE)):
        assert untouched(v, n)


def test_the_collision_writes_exactly_its_layout():
    s = BSplineSurface.from_heights(np.zeros((12, 12)), (0, 44e-9), (0, 44e-9))
    v, out = padded(cl.COLLISION_OUT)
    assert collide_kernel(*Projector(s).kernel_args(), 20e-9, 20e-9, 5e-9, 10e-9, np.nan, np.nan, out) == status.OK
    assert not np.any(out == SENTINEL) and untouched(v, cl.COLLISION_OUT.size)
    assert out[cl.OUT_DEPTH] == pytest.approx(5e-9) and out[cl.OUT_STATUS] == status.OK


def test_the_small_kernels_write_exactly_their_layouts():
    # friction proxy: a stuck then a sliding tick
    st_p, state = padded(fr.FRICTION_STATE, np.nan)
    state[fr.SLIPPING] = 0.0
    o_p, out = padded(fr.FRICTION_OUT)
    for x in (0.0, 1e-10, 5e-9):
        fr.stick_slip_kernel(x, 0.0, 20e-9, 0.0, 0.0, 1.0, 0.3e-7, 0.2e-7, 10.0, state, 0, out)
    assert out[fr.O_STRENGTH] == 1.0 and untouched(st_p, fr.STATE_SIZE) and untouched(o_p, fr.OUT_SIZE)
    assert not np.any(out == SENTINEL)
    # decoupling and its blend
    params = np.append(dc.decoupling_parameters(LEVER), 1e-7)
    d_p, d = padded(dc.MEASURED_SCRATCH)
    b, t = LEVER.angles([1e-9, 2e-9, 5e-9])
    dc.blended_decouple_kernel(b, t, 0.0, 0.0, 1.0, 0.3, 1.0, 0.1, 0.05, 0.0, 1e-9, 0.0, 0.0, 0.0, params, d)
    assert not np.any(d == SENTINEL) and untouched(d_p, dc.MEASURED_SCRATCH.size)
    d_p, d = padded(dc.DECOUPLING_OUT)
    assert dc.bending_only_kernel(b, t, params, d) == dc.DecouplingFlag.FALLBACK_DEGENERATE
    assert not np.any(d == SENTINEL) and untouched(d_p, dc.DECOUPLING_OUT.size)
    # the loop stages' states
    pos = PositionScaling(1e-5, probe_limits=((-1e-6,) * 3, (1e-6,) * 3))
    s_p, s = padded(POSITION_STATE)
    s[:] = pos.state
    position_map_step(pos.params, s, np.array([1e-3, 0.0, 0.0]), 0, 1, np.empty(3))
    assert untouched(s_p, POSITION_STATE.size)
    fp = ForcePositionCoupling(K_fp=3000.0, B_fp=4.0, G_n=5.0, A_f=1e7, A_d=1e5, dt=1e-3, check=False)
    s_p, s = padded(FP_STATE)
    s[:] = fp.state
    for clutched in (False, True, False):
        fp_step(fp.params, fp.phi, fp.gamma, s, np.full(3, 1e-3), np.zeros(3), np.full(3, 1e-9), clutched,
                np.empty(3), np.empty(3))
    assert untouched(s_p, FP_STATE.size)
    safe = SafetyLayer(max_force=6.0, dt=1e-3)
    s_p, s = padded(SAFETY_STATE)
    s[:] = safe.state
    for k, f in enumerate((10.0, math.nan, 1.0)):
        safety_step(safe.params, s, np.array([f, 0.0, 0.0]), k * 1e-3, 0.0, 0, np.empty(3))
    assert untouched(s_p, SAFETY_STATE.size) and s[SAFETY_STATE.slice("counts")].sum() > 0
    pc = PassivityController(1e-3, 5.0)
    s_p, s = padded(PASSIVITY_STATE)
    s[:] = pc.state
    passivity_observe_control(pc.params, s, np.zeros(3), np.ones(3), np.ones(3))
    assert untouched(s_p, PASSIVITY_STATE.size)


def test_the_loop_struct_is_its_one_declaration():
    """The struct's fields are LOOP_FIELDS (with the model's MODEL_ARGS in it); the kernels read
    only declared fields; the model kernel is called with MODEL_ARGS in its own order."""
    assert list(lp.LOOP_FIELDS).count("out") == 1 and len(set(lp.LOOP_FIELDS)) == len(lp.LOOP_FIELDS)
    from numba import typeof

    from arsurf.haptics.device import TOUCH_X

    loop = lp.HapticLoop.direct(_model(), TOUCH_X, (70e-9, 70e-9, 25e-9))
    assert tuple(typeof(loop._packed).field_dict) == lp.LOOP_FIELDS
    src = inspect.getsource(lp)
    read = set(re.findall(r"\ba\.([a-z_]+)", src))
    assert read <= set(lp.LOOP_FIELDS), read - set(lp.LOOP_FIELDS)
    call = re.search(r"model_tick_kernel\((.*?)\)\n", inspect.getsource(lp._model_step), re.S).group(1)
    names = [w.strip()[2:] for w in call.split(",") if w.strip().startswith("a.")]
    assert names == list(MODEL_ARGS)
    per_tick = ("cx", "cy", "cz", "bending", "torsion", "signal_mode")
    params = [p for p in inspect.signature(model_tick_kernel.py_func).parameters if p not in per_tick]
    assert len(params) == len(MODEL_ARGS)


# the engine's kernel vectors: no module-level offsets counted by hand, no vector sized by a literal
_OFFSETS = re.compile(r"^_?[A-Z][A-Z0-9_]*(, _?[A-Z][A-Z0-9_]*)+ = (range\(|\d+, \d)", re.M)
_SIZED = re.compile(r"np\.(empty|zeros|full|ones)\((\d+)\b")
#: the packages and modules whose compiled kernels take vectors
_KERNELS = ("contact", "force", "haptics", "manipulation", "spline", "model.py")
#: literal-sized arrays there that are not vectors of named fields (file: the reason)
_NOT_LAYOUTS = {"spline/fit.py": "the five coefficients of one not-a-knot equation"}


def _engine_files():
    return sorted(ENGINE.rglob("*.py"))


def test_no_hand_counted_kernel_offsets_or_sizes():
    bad = []
    for path in _engine_files():
        rel = path.relative_to(ENGINE).as_posix()
        text = path.read_text()
        for m in _OFFSETS.finditer(text):
            line = text[m.start():text.index("\n", m.start())]
            values = line.split("=", 1)[1]
            if re.fullmatch(r"\s*range\(\d+\)\s*|\s*\d+(,\s*\d+)+\s*(#.*)?", values):
                bad.append(f"{rel}: {line.strip()}")
        if rel in _NOT_LAYOUTS or not rel.startswith(_KERNELS):
            continue
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.args \
                    and node.func.attr in ("empty", "zeros", "full", "ones") \
                    and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, int) \
                    and node.args[0].value > 3:
                bad.append(f"{rel}:{node.lineno}: np.{node.func.attr}({node.args[0].value})")
    # codes and counts, not offsets: an enumeration of modes, a protocol's or a vendor's constants,
    # a key's bounds, the sizes of a quadrature grid
    allowed = ("SIGNALS_NONE", "HD_CALLBACK", "HD_CALIBRATION", "TAG_", "SCANNED", "HEADER, TICKS", "_KEY_MIN",
               "_NQ, _NMU, _NR", "LAW_COMPRESSIVE")
    bad = [b for b in bad if not any(a in b for a in allowed)]
    assert not bad, "kernel vectors sized or indexed by hand (use arsurf._layout.Layout):\n" + "\n".join(bad)


def test_every_branch_and_status_code_comes_from_the_status_table():
    """The Maugis-Dugdale branches, the closest-point statuses and the push codes are
    arsurf.status's; no module defines its own."""
    from arsurf.contact.mechanics import Branch
    from arsurf.manipulation import nanotube

    assert [int(b) for b in Branch] == [status.CONTACT, status.COHESIVE, status.SEPARATED]
    assert [b.name.lower() for b in Branch] == list(status.BRANCH_NAMES)
    assert nanotube.PUSH_FALLBACK is status.PUSH_FALLBACK
    own = re.compile(r"^_?(MD_)?(CONTACT|COHESIVE|SEPARATED|STATUS_[A-Z_]+|PUSH_(OK|SUBSTEP_CAP|FALLBACK)) = -?\d", re.M)
    # the session file's marker of a status not recorded is a value of the file format, not a kernel's
    bad = [f"{p.relative_to(ENGINE)}: {m.group(0)}" for p in _engine_files() if p.name != "status.py"
           for m in own.finditer(p.read_text()) if not m.group(0).startswith("MD_STATUS_NOT_GIVEN")]
    assert not bad, bad
    assert not hasattr(cl, "STATUS_TEXT")  # one text table: arsurf.status.TEXT
