"""The checks every batch option goes through: numbers (finite, bounded, SI), integer pairs, grid
axes, unknown names. Each failure is one :class:`~arsurf.errors.BatchError` line naming the option,
the rule, the value received and what the option is."""
from __future__ import annotations

import math
from typing import Mapping, Sequence

from arsurf.errors import BatchError

__all__ = ["number", "int_pair", "refuse_unknown", "axis", "MAX_AXIS"]

#: most grid values on one axis
MAX_AXIS = 10_000


def number(options: Mapping, name: str, default, *, minimum: float = 0.0, strict: bool = False,
            unit: str = "", what: str = "") -> float:
    value = options.get(name, default)
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise BatchError(f"option {name!r} must be a number{' in ' + unit if unit else ''} (got {value!r}); "
                         f"{what}") from None
    if not math.isfinite(x) or x < minimum or (strict and x == minimum):
        rule = f"> {minimum:g}" if strict else f">= {minimum:g}"
        raise BatchError(f"option {name!r} must be finite and {rule}{' ' + unit if unit else ''} (got {value!r}); "
                         f"{what}")
    return x


def int_pair(options: Mapping, name: str, minimum: int, what: str):
    value = options.get(name)
    if value is None:
        return None
    try:
        pair = [int(v) for v in value]
        ok = len(pair) == 2 and all(float(v) == p for v, p in zip(value, pair))
    except (TypeError, ValueError):
        ok = False
    if not ok or min(pair) < minimum:
        raise BatchError(f"option {name!r} must be two integers >= {minimum} (got {value!r}); {what}")
    return pair


def refuse_unknown(options: Mapping, known: Sequence[str], pipeline: str) -> None:
    extra = sorted(set(options) - set(known))
    if extra:
        raise BatchError(f"unknown option(s) {extra} for the {pipeline!r} pipeline; it takes {sorted(known)}")


def axis(options: Mapping, name: str, default: float, *, strict: bool, unit: str, what: str) -> list[float]:
    values = options.get(name)
    if values is None:
        values = [default]
    elif isinstance(values, (int, float)):
        values = [values]
    try:
        values = list(values)
    except TypeError:
        raise BatchError(f"option {name!r} must be a list of numbers{' in ' + unit if unit else ''} "
                         f"(got {values!r})") from None
    if not values or len(values) > MAX_AXIS:
        raise BatchError(f"option {name!r} needs 1 to {MAX_AXIS} values (got {len(values)})")
    out = [number({name: v}, name, None, strict=strict, unit=unit, what=what) for v in values]
    if len(set(out)) != len(out):
        raise BatchError(f"option {name!r} repeats a value ({values!r}); give each grid value once")
    return out
