"""Benchmark (diagnostic): where the tip's balance behind the coupling steps, and why.

For each run of a families table (``bench/feel.py --families ... --out FILE``; by default only the
failing ones), the run's surface is pressed with the default loop (the preset's press, simulated
source, 1 kHz, 1.5 s), and the model the loop leaves is then driven by hand: its target is swept
from where the press left it along the run's heading, ``--length`` nm in ``--step`` pm steps, at
that height, with the jump blend off (:meth:`arsurf.model.ARModel.set_jump_blend`), so that the
force read at each step is the balance itself, a function of the target and of the contact table
the model keeps (:mod:`arsurf.contact.multi_contact`).

A step is a change of the simulated force by more than ``--threshold`` (1 %) of its median over
the sweep in one step (at 10 nm/s a 1 kHz tick is 10 pm: ten such steps). Each is put down to
the first of these causes that the contact table shows across it:

- ``behind_target``: a contact left the table whose minimum is still there, within half a knot
  spacing of where it was, but deeper than the tip radius under the target: the target passed
  behind its patch (the table takes no such minimum, :func:`~arsurf.contact.multi_contact.find_contacts_kernel`);
- ``not_followed``: a contact left whose minimum is still there and in reach: tracking lost it;
- ``merged``: a contact left whose minimum is now another row's;
- ``below_floor``: a contact left whose minimum is still there, shallower than the interaction
  floor (an exit with no load, by the entry ramp);
- ``gone``: a contact left whose minimum Newton no longer finds within half a knot spacing of
  where it was (a minimum flattening towards the fold where it dies: the run creeps and gives up);
- ``found``: a contact entered (a scan, or a minimum born);
- ``closest_hop``: the closest point (row 0) moved to another minimum;
- ``second_reference``: the second reference of the weights changed;
- ``scan``: the net was scanned;
- ``steep``: none of these: the balance itself moves that fast there.

Printed per run: the force's median where the tip touches (N), the median step (N), the share of
the sweep where it touches, the share of the sweep where the
target is inside the material (the closest point more than a tip radius deep under it, as a
soft coupling lets a pressing hand put it), and per cause the count, the largest step (over the
median force) and its share of the summed step size.

Run: .venv/bin/python bench/feel_steps.py TABLE.jsonl [--all] [--limit N] [--length NM] [--step PM]
[--seed S --families N --runs 4 2] (prints JSON; the seed, families and runs must be those the table
was written with)
"""
from __future__ import annotations

import argparse
import copy
import json
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from feel import _surface, add_table_arguments, table_runs  # noqa: E402  (the table's own runs and surfaces)

from arsurf.contact import multi_contact as mc  # noqa: E402
from arsurf.contact.newton import newton_foot  # noqa: E402
from arsurf.feel_scenarios import run_scenario  # noqa: E402
from arsurf.model import CONTACT_MARGIN, F_JUMP_OUT, M_SIM_FX, S_CONTACTS  # noqa: E402

CAUSES = ("behind_target", "not_followed", "merged", "below_floor", "gone", "found", "closest_hop",
          "second_reference", "scan", "steep")
#: the press before the sweep (s): the model is taken at its last tick
PRESS_SECONDS = 1.5


def pressed_model(surface, tip_radius, friction=None):
    """The model and the target (m) a 1 kHz default-loop press on ``surface`` leaves, with the
    jump blend off (``friction``: the kinetic coefficient; None: the preset's)."""
    taken = {}

    def after(tip, probe, model):
        taken["model"], taken["target"] = model, probe.copy()

    run_scenario(surface, motion="press", source="simulated", rate=1000.0, seconds=PRESS_SECONDS,
                 tip_radius=tip_radius, friction=friction, after_tick=after)
    model = copy.deepcopy(taken["model"])
    model.set_jump_blend(0.0, 1e-3)
    return model, taken["target"]


def _rows(state):
    """The contact table's rows: (u, v, depth) each (m)."""
    t = S_CONTACTS
    rows = []
    for i in range(int(state[t + mc.T_COUNT])):
        r = t + mc.T_ROWS + i * mc.C_SIZE
        rows.append((state[r + mc.C_U], state[r + mc.C_V], state[r + mc.C_DEPTH]))
    return rows


def _near(u, v, rows, tol) -> bool:
    return any(math.hypot(u - a, v - b) <= tol for a, b, _ in rows)


def causes_of_step(model, target, before, after, scan_before, scan_after, second_before, second_after):
    """The causes (in :data:`CAUSES` order) the contact table shows across one step of the sweep."""
    live_ctrl, live_rest, ku, kv, patch = model._live
    h = max(ku[4] - ku[3], kv[4] - kv[3])
    radius = model.tip_radius  # depth = R - signed distance
    floor = model._friction[F_JUMP_OUT] - CONTACT_MARGIN * model.contact.depth_scale
    ev = np.zeros((8, 3))
    found = set()
    for u, v, _ in before:
        if _near(u, v, after, 0.02 * h):
            continue
        uu, vv, *_, signed, ok = newton_foot(live_rest, ku, kv, ev, *target, u, v, h, 0.5 * h)
        if not ok:
            found.add("gone")
        elif _near(uu, vv, after, 1e-3 * h):
            found.add("merged")
        elif signed < 0.0:  # more than R deep: the target is behind its patch
            found.add("behind_target")
        elif radius - signed < floor:
            found.add("below_floor")
        else:
            found.add("not_followed")
    if any(not _near(u, v, before, 0.02 * h) for u, v, _ in after):
        found.add("found")
    if before and after and math.hypot(before[0][0] - after[0][0], before[0][1] - after[0][1]) > 0.02 * h:
        found.add("closest_hop")
    if second_before != second_after:
        found.add("second_reference")
    if scan_before != scan_after:
        found.add("scan")
    return [c for c in CAUSES if c in found] or ["steep"]


def sweep(model, start, heading: float, length: float, step: float, threshold: float) -> dict:
    """The target swept from ``start`` (m) along ``heading`` (rad) by ``length`` m in ``step`` m
    steps: its force steps and their causes (module docstring)."""
    t = S_CONTACTS
    direction = np.array([math.cos(heading), math.sin(heading), 0.0])
    n = int(round(length / step)) + 1
    force = np.empty((n, 3))
    rows, scans, seconds = [], [], []
    inside = 0
    for k in range(n):
        out = model.tick(start + k * step * direction)
        force[k] = out[M_SIM_FX:M_SIM_FX + 3]
        state = model.state
        rows.append(_rows(state))
        scans.append(tuple(state[t + mc.T_SCANNED:t + mc.T_SCANNED + 3]))
        seconds.append(state[t + mc.T_SECOND])
        inside += bool(rows[-1]) and rows[-1][0][2] > model.tip_radius
    size = np.linalg.norm(np.diff(force, axis=0), axis=1)
    magnitude = np.linalg.norm(force, axis=1)
    touching = magnitude > 0.0
    if not touching.any():
        return {"median_force_N": 0.0, "median_step_N": 0.0, "touching_share": 0.0, "target_inside_share": 0.0,
                "steps": 0, "causes": {}}
    scale = float(np.median(magnitude[touching]))
    per = {c: [] for c in CAUSES}
    for k in np.flatnonzero(size > threshold * scale):
        target = start + (k + 1) * step * direction
        cause = causes_of_step(model, target, rows[k], rows[k + 1], scans[k], scans[k + 1], seconds[k],
                               seconds[k + 1])[0]
        per[cause].append(float(size[k]))
    total = sum(sum(v) for v in per.values())
    return {"median_force_N": scale, "median_step_N": float(np.median(size)), "touching_share": float(touching.mean()),
            "target_inside_share": float(inside / n), "steps": int(sum(len(v) for v in per.values())),
            "causes": {c: {"count": len(v), "largest_over_force": max(v) / scale,
                           "share_of_step_size": sum(v) / total} for c, v in per.items() if v}}


def add_sweep_arguments(ap) -> None:
    """The sweep's arguments (module docstring; ``bench/zone_energy.py`` sweeps alike)."""
    ap.add_argument("--length", type=float, default=20.0, help="nm swept (default 20)")
    ap.add_argument("--step", type=float, default=1.0, help="pm per step (default 1)")
    ap.add_argument("--threshold", type=float, default=0.01, help="a step: this fraction of the median force")


def sweep_arguments_error(args) -> str | None:
    """What is wrong with the sweep's arguments, in one line, or None."""
    if not (args.length > 0 and args.step > 0 and args.threshold > 0 and args.length * 1e3 / args.step <= 1e6):
        return "--length, --step and --threshold must be positive, with at most 1e6 steps"
    return None


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_table_arguments(ap, families=240, runs=(4, 2), seed=0)
    add_sweep_arguments(ap)
    args = ap.parse_args()
    if (error := sweep_arguments_error(args)) is not None:
        sys.exit(f"feel_steps: {error}")
    out = []
    for kind in ("slow", "fast"):
        for run in table_runs(args, kind):
            model, target = pressed_model(_surface(run), run["tip_radius_m"])
            out.append({"key": run["key"], "motion": run["motion"], "heading_deg": run["heading_deg"],
                        **sweep(model, target, math.radians(run["heading_deg"]), args.length * 1e-9,
                                args.step * 1e-12, args.threshold)})
    json.dump({"what": "steps of the balance force along a swept target, by cause", "runs": out}, sys.stdout,
              indent=1)
    print()


if __name__ == "__main__":
    main()
