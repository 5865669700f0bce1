"""Benchmark (diagnostic): the contact force field where still and slow family runs fail.

For each still or slow run of a families table (``bench/feel.py --families ... --out FILE``; by
default only the failing ones), the run is repeated with the default loop and, a third of the way
in and at its last tick, the model's force Jacobian J = dF/dC at the loop's target is taken
(:meth:`arsurf.model.ARModel.force_jacobian`, the contact history restored after each probe),
once with the preset's friction and once with none. Printed per run, relative to the model's
virtual-coupling stiffness k_c (N/m at the probe's scale): the eigenvalues of the stiffness
-(J + J^T)/2 and the norm of the skew part (J - J^T)/2, with the contacts the tip rests on. A
coupling at the passivity bound renders at most k_c; a skew part is a force that is not a
gradient: moved round a loop the tip is given energy, the pressing hand's drift finds it, and
the passivity controller (whose damping can only take out b v^2) falls behind (docs/feel-log.rst,
"Where the rough runs' energy comes from").

Run: .venv/bin/python bench/feel_field.py TABLE.jsonl [--all] [--limit N] [--seed S --families N --runs 2 1]
(prints JSON; the seed, families and runs must be those the table was written with)
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from feel import _surface, add_table_arguments, table_runs  # noqa: E402  (the table's own runs and surfaces)

from arsurf.contact import multi_contact as mc  # noqa: E402
from arsurf.feel_scenarios import SLOW_SECONDS, run_slow  # noqa: E402
from arsurf.model import S_CONTACTS  # noqa: E402


def field_at(model, probe) -> dict:
    """The stiffness eigenvalues and skew norm (N/m) of the force field at ``probe`` (m), and the
    contacts (depth m, weight) the tip rests on there."""
    jac = model.force_jacobian(probe)
    table = model.state[S_CONTACTS:S_CONTACTS + mc.TABLE_SIZE]
    rows = [mc.T_ROWS + i * mc.C_SIZE for i in range(int(table[mc.T_COUNT]))]
    return {"stiffness_eigenvalues_N_per_m": np.linalg.eigvalsh(-0.5 * (jac + jac.T)).tolist(),
            "skew_N_per_m": float(np.linalg.norm(0.5 * (jac - jac.T))),
            "contacts": [{"depth_m": float(table[r + mc.C_DEPTH]), "weight": float(table[r + mc.C_WEIGHT])}
                         for r in rows]}


def diagnose(run: dict, friction: float | None) -> dict:
    """One still/slow run repeated (``friction`` None: the preset's), its field read twice."""
    n = int(round(SLOW_SECONDS * run["rate_hz"]))
    at = {n // 3, n - 1}
    seen, tick = [], [0]

    def after(tip, probe, model):
        tick[0] += 1
        if tick[0] - 1 in at:
            seen.append({"tick": tick[0] - 1, "k_c_N_per_m": model.coupling_stiffness, **field_at(model, probe)})

    res = run_slow(run, _surface(run), run["tip_radius_m"], friction=friction, after_tick=after)
    for s in seen:
        k = s["k_c_N_per_m"]
        s["stiffness_over_k_c"] = [round(e / k, 3) for e in s.pop("stiffness_eigenvalues_N_per_m")]
        s["skew_over_k_c"] = round(s.pop("skew_N_per_m") / k, 3)
    return {"friction": "preset" if friction is None else friction,
            "min_energy_over_E0": float(res.energy.min() / res.energy_reserve), "fields": seen}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_table_arguments(ap, families=40, runs=(2, 1), seed=11)
    out = [{"key": run["key"], "motion": run["motion"], "rate_hz": run["rate_hz"],
            "runs": [diagnose(run, None), diagnose(run, 0.0)]} for run in table_runs(ap.parse_args(), "slow")]
    json.dump({"what": "force field at failing still/slow family runs", "runs": out}, sys.stdout, indent=1)
    print()


if __name__ == "__main__":
    main()
