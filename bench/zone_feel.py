"""Benchmark (diagnostic): a table's failing runs judged again with the zone energy's proxy as the contact.

For each failing run of a families table (``bench/feel.py --families ... --out FILE``), the run is
judged as the table judged it (:func:`arsurf.feel_scenarios.judge_run`: the same hand, device,
motion, rates and criteria), but each loop tick takes its force from the zone energy's proxy
(:func:`arsurf.contact.zone_energy.zone_proxy_kernel`: the tip moved from where it was to the
nearest minimum of :math:`E(T) + \\tfrac12 k|T - C|^2`, C the probe, k the loop's virtual coupling
at the probe's scale) instead of the model: the hand gets K_f k (T - C), through the loop's own
passivity controller, saturated at the device's force. What the loop does besides is left out:
the measured source's decoupling and its filter (every run is read as the simulated source), the
jump blend, the friction, the dent, the start-up ramp. So it says what the contact energy alone
gives the hand, not what the product would.

With ``--control`` the runs are judged instead with the model as the contact and the same things
left out (the simulated source, no friction; the model's own jump blend kept): what those
omissions alone do.

Printed per run: the table's verdict and measures, and the zone loop's (``ok``, content above
100 Hz, reversals, energy over E0 or the rate error), or the control's.

Run: .venv/bin/python bench/zone_feel.py TABLE.jsonl [--all] [--limit N] [--per-knot K]
[--seed S --families N --runs 4 2] (prints JSON; the seed, families and runs must be those the table
was written with)
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from feel import _surface, add_table_arguments, read_rows, table_runs  # noqa: E402

import arsurf.feel_scenarios as scenarios  # noqa: E402
from arsurf.contact.zone_energy import Z_SIZE, ZoneLaw, lattice_for, zone_proxy_kernel  # noqa: E402
from arsurf.errors import SurfaceError  # noqa: E402
from arsurf.haptics.loop import LOOP_OUT  # noqa: E402
from arsurf.haptics.safety import SAFETY_PARAMS  # noqa: E402
from arsurf.model import M_IN_CONTACT  # noqa: E402

#: the table's measures shown beside the zone loop's
MEASURES = ("ok", "rate_error", "high_frequency_over_normal", "reversals", "min_energy_over_E0", "rest_error")


def zone_step(loop, model, lattice, law):
    """A replacement for ``loop.step`` (module docstring): the probe's tip behind the coupling on the
    zone energy, its force scaled to the hand through the loop's passivity controller."""
    k = model.coupling_stiffness
    gain = float(np.max(np.abs(loop.coupling.force.gain)))
    limit = float(SAFETY_PARAMS.get(loop.safety.params, "max_force"))
    tip = np.full(3, math.nan)
    zone = np.empty(Z_SIZE)
    device = loop._device_force
    out, mout = loop.out, model.out
    o_probe, o_tip, o_force = LOOP_OUT.offset("probe"), LOOP_OUT.offset("tip"), LOOP_OUT.offset("probe_force")
    o_energy, o_damping = LOOP_OUT.offset("energy"), LOOP_OUT.offset("passivity_damping")

    def step(inputs, now, signals=None):
        probe = loop.coupling.position.map(np.asarray(inputs.position, np.float64))
        if not np.isfinite(tip).all():
            tip[:] = probe
        zone_proxy_kernel(*lattice.kernel_args(), probe[0], probe[1], probe[2], k, *law.args, tip, zone)
        force = k * (tip - probe)
        device[:] = gain * force
        loop.passivity.step(inputs.position, inputs.velocity, device)
        size = float(np.linalg.norm(device))
        if size > limit:
            device[:] *= limit / size
        loop.passivity.applied(device)
        out[o_probe:o_probe + 3] = probe
        out[o_tip:o_tip + 3] = tip
        out[o_force:o_force + 3] = force
        out[o_energy] = loop.passivity.energy
        out[o_damping] = loop.passivity.damping
        mout[M_IN_CONTACT] = 1.0 if float(np.linalg.norm(force)) > 0.0 else 0.0
        return device

    return step


def judged_with_zone(run: dict, surface, per_knot: int) -> dict:
    """``judge_run`` of ``run`` with every loop's contact the zone proxy's (module docstring)."""
    lattice = []  # built once, at the first loop: the run's surface at rest
    real = scenarios.build_loop

    def build(model, haptics, info, origin, **kw):
        loop = real(model, haptics, info, origin, **kw)
        if not lattice:
            lattice.append(lattice_for(model.rest_surface, model.tip_radius, ZoneLaw.from_law(model.contact).interaction_range,
                                       per_knot))
        loop.step = zone_step(loop, model, lattice[0], ZoneLaw.from_law(model.contact))
        return loop

    scenarios.build_loop = build
    try:
        simulated = {**run, "source": "simulated"}
        return scenarios.judge_run(simulated, surface, run["tip_radius_m"])
    finally:
        scenarios.build_loop = real


def judged_as_control(run: dict, surface) -> dict:
    """``judge_run`` of ``run`` with the model as the contact, read as the simulated source and
    without friction (module docstring)."""
    import functools

    real = scenarios.run_scenario
    scenarios.run_scenario = functools.partial(real, friction=0.0)
    try:
        return scenarios.judge_run({**run, "source": "simulated"}, surface, run["tip_radius_m"])
    finally:
        scenarios.run_scenario = real


def _measures(row: dict) -> dict:
    return {k: row[k] for k in MEASURES if k in row}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_table_arguments(ap, families=240, runs=(4, 2), seed=0)
    ap.add_argument("--per-knot", type=int, default=2, help="lattice samples per knot interval, at least (default 2)")
    ap.add_argument("--control", action="store_true",
                    help="judge with the model as the contact, with the same things left out")
    args = ap.parse_args()
    if not 1 <= args.per_knot <= 64:
        sys.exit("zone_feel: --per-knot must be in [1, 64]")
    table = {r["key"]: r for r in read_rows(args.table)}
    out = []
    for kind in ("slow", "fast"):
        for run in table_runs(args, kind):
            row = {"key": run["key"], "kind": kind, "motion": run["motion"], "rate_hz": run.get("rate_hz"),
                   "table": _measures(table[run["key"]])}
            try:
                if args.control:
                    row["control"] = _measures(judged_as_control(run, _surface(run)))
                else:
                    row["zone"] = _measures(judged_with_zone(run, _surface(run), args.per_knot))
            except SurfaceError as exc:  # a lattice too fine for the machine: said in the row, not fatal
                row["error"] = str(exc)
            out.append(row)
    json.dump({"what": "a table's runs judged again with the zone energy's proxy as the loop's contact", "runs": out},
              sys.stdout, indent=1)
    print()


if __name__ == "__main__":
    main()
