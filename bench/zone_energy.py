"""Benchmark (diagnostic): the tip's energy summed over the surface against the model, where the feel fails.

For each failing run of a families table (``bench/feel.py --families ... --out FILE``), the run's
surface is pressed with the default loop as ``bench/feel_steps.py`` does (friction off: the
contact force alone), and then swept along the run's heading, ``--length`` nm in ``--step`` pm
steps, twice:

- ``coupled``: the target, from where the press left it, behind the loop's virtual coupling, as
  the census does: the model's balance (:class:`arsurf.model.ARModel`, several Maugis-Dugdale
  contacts) against the zone energy's proxy (:func:`~arsurf.contact.zone_energy.zone_proxy_kernel`,
  the tip moved from where it was to the nearest minimum of :math:`E(T) + \tfrac12 k|T - C|^2`,
  the same k), each giving the hand the force on the tip;
- ``rigid``: a rigid tip, from where the press left the tip, at that height: the model with its
  coupling set to none against the zone energy (:mod:`arsurf.contact.zone_energy`: the law summed
  over a lattice of the surface, the same E*, w and Dugdale stress).

Printed for each:

- ``median_force_N`` where the tip touches, and ``steps``: changes of the force by more than
  ``--threshold`` (1 %) of that median in one step, with the largest over the median; for the
  proxy its ``snaps`` (the tip moving more than a tenth of the tip radius in one step: its
  minimum ended) and its median Newton iterations;
- for the zone energy, the lattice's spacing (m; ``--per-knot`` samples per knot interval, at
  least enough for an eighth of the tip radius), the median number of samples within reach, and
  the mean time of one evaluation in a compiled loop over the sweep (us), with one bare VTK
  ``FindClosestPoint`` at the same points for scale (the peer of ``bench/feel.py --vtk-only``).

Run: .venv/bin/python bench/zone_energy.py TABLE.jsonl [--all] [--limit N] [--length NM] [--step PM]
[--per-knot K] [--seed S --families N --runs 4 2] (prints JSON; the seed, families and runs must
be those the table was written with)
"""
from __future__ import annotations

import argparse
import copy
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
from numba import njit

sys.path.insert(0, str(Path(__file__).resolve().parent))
from collision import surface_mesh, vtk_locator  # noqa: E402  (the VTK peer, built the same way in every bench)
from feel import _surface, add_table_arguments, table_runs  # noqa: E402
from feel_steps import add_sweep_arguments, pressed_model, sweep_arguments_error  # noqa: E402

from arsurf.assembly import PRESETS  # noqa: E402
from arsurf.contact.maugis_dugdale import MaugisDugdale  # noqa: E402
from arsurf.contact.zone_energy import (Z_FORCE, Z_SIZE, ZoneLaw, lattice_for, zone_energy_kernel,  # noqa: E402
                                        zone_proxy_kernel)
from arsurf.errors import SurfaceError  # noqa: E402
from arsurf.model import M_SIM_FX, M_TIP  # noqa: E402


@njit(cache=True)
def _zone_sweep(lat, path, radius, e_star, sigma0, h0, forces, counts):
    """The zone energy's force at each point of ``path`` (n, 3) m into ``forces`` (n, 3) N, and the
    number of samples in reach into ``counts``."""
    out = np.empty(Z_SIZE)
    none = np.empty((0, 0))
    for k in range(path.shape[0]):
        counts[k] = zone_energy_kernel(lat, path[k, 0], path[k, 1], path[k, 2], radius,
                                       e_star, sigma0, h0, out, none)
        forces[k, 0] = out[Z_FORCE]
        forces[k, 1] = out[Z_FORCE + 1]
        forces[k, 2] = out[Z_FORCE + 2]


@njit(cache=True)
def _proxy_sweep(lat, targets, stiffness, radius, e_star, sigma0, h0, tip, forces, tips,
                 iterations):
    """The zone proxy along ``targets`` (n, 3) m from ``tip`` (3,) m: the force on the tip (N) and
    the tip (m) at each, and the Newton iterations."""
    out = np.empty(Z_SIZE)
    for k in range(targets.shape[0]):
        iterations[k] = zone_proxy_kernel(lat, targets[k, 0], targets[k, 1], targets[k, 2],
                                          stiffness, radius, e_star, sigma0, h0, tip, out)
        forces[k, 0] = out[Z_FORCE]
        forces[k, 1] = out[Z_FORCE + 1]
        forces[k, 2] = out[Z_FORCE + 2]
        tips[k, 0] = tip[0]
        tips[k, 1] = tip[1]
        tips[k, 2] = tip[2]


def step_figures(force: np.ndarray, threshold: float) -> dict:
    """The median of |F| where it is not 0 and the steps beyond ``threshold`` of it (module docstring)."""
    magnitude = np.linalg.norm(force, axis=1)
    touching = magnitude > 0.0
    if not touching.any():
        return {"median_force_N": 0.0, "steps": 0, "largest_step_over_force": 0.0}
    scale = float(np.median(magnitude[touching]))
    size = np.linalg.norm(np.diff(force, axis=0), axis=1)
    return {"median_force_N": scale, "steps": int((size > threshold * scale).sum()),
            "largest_step_over_force": float(size.max() / scale)}


def compare(surface, tip_radius: float, heading: float, length: float, step: float, per_knot: int,
            threshold: float) -> dict:
    """The model's and the zone energy's force along the sweep (module docstring)."""
    model, target = pressed_model(surface, tip_radius, friction=0.0)
    start = model.out[M_TIP:M_TIP + 3].copy()
    n = int(round(length / step)) + 1
    direction = np.array([math.cos(heading), math.sin(heading), 0.0])
    offsets = np.outer(np.arange(n) * step, direction)
    p = PRESETS["demo"]
    law = ZoneLaw.from_law(MaugisDugdale(tip_radius, p.effective_modulus, p.work_of_adhesion))
    lattice = lattice_for(surface, tip_radius, law.interaction_range, per_knot)
    k = model.coupling_stiffness
    coupled = copy.deepcopy(model)  # tick reuses its array: each row copied
    coupled_force = np.array([coupled.tick(c)[M_SIM_FX:M_SIM_FX + 3].copy() for c in target + offsets])
    proxy_force, tips, iterations = np.empty((n, 3)), np.empty((n, 3)), np.empty(n, np.int64)
    _proxy_sweep(*lattice.kernel_args(), target + offsets, k, *law.args, start + np.array([0.0, 0.0, tip_radius]),
                 proxy_force, tips, iterations)
    snaps = int((np.linalg.norm(np.diff(tips, axis=0), axis=1) > 0.1 * tip_radius).sum())
    model.set_coupling_stiffness(math.inf)
    path = start + offsets
    model_force = np.array([model.tick(p)[M_SIM_FX:M_SIM_FX + 3].copy() for p in path])
    forces, counts = np.empty((n, 3)), np.empty(n, np.int64)
    args = (*lattice.kernel_args(), path, *law.args, forces, counts)
    _zone_sweep(*args)  # compiled (or loaded from the cache) before the timing
    t0 = time.perf_counter()
    _zone_sweep(*args)
    per_eval = (time.perf_counter() - t0) / n
    pts, faces = surface_mesh(surface)
    _build, query, _one = vtk_locator(pts, faces)
    vtk_s = float(np.median(query(path[::max(1, n // 2000)])[0]))
    return {"coupling_N_per_m": k,
            "coupled": {"model": step_figures(coupled_force, threshold),
                        "zone_proxy": {**step_figures(proxy_force, threshold), "snaps": snaps,
                                       "iterations_median": float(np.median(np.abs(iterations))),
                                       "not_converged": int((iterations < 0).sum())}},
            "rigid": {"model": step_figures(model_force, threshold),
                      "zone": {**step_figures(forces, threshold), "lattice_spacing_m": float(min(lattice.spacing)),
                     "samples_in_reach_median": float(np.median(counts)), "evaluation_us": per_eval * 1e6,
                     "vtk_query_us": vtk_s * 1e6, "evaluation_over_vtk": per_eval / vtk_s}}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_table_arguments(ap, families=240, runs=(4, 2), seed=0)
    add_sweep_arguments(ap)
    ap.add_argument("--per-knot", type=int, default=2, help="lattice samples per knot interval, at least (default 2)")
    args = ap.parse_args()
    error = sweep_arguments_error(args) or (None if 1 <= args.per_knot <= 64 else "--per-knot must be in [1, 64]")
    if error is not None:
        sys.exit(f"zone_energy: {error}")
    out = []
    for kind in ("slow", "fast"):
        for run in table_runs(args, kind):
            row = {"key": run["key"], "motion": run["motion"], "tip_radius_m": run["tip_radius_m"]}
            try:
                row.update(compare(_surface(run), run["tip_radius_m"], math.radians(run["heading_deg"]),
                                   args.length * 1e-9, args.step * 1e-12, args.per_knot, args.threshold))
            except SurfaceError as exc:  # a lattice too fine for the machine: said in the row, not fatal
                row["error"] = str(exc)
            out.append(row)
    json.dump({"what": "a rigid tip swept where a table's runs fail: the model's force and the zone energy's",
               "runs": out}, sys.stdout, indent=1)
    print()


if __name__ == "__main__":
    main()
