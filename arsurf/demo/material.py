"""``arsurf demo --material``: feel a sample's softer, stiffer and stickier regions.

The haptic loop on a PeakForce QNM file's material map (:mod:`arsurf.contact.material_map`): a
scripted hand presses the same stylus stroke where the sample is softest, stiffest and stickiest
(:func:`pick_spots`), the session is recorded with the map and replayed, and the summary compares
what the hand felt with the Maugis-Dugdale predictions of the local contact law
(:func:`run_material_demo`). Lengths in m, forces in N, moduli in Pa inside; the summary names its
units (``_nm``, ``_nN``, ``_GPa``).
"""
from __future__ import annotations

import logging
import math
import time
from pathlib import Path

import numpy as np

from arsurf._files import write_text
from arsurf._logging import progress as progress_bar
from arsurf.assembly import build_loop, build_model, loop_metadata, preset_metadata
from arsurf.config import DeviceConfig
from arsurf.demo.scripted import DEMO, RATE, SCALE, scene_snapshot, session_tick, viewer_or_none
from arsurf.haptics.virtual_device import HandModel, VirtualDevice
from arsurf.units import summary_json

log = logging.getLogger("arsurf.demo")

__all__ = ["run_material_demo", "pick_spots", "press_measures", "MATERIAL_PRESS", "MATERIAL_HOVER"]


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
                      handle_signals: bool = False, sigma: float | None = None, units=None,
                      zone_energy: bool = False) -> dict:
    r"""``arsurf demo --material``: the haptic loop on a PeakForce QNM file, pressing where the
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
    adhesion. ``zone_energy``: the model's contact the energy of the whole tip, each surface element
    with its local law (:mod:`arsurf.contact.zone_energy`; recorded in the session), and the summary
    adds that law's predictions (``zone_*``: its indentation on a flat, its pull-off
    :math:`2\pi R w`).
    """
    from arsurf.contact.material_map import material_map_from_file
    from arsurf.contact.maugis_dugdale import MaugisDugdale
    from arsurf.contact.zone_energy import ZoneLaw
    from arsurf.replay.replay import replay
    from arsurf.sessions.journal import journal_path
    from arsurf.sessions.reader import load_session
    from arsurf.sessions.writer import SessionWriter
    from arsurf.scan.prepare import prepare_scan

    progress = progress or log.info
    viewer = viewer_or_none() if images else None
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
                                    "dugdale_stress": law.dugdale_stress}, zone_energy=bool(zone_energy))
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
    loop = build_loop(model, setup.config.haptics, dev.info, origin, seed=7, ramp_time=0.2)
    meta = loop_metadata(meta, loop)
    n = int(math.ceil(times[-1] * RATE))
    journal_path(out / "session.h5").unlink(missing_ok=True)
    meta = dict(meta, device=DeviceConfig.of(dev.info, "virtual").to_metadata())  # bounds its stylus on replay
    writer = SessionWriter(out / "session.h5", meta, when_full="wait", handle_signals=handle_signals)
    compute = np.empty(n)
    hand = np.empty(n)
    views = {}
    with writer:
        for k in progress_bar(range(n), desc="session", unit="tick"):
            s, f, compute[k] = session_tick(dev, loop, model, writer)
            hand[k] = float(np.linalg.norm(f))
            for name, (a, b) in windows.items():
                if name in ("soft", "stiff") and abs(s.timestamp - (a + 1.5)) < 0.5 / RATE:
                    views[name] = scene_snapshot(model, loop, model.contact, RATE)
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
        if zone_energy:  # the zone law of the local E* and w (the DMT limit of the same constants)
            zone = ZoneLaw.from_law(md)
            spots_out[k]["zone_indentation_at_reference_load_m"] = zone.flat_depth(ref) if math.isfinite(ref) \
                else math.nan
            spots_out[k]["zone_pull_off_N"] = -zone.pull_off_force()
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
        "scan": str(scan_path), "n_ticks": n, "rate_Hz": RATE, "tip_radius_m": R, "zone_energy": bool(zone_energy),
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
