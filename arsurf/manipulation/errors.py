"""Exceptions of the manipulation package (nano-object models and the virtual instrument).

Both derive from :class:`arsurf.errors.ArsurfError` and :class:`ValueError`, so callers can catch
either the arsurf base class or the usual ``ValueError``. Every message says the rule, the value
received and the way out.
"""
from __future__ import annotations

from arsurf.errors import ArsurfError


class ManipulationError(ArsurfError, ValueError):
    """Invalid nano-object model input (non-positive tube length, load point off the beam...)."""


class InstrumentError(ArsurfError, ValueError):
    """Invalid virtual-instrument input (target outside a stage's travel, bad LSPB limits...)."""
