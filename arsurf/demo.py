"""``arsurf demo``: the whole system on a bundled scan, headless, in well under a minute.

A scripted operator (a :class:`~arsurf.haptics.virtual_device.HandModel` on a
:class:`~arsurf.haptics.virtual_device.VirtualDevice`) approaches a nanotube of the bundled
synthetic scan ``scans/nanotubes.npz``, indents it, slides across it and retracts, through the
full loop at 1 kHz: position scaling, Newton collision on the B-spline, Maugis-Dugdale with
approach/retract hysteresis, control-net dent, angular signals synthesised from the force through
the cantilever model (plus photodiode noise) and decoupled with the contact normal, blended with
the model force, low-pass filter, direct coupling, safety layer. The session is recorded
(HDF5), replayed offline, and the output folder receives:

``summary.json`` (peak forces, depth, contact radius, loop timing), ``session.h5``,
``replay/`` (forces.csv, replay.h5, plots), and PNG views of the dented surface
(``view_*.png``, when the viewer extra and an OpenGL context are available).
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from arsurf.contact.maugis_dugdale import MaugisDugdale
from arsurf.force.cantilever import Cantilever
from arsurf.haptics.loop import HapticLoop, LoopConfig
from arsurf.haptics.virtual_device import HandModel, VirtualDevice
from arsurf.model import M_NX, M_PX, M_RADIUS

BUNDLED_SCAN = Path(__file__).resolve().parents[1] / "scans" / "nanotubes.npz"
TIP_RADIUS = 20e-9
#: demo sample: a soft, adhesive film (E* = 10 GPa, w = 0.1 J/m^2: a polymer-like Maugis-Dugdale
#: contact with lambda ~ 0.5 that dents visibly) - see arsurf.contact.materials for real presets
EFFECTIVE_MODULUS = 10e9
WORK_OF_ADHESION = 0.1
#: a common rectangular silicon contact lever (450 x 50 x 2.5 um, 15 um tip; k ~ 0.2 N/m)
LEVER = dict(length=450e-6, width=50e-6, thickness=2.5e-6, tip_height=15e-6, youngs_modulus=169e9, poisson_ratio=0.27)
RATE = 1000.0
SCALE = 1e-5  # probe metres per stylus metre (1 mm -> 10 nm)
#: hand newtons per probe newton: the hand feels the contact stiffness (~2E*a ~ 200 N/m) as
#: FORCE_GAIN x 200 x SCALE = 200 N/m, passive with the 200 Hz filter; 1e6 made the stylus chatter
FORCE_GAIN = 1e5


def _tube_top(scan, surface):
    """(x, y) of the highest ridge point along the middle row, and the ridge's direction."""
    row = scan.heights[scan.shape[0] // 2]
    ix = int(np.argmax(row))
    return ix * scan.dx, (scan.shape[0] // 2) * scan.dy


def hand_trajectory(approach_from: float, indent: float, slide: float):
    """Stylus set points (device frame, m): hover, approach, indent, slide across, retract."""
    z_touch = -approach_from / SCALE
    z_in = -(approach_from + indent) / SCALE
    times = np.array([0.0, 0.3, 1.5, 2.3, 4.3, 5.0, 6.0])
    pts = np.array([
        [0.0, 0.0, 0.0],
        [0.0, 0.0, 0.0],
        [0.0, 0.0, z_touch],
        [0.0, 0.0, z_in],
        [slide / SCALE, 0.0, z_in],
        [slide / SCALE, 0.0, 0.6 * z_in],
        [slide / SCALE, 0.0, 0.0],
    ])
    return times, pts


def run_demo(out_dir, scan_path=BUNDLED_SCAN, seconds: float = 6.0, images: bool = True, progress=print) -> dict:
    """Run the demo into ``out_dir`` (created; an existing one is replaced); return the summary."""
    from arsurf.replay.replay import replay
    from arsurf.replay.session import SessionWriter, build_model, contact_fields, session_metadata

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    contact = MaugisDugdale(TIP_RADIUS, EFFECTIVE_MODULUS, WORK_OF_ADHESION)
    lever = Cantilever(**LEVER)
    meta = session_metadata(scan=scan_path, tip_radius=TIP_RADIUS, contact=contact, cantilever=lever, friction=0.2,
                            level="plane", sigma=2e-9, loop_rate=RATE,
                            haptics={"coupling": "direct", "scale": SCALE, "force_gain": FORCE_GAIN, "source": "blended",
                                     "filter_cutoff": 200.0, "signal_noise": 2e-7})
    setup = build_model(meta)  # the same construction replay uses: bit-identical re-runs
    scan, surface, model = setup.scan, setup.surface, setup.model
    progress(f"scan {scan_path} ({scan.shape[1]}x{scan.shape[0]} px) fitted: {surface.shape[0]}x{surface.shape[1]} "
             f"control points; Maugis lambda = {contact.maugis_parameter:.3f}")
    x0, y0 = _tube_top(scan, surface)
    x0 -= 80e-9  # start beside the tube, slide across it
    # hover 8 nm above the highest point the sphere could touch
    z_near = surface.evaluate(x0 + np.linspace(-1.5, 1.5, 31) * TIP_RADIUS, np.full(31, y0))[:, 2].max()
    origin = (x0, y0, z_near + TIP_RADIUS + 8e-9)
    dev = VirtualDevice(dt=1.0 / RATE, hand=HandModel(hand_trajectory(8e-9, 5e-9, 160e-9))).open()
    loop = HapticLoop.direct(model, dev.info, origin, scale=SCALE, force_gain=FORCE_GAIN,
                             config=LoopConfig(rate=RATE, source="blended", filter_cutoff=200.0, signal_noise=2e-7,
                                               seed=7), ramp_time=0.2)
    n = int(seconds * RATE)
    writer = SessionWriter(out / "session.h5", meta)
    compute = np.empty(n)
    views = {}
    marks = {"approach": int(1.2 * RATE), "indent": int(2.4 * RATE), "slide": int(3.6 * RATE), "retract": n - 1}
    clock = time.perf_counter_ns
    for k in range(n):
        st = dev.read_state()
        t0 = clock()
        f = loop.step(st, st.timestamp)
        compute[k] = clock() - t0
        dev.command_force(f)
        o, mo = loop.out, model.out
        writer.append(t=st.timestamp, stylus_position=st.position, stylus_velocity=st.velocity, buttons=st.buttons,
                      probe_position=o[0:3], probe_velocity=o[3:6], signals=o[6:8], force=o[8:11],
                      device_force=o[17:20], **contact_fields(model.record(mo)))
        for name, tick in marks.items():
            if k == tick:
                views[name] = _scene(model, loop, contact, RATE)
    writer.close()
    dev.close()
    progress(f"loop: {n} ticks at {RATE:.0f} Hz, tick compute median {np.median(compute) / 1e3:.1f} us, "
             f"p99 {np.percentile(compute, 99) / 1e3:.1f} us")
    result = replay(out / "session.h5", scan_path, out / "replay", overwrite=True, progress=False)
    progress(f"replay: {result.n_ticks} ticks, {result.contact_mismatches} contact mismatches, "
             f"files {', '.join(result.files)}")
    pngs = _render(views, out, progress) if images else []
    from arsurf.replay.session import load_session

    ticks = load_session(out / "session.h5").ticks
    force = ticks["force"]
    summary = {
        "scan": str(scan_path),
        "ticks": n,
        "rate_hz": RATE,
        "maugis_lambda": contact.maugis_parameter,
        "peak_probe_force_nN": float(np.linalg.norm(force, axis=1).max() * 1e9),
        "peak_normal_load_nN": float(np.nanmax(ticks["load"]) * 1e9),
        "min_load_nN (adhesion)": float(np.nanmin(ticks["load"]) * 1e9),
        "max_depth_nm": float(np.nanmax(ticks["depth"]) * 1e9),
        "max_contact_radius_nm": float(np.nanmax(ticks["contact_radius"]) * 1e9),
        "ticks_in_contact": int(ticks["in_contact"].sum()),
        "peak_device_force_N": float(np.linalg.norm(ticks["device_force"], axis=1).max()),
        "tick_compute_median_us": float(np.median(compute) / 1e3),
        "tick_compute_p99_us": float(np.percentile(compute, 99) / 1e3),
        "replay_contact_mismatches": int(result.contact_mismatches),
        "replay_max_load_difference_N": float(result.load_difference),
        "images": [p.name for p in pngs],
        "wall_time_s": time.perf_counter() - t_start,
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    return summary


def _scene(model, loop, contact, rate):
    """A snapshot for the viewer (copies: the live net keeps changing)."""
    o, mo = loop.out, model.out
    return dict(surface=model.surface.copy(), tip_center=o[0:3].copy(), tip_radius=model.tip_radius,
                contact_point=mo[M_PX:M_PX + 3].copy(), contact_normal=mo[M_NX:M_NX + 3].copy(),
                depth=float(mo[9]), contact_radius=float(mo[M_RADIUS]), force=o[8:11].copy(),
                maugis_lambda=contact.maugis_parameter, loop_rate_hz=rate, device_status="virtual device (demo)")


def _render(views: dict, out: Path, progress) -> list[Path]:
    try:
        from arsurf_viewer import SceneState, SurfaceView
    except ImportError as exc:
        progress(f"no PNG views: the viewer is not installed ({exc}); pip install 'arsurf[viewer]'")
        return []
    paths = []
    try:
        for name, kw in views.items():
            view = SurfaceView(kw["surface"], color_by="deformation" if name != "approach" else "height")
            view.update(SceneState(**kw))
            path = out / f"view_{name}.png"
            view.screenshot(path)
            view.close()
            paths.append(path)
    except Exception as exc:  # no OpenGL context: the numbers are still there
        progress(f"no PNG views: rendering failed ({type(exc).__name__}: {exc})")
    return paths


def register(sub) -> None:
    """Add ``arsurf demo`` to the CLI."""
    p = sub.add_parser("demo", help="run the full pipeline on a bundled scan, headless (the main job)")
    p.add_argument("--out", default="out/demo", help="output folder")
    p.add_argument("--scan", default=str(BUNDLED_SCAN), help="scan file (default: the bundled nanotubes)")
    p.add_argument("--seconds", type=float, default=6.0, help="simulated session length")
    p.add_argument("--no-images", action="store_true", help="skip the PNG views")
    p.set_defaults(func=_cmd)


def _cmd(args) -> int:
    summary = run_demo(args.out, args.scan, args.seconds, images=not args.no_images)
    print(json.dumps(summary, indent=2))
    print(f"results in {args.out}/")
    return 0
