"""Exceptions of arsurf: one base class, one subclass per problem a user can act on.

Every message says the rule, the value received and the way out.
"""
from __future__ import annotations


class ArsurfError(Exception):
    """Base class of every error arsurf raises on purpose."""


class ScanError(ArsurfError):
    """A scan file or height map cannot be used; the message names the file and the problem."""


class ScanFileNotFound(ScanError, FileNotFoundError):
    """The scan file does not exist."""


class UnknownFormat(ScanError):
    """Neither the extension nor the content identify a supported format."""


class CorruptScan(ScanError):
    """The file is truncated or inconsistent with its own header."""


class ChannelNotFound(ScanError, KeyError):
    """The requested channel is not in the file (the message lists those that are)."""

    def __str__(self) -> str:  # KeyError would repr() the message
        return str(self.args[0]) if self.args else ""


class InvalidHeights(ScanError):
    """The height map has NaN/inf pixels or an unusable shape (the message says how to proceed)."""


class MissingDependency(ArsurfError, ImportError):
    """An optional extra is needed for this feature (the message names the pip extra)."""


class SurfaceError(ArsurfError, ValueError):
    """Invalid surface data or query (NaN control points, NaN query point, bad shape)."""


class ContactError(ArsurfError, ValueError):
    """Invalid contact-mechanics input (non-positive radius, modulus, NaN depth...)."""


class ForceError(ArsurfError, ValueError):
    """Invalid cantilever, photodiode or decoupling input."""


class HapticsError(ArsurfError, ValueError):
    """Invalid haptic-loop setting (unstable filter, gains outside the admissible range...)."""


class SessionError(ArsurfError):
    """A recorded session cannot be read or does not match its scan."""


def require(module: str, extra: str, feature: str):
    """Import an optional dependency or raise :class:`MissingDependency` naming the extra.

    Example
    -------
    >>> np = require("numpy", "core", "arrays")
    """
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise MissingDependency(
            f"{feature} needs the Python package {module!r}, which is not installed; "
            f"install it with: pip install 'arsurf[{extra}]'"
        ) from exc
