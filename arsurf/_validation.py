"""Validators of scalar inputs shared by every module: one definition, one message shape.

Each returns the value as a Python ``float`` or raises the caller's exception class (an
:class:`arsurf.errors.ArsurfError` subclass) with a message that says the rule, the value received
and, in ``hint``, what the value is or how to fix it:

    radius must be positive and finite (got -2e-09 m); it is the tip radius

Examples
--------
>>> from arsurf.errors import ContactError
>>> positive(2e-8, "radius", ContactError, unit="m")
2e-08
>>> positive(-1, "radius", ContactError, unit="m", hint="it is the tip radius")
Traceback (most recent call last):
...
arsurf.errors.ContactError: radius must be positive and finite (got -1 m); it is the tip radius
"""
from __future__ import annotations

import math

__all__ = ["finite", "non_negative", "positive", "positive_arg", "real"]


def _number(value, name: str, error: type[Exception], unit: str, hint: str) -> float:
    if isinstance(value, bool):  # True is not a length
        raise error(_message(f"{name} must be a number{' in ' + unit if unit else ''}", value, "", hint))
    try:
        return float(value)
    except (TypeError, ValueError, OverflowError):
        raise error(_message(f"{name} must be a number{' in ' + unit if unit else ''}", value, "", hint)) from None


def _message(rule: str, value, unit: str, hint: str) -> str:
    got = f"{value!r}{' ' + unit if unit else ''}"
    return f"{rule} (got {got})" + (f"; {hint}" if hint else "")


def finite(value, name: str, error: type[Exception], *, unit: str = "", hint: str = "") -> float:
    """``float(value)`` if it is a finite real number, else ``error``."""
    v = _number(value, name, error, unit, hint)
    if not math.isfinite(v):
        raise error(_message(f"{name} must be finite", value, unit, hint))
    return v


def positive(value, name: str, error: type[Exception], *, unit: str = "", hint: str = "") -> float:
    """``float(value)`` if it is finite and > 0, else ``error``."""
    v = _number(value, name, error, unit, hint)
    if not (math.isfinite(v) and v > 0.0):
        raise error(_message(f"{name} must be positive and finite", value, unit, hint))
    return v


def non_negative(value, name: str, error: type[Exception], *, unit: str = "", hint: str = "") -> float:
    """``float(value)`` if it is finite and >= 0, else ``error``."""
    v = _number(value, name, error, unit, hint)
    if not (math.isfinite(v) and v >= 0.0):
        raise error(_message(f"{name} must be >= 0 and finite", value, unit, hint))
    return v


def real(value, name: str, what: str, error: type[Exception], *, positive: bool = False,
         nonneg: bool = False) -> float:
    """``float(value)`` if it is a finite real number (and > 0 with ``positive``, >= 0 with
    ``nonneg``), else ``error`` naming ``name``, what it is (``what``) and the value."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise error(f"{name} must be a real number ({what}) (got {value!r})") from None
    if not math.isfinite(v) or (positive and v <= 0.0) or (nonneg and v < 0.0):
        rule = "positive and finite" if positive else ">= 0 and finite" if nonneg else "finite"
        raise error(f"{name} must be {rule} ({what}) (got {value!r})")
    return v


def available_memory() -> int | None:
    """Bytes of memory available to a new allocation (Linux ``MemAvailable``), None if unknown."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def check_memory(nbytes: float, what: str, error: type[Exception], hint: str = "") -> None:
    """Raise ``error`` before an allocation of ``nbytes`` that cannot fit in the available memory.

    Examples
    --------
    >>> from arsurf.errors import SurfaceError
    >>> check_memory(1e3, "a tiny net", SurfaceError)
    >>> check_memory(1e18, "a net of 1 EB", SurfaceError)
    Traceback (most recent call last):
    ...
    arsurf.errors.SurfaceError: a net of 1 EB needs about 1000000000.0 GB but this machine has ... GB available
    """
    free = available_memory()
    if free is not None and nbytes > free:
        raise error(f"{what} needs about {nbytes / 1e9:.1f} GB but this machine has {free / 1e9:.1f} GB available"
                    + (f"; {hint}" if hint else ""))


def positive_arg(unit: str, scale: float = 1.0):
    """An argparse type: a positive finite number given in ``unit``, returned times ``scale`` (SI).

    >>> positive_arg("nm", 1e-9)("20")
    2e-08
    """
    import argparse

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be a number in {unit} (got {text!r})") from None
        if not (math.isfinite(value) and value > 0):
            raise argparse.ArgumentTypeError(f"must be a positive finite number in {unit} (got {text})")
        return value * scale
    return parse
