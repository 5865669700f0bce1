"""``arsurf demo``: the whole system on a bundled scan, headless, in well under a minute.

1. **engage** (seed 001, Fig. 3.10) on the virtual AFM (:mod:`arsurf.instrument.engage`):
   the tip starts 5 um above the sample beside a nanotube of the bundled synthetic scan
   ``nanotubes.npz`` (package data, :mod:`arsurf.data`) and is brought into contact by nano/micro stage steps under a force
   limit; the surface height it finds sets where the haptic loop takes over (the tip is lifted
   to hover 8 nm above it);
2. **haptic session**: a scripted operator (a :class:`~arsurf.haptics.virtual_device.HandModel`
   on a :class:`~arsurf.haptics.virtual_device.VirtualDevice`) approaches the substrate, indents
   it, then slides sideways into the tube near one end and pushes that end about 50 nm, so that
   the tube turns about the corrected Eq. 9 pivot (about 0.29 L from the other end), then
   retracts - through the full loop at 1 kHz: position scaling, Newton collision on the
   B-spline of the substrate, Maugis-Dugdale with approach/retract hysteresis, control-net dent,
   angular signals synthesised from the force through the cantilever model (plus photodiode
   noise) and decoupled with the contact normal, blended with the model force, the tube scene
   (:mod:`arsurf.manipulation.scene`: the tube is an object, pushed every tick, its friction
   resistance added to the probe force), low-pass filter, direct coupling, safety layer;
3. the session (HDF5, with the tube poses of every tick) is **replayed** offline, which
   re-runs the scene and must give back the poses bit for bit.

The output folder receives ``summary.json`` (engage, peak forces, depth, contact radius, the
tube's displacement, rotation and rotation pole, loop timing, replay agreement),
``session.h5``, ``replay/`` (forces.csv, replay.h5, figures: forces, coupled_motion, path, tubes,
dent, as PNG, PDF or SVG, :mod:`arsurf.replay.plots`), and PNG views of the dented surface
with the tube where it is (``view_*.png``, when the viewer extra and an OpenGL context are
available). A scan without a synthetic tube record (``--scan``) runs the session without
a scene: approach, indent, a 160 nm slide along x and retract.
"""
from __future__ import annotations

import logging
import math
import time
from pathlib import Path

import numpy as np

from arsurf._files import write_text
from arsurf._logging import progress as progress_bar
from arsurf.assembly import BUNDLED_SCAN, PRESETS, build_loop, build_model, preset_metadata
from arsurf.haptics.virtual_device import HandModel, VirtualDevice
from arsurf.haptics.loop import LOOP_OUT
from arsurf.haptics.feel import score_force
from arsurf.model import M_IN_CONTACT, MODEL_OUT
from arsurf.sessions.writer import record_loop_tick
from arsurf.units import summary_json

log = logging.getLogger(__name__)

#: the demo's model and haptic settings (tip, sample, lever, scaling, filter): one named preset
DEMO = PRESETS["demo"]
TIP_RADIUS = DEMO.tip_radius
RATE = DEMO.haptics["rate"]
SCALE = DEMO.haptics["scale"]  # probe metres per stylus metre (1 mm -> 10 nm)
#: how far the scripted operator pushes the tube's end sideways (contact-point travel)
PUSH = 50e-9
#: the tip starts this far (centre to tube axis) beside the tube, and pushes this far from its end
PUSH_START_OFFSET = 60e-9
PUSH_END_MARGIN = 20e-9
#: engage (seed 001 Fig. 3.10): start height above the sample, set point (normalised signal
#: change: 0.05 x 1117 nm/V = 56 nm of lever deflection, 17 nN on the 0.3 N/m lever), force limit
ENGAGE_FROM = 5e-6
ENGAGE_SETPOINT = 0.05
ENGAGE_FORCE_LIMIT = 30e-9


def _tube_top(scan, surface):
    """(x, y) of the highest ridge point along the middle row (scans without a tube scene)."""
    row = scan.heights[scan.shape[0] // 2]
    ix = int(np.argmax(row))
    return ix * scan.dx, (scan.shape[0] // 2) * scan.dy


def hand_trajectory(approach_from: float, indent: float, slide: float, direction=(1.0, 0.0)):
    """Stylus set points (device frame, m): hover, approach, indent, slide ``slide`` metres (probe)
    along the unit ``direction`` (x, y), retract."""
    z_touch = -approach_from / SCALE
    z_in = -(approach_from + indent) / SCALE
    dx, dy = (slide / SCALE) * np.asarray(direction, dtype=np.float64)
    times = np.array([0.0, 0.3, 1.5, 2.3, 4.3, 5.0, 6.0])
    pts = np.array([
        [0.0, 0.0, 0.0],
        [0.0, 0.0, 0.0],
        [0.0, 0.0, z_touch],
        [0.0, 0.0, z_in],
        [dx, dy, z_in],
        [dx, dy, 0.6 * z_in],
        [dx, dy, 0.0],
    ])
    return times, pts


def plan_end_push(scene, scan, tip_radius: float):
    """Choose the tube end and side for a sideways push with the most room around it.

    For each tube, end and side, the tip starts :data:`PUSH_START_OFFSET` from the axis, beside
    the point :data:`PUSH_END_MARGIN` from the end, and moves along the tube normal until the
    contact point has travelled :data:`PUSH`. The score is the smallest distance from the tip's
    start and end and the pushed end's new position to the other tubes and to the scan border;
    the best candidate wins (deterministic).

    Returns
    -------
    dict: ``tube`` (index), ``end`` ("A"/"B"), ``contact`` (arc-length, m), ``start`` (x, y),
    ``direction`` (unit (x, y)), ``slide`` (m, tip travel), ``clearance`` (m).
    """
    from arsurf.manipulation.nanotube import _seg_dist

    w, h = (scan.shape[1] - 1) * scan.dx, (scan.shape[0] - 1) * scan.dy
    best = None
    for i, tube in enumerate(scene.initial):
        reach = tip_radius + tube.radius
        slide = PUSH_START_OFFSET - reach + PUSH
        u = tube.direction
        normal = np.array([-u[1], u[0]])
        for end, arc in (("A", PUSH_END_MARGIN), ("B", tube.length - PUSH_END_MARGIN)):
            c = tube.point_at(arc)[:2]
            tip_end = tube.endpoints[0 if end == "A" else 1][:2]
            for side in (1.0, -1.0):
                n = side * normal
                start = c - PUSH_START_OFFSET * n
                pts = (start, start + slide * n, tip_end + PUSH * n)
                room = min(min(p[0], w - p[0], p[1], h - p[1]) for p in pts)
                for j, other in enumerate(scene.initial):
                    if j == i:
                        continue
                    a = other.endpoints[0]
                    for p in pts:
                        d = _seg_dist(p[0], p[1], a[0], a[1], other.direction[0], other.direction[1],
                                      other.length)[3]
                        room = min(room, d - other.radius - tip_radius)
                if best is None or room > best["clearance"]:
                    best = {"tube": i, "end": end, "contact": arc, "start": start, "direction": n, "slide": slide,
                            "clearance": room}
    return best


def engage_at(scan, x: float, y: float, seed: int = 5):
    r"""Engage the virtual AFM (seed 001 Fig. 3.10) from :data:`ENGAGE_FROM` above ``scan`` at (x, y).

    Returns ``(EngageResult, surface_found)``: the surface height the engage found (metres, scan
    frame) from the stage positions and the deflection read on the photodiode,
    :math:`z = h_{probe} - z_{pico} - z_{micro} - z_{nano} + |S_n| \Delta V`.
    """
    from arsurf.instrument.engage import engage
    from arsurf.instrument.instrument import VirtualAFM

    z0 = VirtualAFM(scan, probe_height=0.0, tip_xy=(x, y)).surface_height
    afm = VirtualAFM(scan, probe_height=z0 + ENGAGE_FROM, tip_xy=(x, y), seed=seed)
    result = engage(afm, setpoint=ENGAGE_SETPOINT, force_limit=ENGAGE_FORCE_LIMIT)
    pos = afm.position
    found = (afm.probe_height - pos["pico"] - pos["micro"] - pos["nano"]
             + abs(afm.deflection_sensitivity) * result.signal)
    return result, found


def run_demo(out_dir, scan_path=BUNDLED_SCAN, seconds: float = 6.0, images: bool = True, progress=None,
             handle_signals: bool = False, figure_format: str = "png", dpi: int | None = None) -> dict:
    """Run the demo into ``out_dir`` (created; an existing one is replaced); return the summary.

    ``progress`` (a callable taking one line) receives the progress messages; by default they
    are logged (INFO) to ``arsurf.demo``. With ``images``, PNG views need the viewer extra
    (without it a warning says so and the demo goes on) and an OpenGL context (without one,
    :class:`~arsurf.errors.RenderingUnavailable` says what to install, before the session runs).
    ``handle_signals`` (the command line): SIGINT/SIGTERM during the session close
    ``session.h5`` with every tick recorded so far (marked incomplete) before the demo stops.
    ``figure_format`` (png, pdf, svg) and ``dpi`` (PNG) are those of the replay's figures
    (:mod:`arsurf.replay.plots`).
    """
    from arsurf.errors import ManipulationError
    from arsurf.manipulation.scene import TubeScene
    from arsurf.replay.replay import replay
    from arsurf.sessions.journal import journal_path
    from arsurf.sessions.writer import SessionWriter
    from arsurf.scan.prepare import prepare_scan

    from arsurf.replay.plots import check_figure_options

    progress = progress or log.info
    dpi = check_figure_options(figure_format, dpi)
    viewer = _viewer_or_none() if images else None  # no OpenGL: said now, not after the session
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    prepared = prepare_scan(scan_path, None, DEMO.level, DEMO.sigma, True)  # the scan the instrument and the tubes see
    try:
        tubes = TubeScene.from_scan(prepared).to_metadata()
    except ManipulationError:
        tubes = None  # not a synthetic nanotubes scan: a session without a scene
    meta = preset_metadata(scan_path, DEMO, **({"tubes": tubes} if tubes is not None else {}))
    setup = build_model(meta)  # the same construction replay uses: bit-identical re-runs
    scan, surface, model, scene = setup.scan, setup.surface, setup.model, setup.scene
    contact = model.contact
    progress(f"scan {scan_path} ({scan.shape[1]}x{scan.shape[0]} px) fitted: {surface.shape[0]}x{surface.shape[1]} "
             f"control points; Maugis lambda = {contact.maugis_parameter:.3f}"
             + (f"; {len(scene)} tubes are scene objects (the spline holds the substrate)" if scene else ""))
    if scene is not None:
        plan = plan_end_push(scene, scan, TIP_RADIUS)
        (x0, y0), direction, slide = plan["start"], plan["direction"], plan["slide"]
    else:
        plan = None
        x0, y0 = _tube_top(scan, surface)
        x0 -= 80e-9  # start beside the ridge, slide across it
        direction, slide = (1.0, 0.0), 160e-9
    # engage from 5 um above, then hand over: hover 8 nm above the surface the engage found
    t_engage = time.perf_counter()
    eng, z_found = engage_at(prepared, x0, y0)
    t_engage = time.perf_counter() - t_engage
    z_spline = float(surface.evaluate(x0, y0)[2])
    progress(f"engage from {ENGAGE_FROM * 1e6:.0f} um: {eng.reason} after {eng.coarse_steps} micro and "
             f"{eng.fine_steps} nano steps ({eng.duration:.2f} s simulated, {t_engage:.2f} s wall), max force "
             f"{eng.max_force * 1e9:.1f} nN; surface found {(z_found - z_spline) * 1e9:+.2f} nm from the model")
    # hover 8 nm above the found surface, or above the highest point the sphere could touch when
    # that is higher (a step beside the engage point, which a point measurement cannot see)
    z_strip = surface.evaluate(x0 + np.linspace(-1.5, 1.5, 31) * TIP_RADIUS, np.full(31, y0))[:, 2].max()
    z_hover = max(z_found, z_strip) if eng.engaged else z_strip
    origin = (x0, y0, z_hover + TIP_RADIUS + 8e-9)
    dev = VirtualDevice(dt=1.0 / RATE, hand=HandModel(hand_trajectory(8e-9, 5e-9, slide, direction))).open()
    loop = build_loop(model, meta["haptics"], dev.info, origin, scene=scene, seed=7, ramp_time=0.2)
    n = int(seconds * RATE)
    journal_path(out / "session.h5").unlink(missing_ok=True)  # a killed earlier run's: replaced like the rest
    # the loop runs in simulated time, faster than real time: wait for the disk rather than drop ticks
    writer = SessionWriter(out / "session.h5", meta, when_full="wait", handle_signals=handle_signals)
    compute = np.empty(n)
    device_force = np.empty((n, 3))
    energy = np.empty(n)
    damping = np.empty(n)
    in_contact = np.empty(n, bool)
    views = {}
    marks = {"approach": int(1.2 * RATE), "indent": int(2.4 * RATE), "slide": int(3.6 * RATE), "retract": n - 1}
    tube_force = np.zeros(n)
    with writer:  # an exception or a signal still closes the file (incomplete) with every tick
        for k in progress_bar(range(n), desc="session", unit="tick"):
            st, f, compute[k] = _session_tick(dev, loop, model, writer, scene)
            o, mo = loop.out, model.out
            device_force[k] = f
            energy[k] = LOOP_OUT.get(o, "energy")
            damping[k] = LOOP_OUT.get(o, "passivity_damping")
            in_contact[k] = mo[M_IN_CONTACT] > 0.5
            if scene is not None:
                tube_force[k] = math.hypot(scene.force[0], scene.force[1])
            for name, tick in marks.items():
                if k == tick:
                    views[name] = _scene(model, loop, contact, RATE, scene)
    dev.close()
    progress(f"loop: {n} ticks at {RATE:.0f} Hz, tick compute median {np.median(compute) / 1e3:.1f} us, "
             f"p99 {np.percentile(compute, 99) / 1e3:.1f} us")
    feel = score_force(device_force, 1.0 / RATE, settle=marks["approach"] / RATE, energy=energy, contact=in_contact,
                       energy_reserve=loop.passivity.reserve)
    progress(feel.summary() + (" - the hand felt a buzz: see the feel scores in summary.json" if feel.buzzes else ""))
    tube_summary = None
    if scene is not None:
        i = plan["tube"]
        motion = scene.motion(i)
        L = scene.initial[i].length
        from arsurf.manipulation.nanotube import rotation_centre

        e = 0 if plan["end"] == "A" else 1
        end_move = float(np.hypot(*(scene.tubes[i].endpoints[e, :2] - scene.initial[i].endpoints[e, :2])))
        tube_summary = {  # SI, the unit in each key (arsurf.units)
            "pushed_tube_index": i, "end": plan["end"], "length_m": L,
            "displacement_m": motion.displacement, "end_displacement_m": end_move,
            "rotation_rad": motion.rotation,
            "pole_arc_fraction": motion.pole_arc_length / L,
            "eq9_pivot_arc_fraction": float(rotation_centre(plan["contact"], L)) / L,  # at the first contact
            "pole_offset_m": motion.pole_offset,
            "ticks_pushing": int(np.count_nonzero(tube_force)),
            "peak_tube_force_N": float(tube_force.max()),
            "median_tube_force_while_pushing_N": float(np.median(tube_force[tube_force > 0]))
            if tube_force.any() else 0.0,
            "other_moved_tube_indices": [j for j in range(len(scene))
                                         if j != i and scene.motion(j).displacement > 0.0],
        }
        progress(f"tube {i}: pushed at end {plan['end']} (which moved {end_move * 1e9:.1f} nm), centre moved "
                 f"{motion.displacement * 1e9:.1f} nm, turned "
                 f"{math.degrees(motion.rotation):+.2f} deg about the point {motion.pole_arc_length / L:.3f} L "
                 f"from end A (Eq. 9 pivot {tube_summary['eq9_pivot_arc_fraction']:.3f} L)")
    result = replay(out / "session.h5", scan_path, out / "replay", overwrite=True, figure_format=figure_format,
                    dpi=dpi)
    progress(f"replay: {result.n_ticks} ticks, {result.contact_mismatches} contact mismatches"
             + (f", tube poses differ by {result.tube_pose_difference:g}" if scene is not None else "")
             + f", files {', '.join(result.files)}")
    pngs = _render(viewer, views, out) if viewer is not None else []
    from arsurf.sessions.reader import load_session

    ticks = load_session(out / "session.h5").ticks
    force = ticks["force"]
    summary = {  # SI, the unit in each key (arsurf.units)
        "scan": str(scan_path),
        "n_ticks": n,
        "rate_Hz": RATE,
        "maugis_lambda": contact.maugis_parameter,
        "engage": {
            "engaged": bool(eng.engaged), "reason": eng.reason, "from_height_m": ENGAGE_FROM,
            "micro_steps": int(eng.coarse_steps), "nano_steps": int(eng.fine_steps),
            "simulated_time_s": eng.duration, "max_force_N": eng.max_force,
            "force_limit_N": ENGAGE_FORCE_LIMIT, "surface_found_minus_model_m": z_found - z_spline,
            "hover_reference": "engage" if z_hover == z_found else "model (higher point within the tip's reach)",
            "wall_time_s": t_engage,
        },
        "peak_probe_force_N": float(np.linalg.norm(force, axis=1).max()),
        "peak_normal_load_N": float(np.nanmax(ticks["load"])),
        "min_load_N": float(np.nanmin(ticks["load"])),  # < 0: adhesion held the tip
        "max_depth_m": float(np.nanmax(ticks["depth"])),
        "max_contact_radius_m": float(np.nanmax(ticks["contact_radius"])),
        "ticks_in_contact": int(ticks["in_contact"].sum()),
        "peak_device_force_N": float(np.linalg.norm(ticks["device_force"], axis=1).max()),
        "feel": feel.as_dict(),
        "passivity_controller_ticks": int(np.count_nonzero(damping)),
        "tick_compute_median_s": float(np.median(compute) / 1e9),
        "tick_compute_p99_s": float(np.percentile(compute, 99) / 1e9),
        "replay_contact_mismatches": int(result.contact_mismatches),
        "replay_max_load_difference_N": float(result.load_difference),
        "images": [p.name for p in pngs],
        "wall_time_s": time.perf_counter() - t_start,
    }
    if tube_summary is not None:
        diff = result.tube_poses - ticks["tube_poses"]
        tube_summary["replay_position_difference_m"] = float(np.abs(diff[..., :2]).max())
        tube_summary["replay_angle_difference_rad"] = float(np.abs(diff[..., 2]).max())
        summary["tube"] = tube_summary
    write_text(out / "summary.json", summary_json(summary), what="demo summary")
    return summary


def _session_tick(dev, loop, model, writer, scene=None):
    """One tick of a scripted session: read the device, step the loop, command the force, record
    the tick (stylus, probe, tip, energy, signals, forces, contact, and the tube poses after this
    tick's push); ``(state, force, compute ns)``."""
    st = dev.read_state()
    t0 = time.perf_counter_ns()
    f = loop.step(st, st.timestamp)
    compute = time.perf_counter_ns() - t0
    dev.command_force(f)
    record_loop_tick(writer, loop, st.timestamp, st)
    return st, f, compute


def _scene(model, loop, contact, rate, scene=None):
    """A snapshot for the viewer (copies: the live net keeps changing, so do the tube poses)."""
    o, m = LOOP_OUT.record(loop.out), MODEL_OUT.record(model.out)
    return dict(surface=model.surface.copy(), tip_center=o["probe"], tip_radius=model.tip_radius,
                contact_point=m["point"], contact_normal=m["normal"],
                depth=m["depth"], contact_radius=m["contact_radius"], force=o["probe_force"],
                maugis_lambda=contact.maugis_parameter, loop_rate_hz=rate, device_status="virtual device (demo)",
                tubes=scene.viewer_tubes() if scene is not None else ())


def _viewer_or_none():
    """The viewer with a rendering backend chosen; None (and a warning) when the extra is not installed.

    Raises :class:`~arsurf.errors.RenderingUnavailable` (what to install) when nothing can render.
    """
    try:
        import arsurf_viewer
    except ImportError as exc:
        log.warning("no PNG views: the viewer is not installed (%s); pip install 'arsurf[viewer]', or --no-images", exc)
        return None
    arsurf_viewer.choose_backend()
    return arsurf_viewer


def _render(viewer, views: dict, out: Path) -> list[Path]:
    from arsurf.errors import rendering_failed

    SceneState, SurfaceView = viewer.SceneState, viewer.SurfaceView
    paths = []
    try:
        for name, kw in progress_bar(views.items(), desc="views", unit="view"):
            view = SurfaceView(kw["surface"])  # coloured by height, the dent as contour lines over it
            view.update(SceneState(**kw))
            path = out / f"view_{name}.png"
            view.screenshot(path)
            view.close()
            paths.append(path)
            if name == "indent":  # the dent itself: ~8 tip radii of field, surface sampled at ~1 nm
                view = SurfaceView(kw["surface"], resolution=1024)
                view.update(SceneState(**kw))
                view.close_up(kw["tip_center"], 8 * kw["tip_radius"])
                path = out / "view_indent_closeup.png"
                view.screenshot(path)
                view.close()
                paths.append(path)
    except Exception as exc:  # no OpenGL context after all: the numbers are written, the views asked for are not
        raise rendering_failed(f"demo views (the numbers are in {out}; --no-images skips the views)", exc) from exc
    return paths


def register(sub) -> None:
    """Add ``arsurf demo`` to the CLI."""
    from arsurf.contact.material_conversion import MaterialConversion

    p = sub.add_parser("demo", help="run the full pipeline on a bundled scan, headless (the main job); --material "
                       "FILE: feel a PeakForce QNM file's soft, stiff and sticky regions")
    p.add_argument("--out", default="out/demo", help="output folder")
    p.add_argument("--scan", default=str(BUNDLED_SCAN), help="scan file (default: the bundled nanotubes)")
    p.add_argument("--seconds", type=float, default=6.0, help="simulated session length")
    p.add_argument("--no-images", action="store_true", help="skip the PNG views")
    from arsurf.replay.plots import add_figure_arguments

    add_figure_arguments(p)
    p.add_argument("--material", metavar="FILE", help="run the material demo on this file's mechanical channels "
                   "(DMTModulus, Adhesion...; uncalibrated channels need the conversion flags below)")
    MaterialConversion.cli_arguments(p, tip_radius_nm=TIP_RADIUS * 1e9)
    p.add_argument("--material-sigma-nm", type=float, default=None, metavar="NM",
                   help="Gaussian smoothing of the material map, nm (default: half the tip radius)")
    p.set_defaults(func=_cmd)


def _cmd(args) -> int:
    if args.material is not None:
        from arsurf.contact.material_conversion import MaterialConversion

        summary = run_material_demo(args.out, args.material, MaterialConversion.from_cli(args),
                                    MaterialConversion.cli_channels(args), images=not args.no_images,
                                    handle_signals=True,
                                    sigma=None if args.material_sigma_nm is None else args.material_sigma_nm * 1e-9)
    else:
        summary = run_demo(args.out, args.scan, args.seconds, images=not args.no_images, handle_signals=True,
                           figure_format=args.figure_format, dpi=args.dpi)
    print(summary_json(summary), end="")
    print(f"results in {args.out}/")
    return 0


# ---------------------------------------------------------------------------------------------
# arsurf demo --material: feel a sample's harder and stickier regions


#: the material demo's scripted press: the stylus takes the probe this far past the touch (m)
MATERIAL_PRESS = 4e-9
#: and the tip hovers this far above the surface between presses (m)
MATERIAL_HOVER = 8e-9


def pick_spots(material, scan, tip_radius: float) -> dict:
    """Where to press: the softest and the stiffest decile of E*, and the stickiest of w.

    The log of each field is smoothed over the tip radius (a contact averages it), pixels more
    than 4 R from the border and with a slope under 15 deg (after the same smoothing) are kept,
    and the extreme of the smoothed field is taken among the pixels of the decile itself: the
    spot lies in the decile *and* in a region of it the tip can feel. The stickiest spot is kept
    6 R away from the other two. Returns ``{"soft", "stiff", "sticky"}`` -> (x, y) in metres.
    """
    from scipy.ndimage import gaussian_filter

    e = material.fields["reduced_modulus"].pixels
    w = material.fields["work_of_adhesion"].pixels
    sx, sy = material.spacing
    sig = (tip_radius / sy, tip_radius / sx)
    le, lw = gaussian_filter(np.log(e), sig), gaussian_filter(np.log(w), sig)
    z = gaussian_filter(np.asarray(scan.heights, dtype=np.float64), (tip_radius / scan.dy, tip_radius / scan.dx))
    gy, gx = np.gradient(z, scan.dy, scan.dx)
    ny, nx = e.shape
    iy, ix = np.mgrid[0:ny, 0:nx]
    x0, y0 = material.offset
    xx, yy = x0 + ix * sx, y0 + iy * sy
    mx, my = 4 * tip_radius, 4 * tip_radius
    ok = ((xx >= mx) & (xx <= (scan.shape[1] - 1) * scan.dx - mx) & (yy >= my)
          & (yy <= (scan.shape[0] - 1) * scan.dy - my))
    hy, hx = scan.shape
    jy = np.clip(np.rint(yy / scan.dy).astype(int), 0, hy - 1)
    jx = np.clip(np.rint(xx / scan.dx).astype(int), 0, hx - 1)
    ok &= np.hypot(gx, gy)[jy, jx] < math.tan(math.radians(15.0))
    lo_e, hi_e = np.percentile(e, [10.0, 90.0])
    hi_w = np.percentile(w, 90.0)

    def best(mask, field, sign):
        cand = np.flatnonzero(ok & mask)
        if cand.size == 0:
            raise ValueError("no candidate")
        k = cand[np.argmax(sign * field.ravel()[cand])]
        return float(xx.ravel()[k]), float(yy.ravel()[k])

    spots = {"soft": best(e <= lo_e, le, -1.0), "stiff": best(e >= hi_e, le, 1.0)}
    far = np.ones_like(ok)
    for (px, py) in spots.values():
        far &= np.hypot(xx - px, yy - py) > 6 * tip_radius
    spots["sticky"] = best((w >= hi_w) & far, lw, 1.0)
    return spots


def _press_tour(surface, spots: dict, tip_radius: float, origin):
    """Stylus set points (device frame, m) and the time window of each press: hover, approach,
    press :data:`MATERIAL_PRESS` past the touch, hold, retract, move over to the next spot."""
    times, pts, windows = [0.0], [np.zeros(3)], {}
    t = 0.0

    def probe_to_device(p):
        return (np.asarray(p) - origin) / SCALE

    def z_touch(x, y):
        return float(surface.evaluate(x, y)[2]) + tip_radius

    prev = None
    for name, (x, y) in spots.items():
        zt = z_touch(x, y)
        if prev is not None:  # over to the next spot, above everything in between
            line = np.linspace(0.0, 1.0, 64)
            px, py = prev[0] + line * (x - prev[0]), prev[1] + line * (y - prev[1])
            top = float(surface.evaluate(px, py)[:, 2].max()) + tip_radius + MATERIAL_HOVER
            for p, dt in (((prev[0], prev[1], top), 0.3), ((x, y, top), 0.8)):
                t += dt
                times.append(t)
                pts.append(probe_to_device(p))
        start = t
        for p, dt in (((x, y, zt + MATERIAL_HOVER), 0.3), ((x, y, zt), 0.5), ((x, y, zt - MATERIAL_PRESS), 0.6),
                      ((x, y, zt - MATERIAL_PRESS), 0.25), ((x, y, zt + MATERIAL_HOVER), 0.9)):
            t += dt
            times.append(t)
            pts.append(probe_to_device(p))
        windows[name] = (start, t)
        prev = (x, y, zt + MATERIAL_HOVER)
    times.append(t + 0.3)
    pts.append(pts[-1])
    return np.array(times), np.array(pts), windows


def press_measures(t, depth, load, in_contact, windows: dict, reference=("soft", "stiff")) -> dict:
    """Per press: the peak load, the indentation at the reference load on the way in (first
    crossing in contact, interpolated; NaN if the press never reached it), and the pull-off (the
    most tensile load, retracting). The reference load is half the smaller peak load of the
    ``reference`` presses (NaN when one of them never became compressive)."""
    peaks = {k: float(np.nanmax(np.where((t >= a) & (t <= b), load, np.nan))) for k, (a, b) in windows.items()}
    low = min(peaks[k] for k in reference)
    ref = 0.5 * low if low > 0.0 else math.nan
    out = {"reference_load": ref}
    for k, (a, b) in windows.items():
        sel = np.flatnonzero((t >= a) & (t <= b))
        ld, dp, on = load[sel], depth[sel], in_contact[sel] > 0
        top = int(np.nanargmax(ld))
        up = np.flatnonzero(on[:top + 1] & (ld[:top + 1] >= ref))
        ind = math.nan
        if up.size:
            i = int(up[0])
            ind = float(dp[i])
            if i > 0 and on[i - 1] and ld[i - 1] < ref:
                ind = float(dp[i - 1] + (ref - ld[i - 1]) / (ld[i] - ld[i - 1]) * (dp[i] - dp[i - 1]))
        out[k] = {"peak_load": peaks[k], "indentation_at_reference_load": ind,
                  "pull_off": float(np.nanmin(ld[top:]))}
    return out


def run_material_demo(out_dir, scan_path, conversion, channels=None, images: bool = True, progress=None,
                      handle_signals: bool = False, sigma: float | None = None, units=None) -> dict:
    """``arsurf demo --material``: the haptic loop on a PeakForce QNM file, pressing where the
    sample is softest, stiffest and stickiest; the hand feels the difference.

    The model is the demo's (lever, haptic settings, virtual coupling) with the tip radius of
    ``conversion`` and the material map of the file's mechanical channels
    (:mod:`arsurf.contact.material_map`; ``channels`` role -> name overrides the QNM names),
    smoothed over ``sigma`` (default half the tip radius: a contact feels the sample averaged
    over its area, not one pixel's fit, which on a QNM image scatters by a decade from pixel to
    pixel); ``units`` (role -> unit) for a file that does not state its channels' units. The
    scripted hand (:func:`_press_tour`) presses the same stylus stroke at the three spots of
    :func:`pick_spots`; the session is recorded with the map and replayed (which rebuilds the
    map and must give back every contact). ``summary.json`` compares, per spot, the local E* and
    w, the peak load the hand felt, the indentation at one reference load and the pull-off with
    the Maugis-Dugdale predictions of the local law; PNG views colour the surface by modulus and
    adhesion.
    """
    from arsurf.contact.material_map import material_map_from_file
    from arsurf.contact.maugis_dugdale import MaugisDugdale
    from arsurf.replay.replay import replay
    from arsurf.sessions.journal import journal_path
    from arsurf.sessions.reader import load_session
    from arsurf.sessions.writer import SessionWriter
    from arsurf.scan.prepare import prepare_scan

    progress = progress or log.info
    viewer = _viewer_or_none() if images else None
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    R = conversion.tip_radius
    prepared = prepare_scan(scan_path, None, DEMO.level, DEMO.sigma, True)
    sigma = 0.5 * R if sigma is None else float(sigma)
    material = material_map_from_file(scan_path, conversion, height=prepared, channels=channels, sigma=sigma,
                                      units=units)
    st = material.statistics
    progress(f"material map of {scan_path}: {', '.join(f'{k} <- {v}' for k, v in material.channels.items())}; "
             f"E* median {st['reduced_modulus']['median'] / 1e9:.3g} GPa (5-95 % "
             f"{st['reduced_modulus']['p5'] / 1e9:.3g}..{st['reduced_modulus']['p95'] / 1e9:.3g}), w median "
             f"{st['work_of_adhesion']['median'] * 1e3:.3g} mJ/m^2 (5-95 % {st['work_of_adhesion']['p5'] * 1e3:.3g}.."
             f"{st['work_of_adhesion']['p95'] * 1e3:.3g}); masked {100 * material.masked['modulus']['masked']:.2f} % "
             f"(modulus), {100 * material.masked['adhesion']['masked']:.2f} % (adhesion); "
             f"{100 * material.masked['adhesion']['floored']:.1f} % of the pull-offs below the noise floor "
             f"{material.masked['adhesion']['floor_N'] * 1e9:.3g} nN")
    law = material.contact_law()
    meta = preset_metadata(scan_path, DEMO, tip_radius=R, material=material,
                           contact={"effective_modulus": law.effective_modulus, "work_of_adhesion": law.work_of_adhesion,
                                    "dugdale_stress": law.dugdale_stress})
    setup = build_model(meta)  # rebuilds the map from the file and checks its hash: what replay does
    scan, surface, model = setup.scan, setup.surface, setup.model
    spots = pick_spots(model.material, scan, R)
    local = {}
    for k, (x, y) in spots.items():
        e, w = float(model.material.reduced_modulus(x, y)), float(model.material.work_of_adhesion(x, y))
        local[k] = (e, w, MaugisDugdale(R, e, w, w / conversion.dugdale_range))
    progress("spots: " + "; ".join(f"{k} at ({x * 1e9:.1f}, {y * 1e9:.1f}) nm: E* {local[k][0] / 1e9:.3g} GPa, "
                                   f"w {local[k][1] * 1e3:.3g} mJ/m^2, lambda {local[k][2].maugis_parameter:.3g}"
                                   for k, (x, y) in spots.items()))
    first = next(iter(spots.values()))
    origin = np.array([first[0], first[1], float(surface.evaluate(*first)[2]) + R + MATERIAL_HOVER])
    times, pts, windows = _press_tour(surface, spots, R, origin)
    dev = VirtualDevice(dt=1.0 / RATE, hand=HandModel((times, pts))).open()
    loop = build_loop(model, meta["haptics"], dev.info, origin, seed=7, ramp_time=0.2)
    n = int(math.ceil(times[-1] * RATE))
    journal_path(out / "session.h5").unlink(missing_ok=True)
    writer = SessionWriter(out / "session.h5", meta, when_full="wait", handle_signals=handle_signals)
    compute = np.empty(n)
    hand = np.empty(n)
    views = {}
    with writer:
        for k in progress_bar(range(n), desc="session", unit="tick"):
            s, f, compute[k] = _session_tick(dev, loop, model, writer)
            hand[k] = float(np.linalg.norm(f))
            for name, (a, b) in windows.items():
                if name in ("soft", "stiff") and abs(s.timestamp - (a + 1.5)) < 0.5 / RATE:
                    views[name] = _scene(model, loop, model.contact, RATE)
    dev.close()
    ticks = load_session(out / "session.h5").ticks
    meas = press_measures(ticks["t"], ticks["depth"], ticks["load"], ticks["in_contact"], windows)
    ref = meas["reference_load"]
    spots_out = {}
    for k, (x, y) in spots.items():
        e, w, md = local[k]
        sel = (ticks["t"] >= windows[k][0]) & (ticks["t"] <= windows[k][1])
        spots_out[k] = {  # SI, the unit in every key
            "x_m": x, "y_m": y, "E_star_Pa": e, "w_J_per_m2": w,
            "maugis_lambda": md.maugis_parameter, "peak_load_N": meas[k]["peak_load"],
            "peak_hand_force_N": float(hand[sel[:n]].max()),
            "indentation_at_reference_load_m": meas[k]["indentation_at_reference_load"],
            "md_indentation_at_reference_load_m": float(md.depth(ref)) if math.isfinite(ref) else math.nan,
            "pull_off_N": meas[k]["pull_off"],
            "md_pull_off_load_control_N": md.pull_off_force(),
            "md_jump_out_load_displacement_control_N": md.critical_points().jump_out_load,
        }
    for k, v in spots_out.items():
        progress(f"{k:6s}: peak load {v['peak_load_N'] * 1e9:8.2f} nN (hand {v['peak_hand_force_N']:.3g} N), "
                 f"indentation at {ref * 1e9:.2f} nN {v['indentation_at_reference_load_m'] * 1e9:.3f} nm (MD "
                 f"{v['md_indentation_at_reference_load_m'] * 1e9:.3f}), pull-off {v['pull_off_N'] * 1e9:.2f} nN (MD "
                 f"{v['md_jump_out_load_displacement_control_N'] * 1e9:.2f} at jump-out, "
                 f"{v['md_pull_off_load_control_N'] * 1e9:.2f} under load control)")
    result = replay(out / "session.h5", scan_path, out / "replay", overwrite=True)
    progress(f"replay: {result.n_ticks} ticks, {result.contact_mismatches} contact mismatches (the map rebuilt, "
             f"hash {model.material.sha256[:12]}...)")
    pngs = _render_material(viewer, views, model.material, out) if viewer is not None else []
    s_, h_ = spots_out["soft"], spots_out["stiff"]
    summary = {  # SI, the unit in every key (arsurf.units)
        "scan": str(scan_path), "n_ticks": n, "rate_Hz": RATE, "tip_radius_m": R,
        "material": material.summary(), "reference_load_N": ref, "spots": spots_out,
        "passivity_reserve_probe_J": model.adhesion_energy(),   # the map's deepest well (at the probe)
        "reference_law_adhesion_energy_J": model.adhesion_energy(with_map=False),   # the median law's alone
        "soft_over_stiff_indentation": s_["indentation_at_reference_load_m"] / h_["indentation_at_reference_load_m"],
        "stiff_over_soft_peak_load": h_["peak_load_N"] / s_["peak_load_N"] if s_["peak_load_N"] > 0 else math.inf,
        "sticky_over_soft_pull_off": spots_out["sticky"]["pull_off_N"] / s_["pull_off_N"],
        "tick_compute_median_s": float(np.median(compute) / 1e9),
        "tick_compute_p99_s": float(np.percentile(compute, 99) / 1e9),
        "replay_contact_mismatches": int(result.contact_mismatches),
        "images": [p.name for p in pngs], "wall_time_s": time.perf_counter() - t_start,
    }
    write_text(out / "summary.json", summary_json(summary), what="demo summary")
    return summary


def _render_material(viewer, views: dict, material, out: Path) -> list[Path]:
    """The scan coloured by modulus and by adhesion (top view, the tip pressing at the soft and the
    stiff spot), and a close-up of the soft press."""
    from arsurf.errors import rendering_failed

    SceneState, SurfaceView = viewer.SceneState, viewer.SurfaceView
    paths = []
    try:
        for name, mode, camera in (("soft", "modulus", "top"), ("stiff", "adhesion", "top"), ("soft", "modulus", None)):
            if name not in views:
                continue
            kw = views[name]
            view = SurfaceView(kw["surface"], material=material, color_by=mode, resolution=512,
                               camera=camera or "oblique")
            view.update(SceneState(**kw))
            if camera is None:
                view.close_up(kw["tip_center"], 10 * kw["tip_radius"])
            path = out / (f"view_{mode}.png" if camera else f"view_{name}_press_closeup.png")
            view.screenshot(path)
            view.close()
            paths.append(path)
    except Exception as exc:
        raise rendering_failed(f"material demo views (the numbers are in {out}; --no-images skips the views)",
                               exc) from exc
    return paths
