"""Benchmark (diagnostic): the work the contact force does round a closed loop of the target.

A force that is the gradient of a potential does no net work round a closed path: what a hand
gains on one side of a loop it gives back on the other. The model's force is not one everywhere
(docs/feel-log.rst, "Where the rough runs' energy comes from"): this measures by how much, over a
finite loop rather than at a point (``bench/feel_field.py`` reads the Jacobian's skew part there).

For the surface of each run of a families table (``bench/feel.py --families ... --out FILE``; by
default only the failing ones; each surface once), the surface is pressed with the default loop
(the preset's press, simulated source, 1 kHz, 1.5 s, ``--friction``: by default none, so that the
contact force alone is read), and the model the loop leaves is then driven by hand, with the jump
blend off: its target goes twice round a circle of ``--radius`` nm through where the press left
it, in each coordinate plane (xy, xz, yz), in ``--points`` steps a turn. Printed per surface
(with the table keys of its runs) and plane, for the second turn:

- ``lap_work_J``: :math:`W = \\oint F\\cdot dC` (trapezoidal), the work the force does on the
  target in one turn (> 0: the hand that moves the target gains it; a gradient gives 0);
- ``absolute_work_J``: :math:`\\oint |F\\cdot dC|`, the scale it is read against, and their
  ratio ``circulation``;
- ``memory``: the rms difference of the force between the two turns over its median (0 where the
  force is a function of the target alone; the contact table's tracking, the law's hysteresis and
  friction remember the path). With no memory the work is a curl's: the loop run the other way
  round gives it back with the other sign, so its size, not its sign, is what counts.

Run: .venv/bin/python bench/feel_circulation.py TABLE.jsonl [--all] [--limit N] [--radius NM]
[--points N] [--friction MU] [--seed S --families N --runs 4 2] (prints JSON; the seed, families and
runs must be those the table was written with)
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from feel import _surface, add_table_arguments, table_runs  # noqa: E402  (the table's own runs and surfaces)
from feel_steps import pressed_model  # noqa: E402

from arsurf.model import M_SIM_FX  # noqa: E402

PLANES = {"xy": (0, 1), "xz": (0, 2), "yz": (1, 2)}


def loop_work(model, centre, radius: float, plane: str = "xy", points: int = 2000, sense: int = 1) -> dict:
    """The target of ``model`` (an :class:`~arsurf.model.ARModel`) taken twice round a circle of
    ``radius`` m in ``plane`` that passes through ``centre`` (m), ``points`` steps a turn,
    counter-clockwise in the plane's axes (``sense`` -1: clockwise): the second turn's work, its
    absolute work (J), their ratio and the force's memory of the path (module docstring)."""
    a, b = PLANES[plane]
    angle = sense * np.linspace(0.0, 4.0 * math.pi, 2 * points + 1)
    target = np.repeat(np.asarray(centre, dtype=np.float64)[None], angle.size, axis=0)
    target[:, a] += radius * (np.cos(angle) - 1.0)
    target[:, b] += radius * np.sin(angle)
    force = np.array([model.tick(t)[M_SIM_FX:M_SIM_FX + 3].copy() for t in target])
    work = np.sum(0.5 * (force[1:] + force[:-1]) * np.diff(target, axis=0), axis=1)[points:]
    absolute = float(np.abs(work).sum())
    magnitude = np.linalg.norm(force, axis=1)
    median = float(np.median(magnitude[magnitude > 0.0])) if (magnitude > 0.0).any() else 0.0
    apart = force[points:2 * points] - force[:points]
    return {"lap_work_J": float(work.sum()), "absolute_work_J": absolute,
            "circulation": float(work.sum()) / absolute if absolute > 0.0 else 0.0,
            "memory": float(np.sqrt(np.mean(np.sum(apart * apart, axis=1)))) / median if median > 0.0 else 0.0,
            "median_force_N": median}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_table_arguments(ap, families=240, runs=(4, 2), seed=0)
    ap.add_argument("--radius", type=float, default=3.0, help="nm, the loop's radius (default 3)")
    ap.add_argument("--points", type=int, default=2000, help="steps a turn (default 2000)")
    ap.add_argument("--friction", type=float, default=0.0, help="the kinetic friction coefficient (default 0)")
    args = ap.parse_args()
    if not (0.0 < args.radius <= 1e3 and 8 <= args.points <= 10**6 and 0.0 <= args.friction <= 10.0):
        sys.exit("feel_circulation: --radius must be in (0, 1000] nm, --points in [8, 1e6], --friction in [0, 10]")
    out = {}
    for kind in ("slow", "fast"):
        for run in table_runs(args, kind):
            name = run.get("scan") or run["surface"]
            if name in out:  # the press, and so the loop, is the surface's, not the run's
                out[name]["keys"].append(run["key"])
                continue
            model, target = pressed_model(_surface(run), run["tip_radius_m"], friction=args.friction)
            out[name] = {"surface": name, "tip_radius_m": run["tip_radius_m"], "keys": [run["key"]],
                         "planes": {p: loop_work(model, target, args.radius * 1e-9, p, args.points) for p in PLANES}}
    json.dump({"what": "work of the contact force round a closed loop of the target", "radius_m": args.radius * 1e-9,
               "friction": args.friction, "surfaces": list(out.values())}, sys.stdout, indent=1)
    print()


if __name__ == "__main__":
    main()
