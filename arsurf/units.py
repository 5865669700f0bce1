r"""Units at the edge: how every file arsurf writes names the unit of each number (one convention).

Inside arsurf every value is SI and names carry no unit (docs/design.rst, "Units and conventions"). Where numbers
leave the program - files for people and for other programs - each one says its SI unit, the same way in
every file:

================  =================================================================================
file kind         how a number gives its unit
================  =================================================================================
JSON summaries    the key ends with the SI unit: ``peak_force_N``, ``max_depth_m``, ``duration_s``,
                  ``work_of_adhesion_J_per_m2`` (``summary.json`` of the demo, the replay and a batch;
                  ``batch.json``). A list takes the unit of its key; the statistics under a key
                  (``min``, ``median``, ``max``, ``mean``) take that key's unit
CSV tables        the column name ends with the unit: ``t_s``, ``F_simulated_x_N``, ``rms_roughness_m``
                  (``forces.csv`` of a replay, ``results.csv`` of a batch)
HDF5 datasets     a ``units`` attribute on each dataset (:data:`UNITS_ATTR`): ``"m"``, ``"N"``,
                  ``"m/s"``; ``"1"`` for a dimensionless number; one unit per column, comma
                  separated, where the columns differ (``"m,m,rad"``). The dataset names stay those
                  of the format, so files written before the attribute existed still read
================  =================================================================================

A number without a unit suffix is dimensionless, and its name says so: a count (``n_ticks``,
``ticks_in_contact``, ``inpainted_pixels``, ``contact_mismatches``), a ratio or fraction
(``friction_ratio``, ``slip_fraction``, ``high_frequency_over_normal``), an index (``_index``) or
one of the dimensionless quantities of :data:`DIMENSIONLESS` (the friction coefficient, the
Maugis parameter...). What a command writes for people (``arsurf info --json``, ``arsurf fit``, ``arsurf verify``'s
report) may give a scaled unit instead, as its suffix says (:data:`SCALED_SUFFIXES`: ``_nm``,
``_nN``, ``_GPa``, ``_mJ_per_m2``, ``_ms``, ``_us``, ``_deg``, ``_percent``, ``_A``); a lower-case
``_hz`` or an ``E*`` is no unit. :func:`unit_of` reads a name the way this table says, and
:func:`undeclared` lists the numbers of a JSON document whose names give no unit (the tests run it
over every file the demo, the replay and a batch write).

Examples
--------
>>> unit_of("peak_force_N"), unit_of("work_of_adhesion_J_per_m2"), unit_of("ticks_in_contact")
('N', 'J/m^2', '1')
>>> unit_of("peak_force") is None                     # no unit: not allowed in a file
True
>>> undeclared({"duration_s": 1.0, "peak_force": 2e-9, "engage": {"steps": [3, 4], "max_force_N": 1e-8}})
['peak_force']
"""
from __future__ import annotations

import json
import math
import re
from typing import Any

__all__ = ["UNITS_ATTR", "SUFFIXES", "SCALED_SUFFIXES", "DIMENSIONLESS", "STATISTICS", "unit_of", "undeclared", "with_unit",
           "summary_json"]

#: the HDF5 attribute that holds a dataset's unit
UNITS_ATTR = "units"

#: name suffix -> SI unit (longest first: ``_N_per_m`` is newtons per metre, not metres)
SUFFIXES: dict[str, str] = {
    "J_per_m2": "J/m^2",
    "N_s_per_m": "N s/m",
    "N_per_m": "N/m",
    "m_per_s": "m/s",
    "m_per_V": "m/V",
    "per_s": "1/s",
    "bytes": "B",  # file sizes (the replay's manifest, the batch's output check)
    "rad": "rad",
    "Pa": "Pa",
    "Hz": "Hz",
    "px": "px",
    "N": "N",
    "J": "J",
    "V": "V",
    "m": "m",
    "s": "s",
}

#: name suffix -> a scaled unit, accepted where a command writes for people (``arsurf info --json``
#: in nm, ``arsurf verify``'s report in nm and degrees); the files of record stay in SI
SCALED_SUFFIXES: dict[str, str] = {
    "mJ_per_m2": "mJ/m^2",
    "percent": "%",
    "GPa": "GPa",
    "deg": "deg",
    "nm": "nm",
    "nN": "nN",
    "ms": "ms",
    "us": "us",
    "A": "A",
}

#: names of dimensionless numbers that no pattern below recognises
DIMENSIONLESS = frozenset({
    "friction",  # kinetic friction coefficient mu
    "maugis_lambda",  # Maugis' elasticity parameter lambda
    "sample_poisson", "tip_poisson",  # Poisson ratios
    "outlier_mads",  # robust standard deviations (a multiple of a scale)
    "smoothing",  # P-spline penalty weight (scaled to the data, no unit)
    "control_nu", "control_nv", "control_shape", "resolution",  # numbers of control points / samples
    "steps", "frames", "items", "ok", "failed", "not_run", "reversals",  # counts
    "version", "format_version", "session_format_version",
    "in_contact", "md_status", "decoupling_flags", "collide_status", "moved", "buttons",  # flags and codes
})

#: statistics that take the unit of the key they are under (``count`` is always a count)
STATISTICS = frozenset({"min", "median", "max", "mean", "p5", "p95", "p99", "std"})

_COUNT = re.compile(r"^(n|ticks|ran|skipped)_|_(count|ticks|steps|pixels|mismatches|failures|index|indices|"
                    r"ratio|fraction)$|_over_")
_NAME = re.compile(r"[A-Za-z0-9_]+")
_SUFFIX = re.compile(r"_(" + "|".join(re.escape(s) for s in {**SUFFIXES, **SCALED_SUFFIXES}) + r")$")


def unit_of(name: str) -> str | None:
    """The SI unit a file name (JSON key, CSV column) declares.

    Parameters
    ----------
    name : str
        A key or column name.

    Returns
    -------
    str or None
        The unit (``"N"`` for ``peak_force_N``), ``"1"`` for a dimensionless name (a count,
        ratio, index or one of :data:`DIMENSIONLESS`), None when the name declares no unit.
    """
    if not _NAME.fullmatch(name):  # E*_GPa: a unit suffix on a name that is no identifier
        return None
    m = _SUFFIX.search(name)
    if m is not None:
        return SUFFIXES.get(m.group(1)) or SCALED_SUFFIXES[m.group(1)]
    if name in DIMENSIONLESS or _COUNT.search(name) or name == "count":
        return "1"
    return None


def with_unit(name: str, unit: str) -> str:
    """``name`` with the suffix of ``unit`` (an SI unit of :data:`SUFFIXES`; ``""``/``"1"``: none).

    >>> with_unit("tip_radius", "m"), with_unit("friction", "")
    ('tip_radius_m', 'friction')
    """
    if unit in ("", "1"):
        return name
    for suffix, u in SUFFIXES.items():
        if u == unit:
            return f"{name}_{suffix}"
    raise ValueError(f"unit {unit!r} has no name suffix; use one of {sorted(set(SUFFIXES.values()))}")


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def undeclared(obj: Any, unit: str | None = None, path: str = "") -> list[str]:
    """The numbers of a JSON document whose key declares no unit (``[]``: it follows the convention).

    Parameters
    ----------
    obj : dict, list or scalar
        A parsed JSON document (``json.load``).
    unit : str, optional
        The unit the enclosing key declared (lists and statistics inherit it).
    path : str
        Where ``obj`` sits (for the answer).

    Returns
    -------
    list of str
        Slash-separated paths of the numbers whose unit is unknown (a ``null`` holds no number: it
        is not checked).
    """
    bad: list[str] = []
    if isinstance(obj, dict):
        for key, value in obj.items():
            key = str(key)
            here = f"{path}/{key}" if path else key
            if key == "count":
                own = "1"
            elif key in STATISTICS:
                own = unit
            else:
                own = unit_of(key)
            if isinstance(value, (dict, list)):
                bad.extend(undeclared(value, own, here))
            elif _is_number(value) and own is None:
                bad.append(here)
    elif isinstance(obj, list):
        for k, value in enumerate(obj):
            if isinstance(value, (dict, list)):
                bad.extend(undeclared(value, unit, f"{path}[{k}]"))
            elif _is_number(value) and unit is None:
                bad.append(f"{path}[{k}]")
    elif _is_number(obj) and unit is None:
        bad.append(path or "(top level)")
    return bad


def _strict(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {k: _strict(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_strict(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def summary_json(summary: Any, sort_keys: bool = False) -> str:
    """The text of a JSON summary file: strict JSON (NaN and infinities, which JSON lacks, written as
    ``null``: a value that was not measured keeps its key), indented, one final newline.

    >>> print(summary_json({"settle_time_s": float("nan"), "n_ticks": 3}), end="")
    {
      "settle_time_s": null,
      "n_ticks": 3
    }
    """
    return json.dumps(_strict(summary), indent=2, sort_keys=sort_keys, allow_nan=False) + "\n"
