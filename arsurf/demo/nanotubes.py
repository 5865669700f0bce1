"""``arsurf demo``: the whole system on a bundled scan, headless, in well under a minute.

1. **engage** ([Alabdulmuhsin], Fig. 3.10) on the virtual AFM (:mod:`arsurf.instrument.engage`):
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
from arsurf.assembly import BUNDLED_SCAN, build_loop, build_model, loop_metadata, preset_metadata
from arsurf.config import DeviceConfig
from arsurf.demo.scripted import DEMO, RATE, SCALE, TIP_RADIUS, scene_snapshot, session_tick, viewer_or_none
from arsurf.haptics.loop import LOOP_OUT
from arsurf.haptics.virtual_device import HandModel, VirtualDevice
from arsurf.units import summary_json

log = logging.getLogger("arsurf.demo")

__all__ = ["run_demo", "engage_at", "hand_trajectory", "plan_end_push"]

#: how far the scripted operator pushes the tube's end sideways (contact-point travel)
PUSH = 50e-9
#: the tip starts this far (centre to tube axis) beside the tube, and pushes this far from its end
PUSH_START_OFFSET = 60e-9
PUSH_END_MARGIN = 20e-9
#: engage ([Alabdulmuhsin] Fig. 3.10): start height above the sample, set point (normalised signal
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
    r"""Engage the virtual AFM ([Alabdulmuhsin] Fig. 3.10) from :data:`ENGAGE_FROM` above ``scan`` at (x, y).

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
    viewer = viewer_or_none() if images else None  # no OpenGL: said now, not after the session
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
    loop = build_loop(model, setup.config.haptics, dev.info, origin, scene=scene, seed=7, ramp_time=0.2)
    meta = loop_metadata(meta, loop)
    n = int(seconds * RATE)
    journal_path(out / "session.h5").unlink(missing_ok=True)  # a killed earlier run's: replaced like the rest
    # the loop runs in simulated time, faster than real time: wait for the disk rather than drop ticks
    meta = dict(meta, device=DeviceConfig.of(dev.info, "virtual").to_metadata())  # bounds its stylus on replay
    writer = SessionWriter(out / "session.h5", meta, when_full="wait", handle_signals=handle_signals)
    compute = np.empty(n)
    damping = np.empty(n)
    views = {}
    marks = {"approach": int(1.2 * RATE), "indent": int(2.4 * RATE), "slide": int(3.6 * RATE), "retract": n - 1}
    tube_force = np.zeros(n)
    with writer:  # an exception or a signal still closes the file (incomplete) with every tick
        for k in progress_bar(range(n), desc="session", unit="tick"):
            st, f, compute[k] = session_tick(dev, loop, model, writer, scene)
            damping[k] = LOOP_OUT.get(loop.out, "passivity_damping")
            if scene is not None:
                tube_force[k] = math.hypot(scene.force[0], scene.force[1])
            for name, tick in marks.items():
                if k == tick:
                    views[name] = scene_snapshot(model, loop, contact, RATE, scene)
    dev.close()
    progress(f"loop: {n} ticks at {RATE:.0f} Hz, tick compute median {np.median(compute) / 1e3:.1f} us, "
             f"p99 {np.percentile(compute, 99) / 1e3:.1f} us")
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
            "ticks_with_tube_force": int(np.count_nonzero(tube_force)),  # the scene pushed back on the tip
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
    # the session's one feel score (arsurf.haptics.feel.score_session): the replay's, drawn on forces.png
    feel = result.feel
    if feel is not None:
        progress(feel.summary() + (" - the hand felt a buzz: see the feel scores in summary.json" if feel.buzzes
                                   else ""))
    else:
        progress("feel: not scored (the tip never touched the surface, or the record is shorter than 0.1 s)")
    pngs = _render(viewer, views, out, dpi) if viewer is not None else []
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
        "feel": feel.as_dict() if feel is not None else None,
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


def _render(viewer, views: dict, out: Path, dpi: int) -> list[Path]:
    """The 3D views (960 x 720 px, the PNG stating ``dpi``: the figures' --dpi), in the 2D figures'
    conventions (:mod:`arsurf_viewer.view`: magma, 1-99 % limits, scale bar, no HUD)."""
    from arsurf.errors import rendering_failed

    SceneState, SurfaceView = viewer.SceneState, viewer.SurfaceView
    paths = []
    try:
        for name, kw in progress_bar(views.items(), desc="views", unit="view"):
            view = SurfaceView(kw["surface"])  # coloured by height, the dent as contour lines over it
            view.update(SceneState(**kw))
            path = out / f"view_{name}.png"
            view.screenshot(path, dpi=dpi)
            view.close()
            paths.append(path)
            if name == "indent":  # the dent itself: ~8 tip radii of field, surface sampled at ~1 nm
                view = SurfaceView(kw["surface"], resolution=1024)
                view.update(SceneState(**kw))
                view.close_up(kw["tip_center"], 8 * kw["tip_radius"])
                path = out / "view_indent_closeup.png"
                view.screenshot(path, dpi=dpi)
                view.close()
                paths.append(path)
    except Exception as exc:  # no OpenGL context after all: the numbers are written, the views asked for are not
        raise rendering_failed(f"demo views (the numbers are in {out}; --no-images skips the views)", exc) from exc
    return paths


