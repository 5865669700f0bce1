"""Benchmark of ``arsurf verify`` on the virtual AFM: the method's own error and how well it
detects a wrong model.

Each row pushes a tube in the virtual AFM with the true pivot physics while the session's model
is right, has the wrong pivot (middle band 0.45: it translates what turns) or the wrong friction
(5x: another force, the same motion), scans after (new drift, noise, tip dilation), runs
``verify_session`` and compares with the truth the instrument knows: the drift map's worst-corner
error (px), each tube's position (px) and angle (deg) error, and whether the model was flagged.
Peers in the same run: scikit-image's ``phase_cross_correlation`` (translation only, upsampled,
its masked variant integer-only) on the same pairs, and ``scipy.ndimage.grey_dilation`` against
the imaging's dilation kernel.

Run: ``python bench/verify.py [--rows N]``; prints one JSON document.
"""
from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _timing import emit, stats, time_calls  # noqa: E402

from arsurf.instrument.imaging import TipShape, dilate  # noqa: E402
from arsurf.scan.io import load_scan  # noqa: E402
from arsurf.verify.verify import verify_session  # noqa: E402
from arsurf.verify.virtual import Case, run_experiment, true_map_error  # noqa: E402


def table(rows: int) -> list[Case]:
    rng = np.random.default_rng(2026)
    out = []
    for k in range(rows):
        out.append(Case(seed=100 + k, tip_radius=float(rng.choice([6e-9, 10e-9, 15e-9, 25e-9])),
                        drift_rate=float(rng.choice([0.02e-9, 0.08e-9, 0.15e-9])),
                        noise=float(rng.choice([0.1e-9, 0.2e-9, 0.3e-9])),
                        push_at=float(rng.choice([0.1, 0.3, 0.5, 0.7, 0.9])), push=float(rng.choice([25e-9, 50e-9])),
                        wrong=("", "pivot", "friction")[k % 3]))
    return out


def skimage_peer(before, after, true_affine) -> dict | None:
    try:
        from skimage.registration import phase_cross_correlation
    except ImportError:
        return None
    from arsurf.verify.register import level_substrate

    hb, mb = level_substrate(before)
    ha, ma = level_substrate(after)
    t0 = time.perf_counter()
    shift, _, _ = phase_cross_correlation(np.where(mb, 0, hb), np.where(ma, 0, ha), upsample_factor=100)
    dt = time.perf_counter() - t0
    ny, nx = before.shape
    c = np.array([(nx - 1) / 2, (ny - 1) / 2, 1.0])
    truth = true_affine @ c - c[:2]
    # skimage's shift (y, x) registers the after image onto the before one: a feature at p in the
    # after scan is at p + shift in the before scan, the after->before map at the centre
    return {"centre_error_px": float(np.hypot(shift[1] - truth[0], shift[0] - truth[1])), "time_s": dt}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--rows", type=int, default=12)
    args = ap.parse_args()
    rows, peer = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for case in table(args.rows):
            e = run_experiment(case, Path(tmp) / f"c{case.seed}")
            t0 = time.perf_counter()
            r = verify_session(e.session, e.after)
            dt = time.perf_counter() - t0
            err = []
            for c in r.checks:
                tp = e.true_poses[c.index]
                if c.found is None:
                    err.append((math.inf, math.inf))
                else:
                    err.append((math.hypot(c.found.x - tp[0], c.found.y - tp[1]) / r.dx,
                                abs(math.degrees((c.found.angle - tp[2] + math.pi / 2) % math.pi - math.pi / 2))))
            pushed = r.checks[e.pushed]
            rows.append({"seed": case.seed, "model": case.wrong or "right", "tip_radius_nm": case.tip_radius * 1e9,
                         "drift_rate_nm_per_s": case.drift_rate * 1e9, "noise_nm": case.noise * 1e9,
                         "push_at_L": case.push_at, "push_nm": case.push * 1e9,
                         "drift_found_px": [round(float(v), 3) for v in r.registration.shift_px],
                         "drift_error_px": round(true_map_error(r.registration.affine, e.true_affine, (96, 96)), 4),
                         "pose_error_px": [round(a, 3) for a, _ in err], "angle_error_deg": [round(b, 3) for _, b in err],
                         "model_error_pushed_nm": round(pushed.position_error * 1e9, 2),
                         "model_error_pushed_deg": round(math.degrees(pushed.angle_error), 2),
                         "flagged": r.wrong, "verify_s": round(dt, 3)})
            p = skimage_peer(load_scan(e.before), load_scan(e.after), e.true_affine)
            if p is not None:
                c = np.array([47.5, 47.5, 1.0])
                ours = float(np.hypot(*((r.registration.affine - e.true_affine) @ c)))
                peer.append({**p, "ours_centre_error_px": ours})
    right = [x for x in rows if x["model"] == "right"]
    summary = {
        "rows": len(rows),
        "max_drift_error_px": max(x["drift_error_px"] for x in rows),
        "max_pose_error_px": max(max(x["pose_error_px"]) for x in rows),
        "max_angle_error_deg": max(max(x["angle_error_deg"]) for x in rows),
        "wrong_pivot_flagged": f"{sum(x['flagged'] for x in rows if x['model'] == 'pivot')}/"
                               f"{sum(x['model'] == 'pivot' for x in rows)}",
        "wrong_friction_flagged": f"{sum(x['flagged'] for x in rows if x['model'] == 'friction')}/"
                                  f"{sum(x['model'] == 'friction' for x in rows)} (friction sets the force, not the "
                                  "motion: a pose check cannot see it)",
        "right_model_flagged": f"{sum(x['flagged'] for x in right)}/{len(right)}",
    }
    if peer:
        summary["skimage_phase_cross_correlation"] = {
            "centre_error_px_median": float(np.median([p["centre_error_px"] for p in peer])),
            "ours_centre_error_px_median": float(np.median([p["ours_centre_error_px"] for p in peer])),
            "time_s_median": float(np.median([p["time_s"] for p in peer])),
            "ours_verify_s_median": float(np.median([x["verify_s"] for x in rows]))}
    # the imaging's dilation against scipy's grey dilation with the same tip (the same numbers)
    from scipy.ndimage import grey_dilation

    rng = np.random.default_rng(0)
    z = rng.standard_normal((256, 256)) * 2e-9
    tip = TipShape(10e-9)
    oy, ox, t = tip.footprint(2e-9, 2e-9, float(np.ptp(z)) + 1e-15)
    k = int(max(np.abs(oy).max(), np.abs(ox).max()))
    se = np.full((2 * k + 1, 2 * k + 1), -np.inf)
    se[oy + k, ox + k] = -t
    ours = dilate(z, 2e-9, 2e-9, tip)
    theirs = grey_dilation(z, structure=se, mode="constant", cval=-np.inf)
    summary["dilation_vs_scipy_grey_dilation"] = {
        "max_difference_m": float(np.abs(ours - theirs).max()), "footprint_points": int(oy.size),
        "ours": stats(time_calls(lambda: dilate(z, 2e-9, 2e-9, tip), 5, 1)),
        "scipy": stats(time_calls(lambda: grey_dilation(z, structure=se, mode="constant", cval=-np.inf), 5, 1))}
    emit("verify", {"summary": summary, "rows": rows})


if __name__ == "__main__":
    main()
