"""Benchmark (diagnostic): where the rate pairs of a families table part, with the jump blend and without.

For each rate pair of a families table (``bench/feel.py --families ... --out FILE``; by default
only the failing ones), the pair is run again with the default loop and once more with the jump
blend off (``jump_blend`` 0, :mod:`arsurf.contact.jump_blend`), and compared as the table does
(:func:`arsurf.feel_scenarios.rate_difference`). Printed per pair and setting: the rate error
and the lowest energy of the two runs (E0), the share of the squared difference that lies in its
worst 100 ms (one event: a jump the two rates took differently), and how far the two rendered
tips are apart where the 1 kHz loop sampled the path (nm; the largest, and the median of each
100 ms's largest: paths that parted stay apart). The pass count of a table moves by a few runs with
any change to the loop (docs/feel-log.rst, "The blend and the loop rate"); these say why a pair fails.

Run: .venv/bin/python bench/feel_pairs.py TABLE.jsonl [--all] [--limit N] [--seed S --families N --runs 4 2]
(prints JSON; the seed, families and runs must be those the table was written with)
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

from arsurf.feel_scenarios import FAST_SECONDS, _at_matched_instants, rate_convergence  # noqa: E402

#: s: the windows the difference is read in
WINDOW = 0.1


def parting(slow, fast, settle: float = 1.0) -> dict:
    """Where the 1 kHz run ``slow`` and the 10 kHz run ``fast`` (:class:`~arsurf.feel_scenarios.FeelRun`)
    part, after ``settle`` s: the worst window's share of the squared force difference, and the
    rendered tips' separation (m) where the 1 kHz probe passes (the largest, the median window's)."""
    n = min(slow.force.shape[0], fast.force.shape[0] // 10)
    force = _at_matched_instants(fast.force[:10 * n], fast.probe[:10 * n], slow.probe[:n], 10)
    tip = _at_matched_instants(fast.tip[:10 * n], fast.probe[:10 * n], slow.probe[:n], 10)
    k0, w = int(round(settle * 1000.0)), int(round(WINDOW * 1000.0))
    sq = np.sum((slow.force[k0:n] - force[k0:]) ** 2, axis=1)
    apart = np.linalg.norm(slow.tip[k0:n] - tip[k0:], axis=1)
    starts = range(0, len(sq), w)
    worst = max((float(sq[i:i + w].sum()) for i in starts), default=0.0)
    largest = [float(apart[i:i + w].max()) for i in starts]
    return {"worst_window_share": worst / float(sq.sum()) if sq.sum() > 0 else 0.0,
            "tips_apart_max_m": max(largest, default=0.0),
            "tips_apart_median_window_m": float(np.median(largest)) if largest else 0.0}


def diagnose(run: dict, jump_blend: float | None) -> dict:
    """One rate pair run again (``jump_blend`` None: the loop's default)."""
    r = rate_convergence(_surface(run), run["motion"], run["source"], FAST_SECONDS, tip_radius=run["tip_radius_m"],
                         heading=math.radians(run["heading_deg"]), room=run["room_m"], records=True,
                         jump_blend=jump_blend)
    energy = [x for x in r["min_energy_over_E0"] if math.isfinite(x)]
    return {"jump_blend_s": "default" if jump_blend is None else jump_blend, "rate_error": r["rate_error"],
            "min_energy_over_E0": min(energy) if energy else None, "ok": r["ok"], **parting(*r["runs"])}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_table_arguments(ap, families=240, runs=(4, 2), seed=0)
    out = [{"key": run["key"], "motion": run["motion"], "source": run["source"],
            "settings": [diagnose(run, None), diagnose(run, 0.0)]} for run in table_runs(ap.parse_args(), "fast")]
    json.dump({"what": "where failing rate pairs of a families table part, with the jump blend and without",
               "pairs": out}, sys.stdout, indent=1)
    print()


if __name__ == "__main__":
    main()
