"""Exceptions and warnings of arsurf: one base class, one subclass per problem a user can act on.

Every exception arsurf raises on purpose is defined here (and nowhere else), so a caller can
catch :class:`ArsurfError` or one family (``ScanError``, ``SessionError``...) without importing
the module that raised it.

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


class UnsupportedScan(ScanError):
    """A valid file of a kind arsurf does not read (Gwyddion 1.x, force curves, an RGB picture, a
    Nanonis grid): the message says what the file is and how to get a height map from it."""


class ChannelNotFound(ScanError, KeyError):
    """The requested channel is not in the file (the message lists those that are)."""

    def __str__(self) -> str:  # KeyError would repr() the message
        return str(self.args[0]) if self.args else ""


class InvalidHeights(ScanError):
    """The height map has NaN/inf pixels or an unusable shape (the message says how to proceed)."""


class MissingCalibration(ScanError):
    """The file does not state its pixel spacing or height unit, and none was passed."""


class LevelingError(ScanError, ValueError):
    """A levelling request cannot be carried out (bad method, option, mask or too few pixels)."""


class SmoothingError(ScanError, ValueError):
    """A smoothing request cannot be carried out (bad width, truncation or input)."""


class SigmaTooWide(SmoothingError):
    """The smoothing width is wider than the scan (often a width in the wrong unit). The fields
    let an interface restate it in its own units: ``axis`` ("x"/"y"), ``sigma`` and ``spacing``
    (metres), ``pixels`` (sigma in pixels), ``widest`` (pixels of the scan's longer side)."""

    def __init__(self, message: str, *, axis: str, sigma: float, spacing: float, pixels: float, widest: int):
        super().__init__(message)
        self.axis, self.sigma, self.spacing, self.pixels, self.widest = axis, sigma, spacing, pixels, widest


class SyntheticError(ScanError, ValueError):
    """A synthetic surface cannot be built from the parameters given."""


class UnsafeFile(ArsurfError):
    """A file arsurf was asked to read or write is not one it may use as asked: an output that is a
    symbolic link, an input that is a FIFO or a device, an HDF5 file reaching outside its own bytes
    (external storage, an external link, a virtual dataset) or declaring more data than it holds.
    Readers raise it as their own family (``CorruptScan``, ``SessionError``) when they have one."""


class MissingDependency(ArsurfError, ImportError):
    """An optional extra is needed for this feature (the message names the pip extra)."""


class SurfaceError(ArsurfError, ValueError):
    """Invalid surface data or query (NaN control points, NaN query point, bad shape)."""


class ExportError(ArsurfError, ValueError):
    """The surface cannot be meshed or written as asked (resolution, base height, file type)."""


class MeshError(ArsurfError, ValueError):
    """A mesh cannot be built from the dimensions given."""


class ContactError(ArsurfError, ValueError):
    """Invalid contact-mechanics input (non-positive radius, modulus, NaN depth...)."""


class MaterialMapError(ContactError):
    """A material map cannot be built as asked: a channel in arbitrary units without its stated
    conversion, a grid that does not cover the height image, a channel with no usable pixel."""


class PositionError(SurfaceError, ContactError):
    """A position (tip centre, query point) is not 3 finite coordinates in metres.

    One cause, one class, whichever stage finds it (the projection or the model tick); it is both
    a :class:`SurfaceError` and a :class:`ContactError` so callers of either family catch it.
    """


class ForceError(ArsurfError, ValueError):
    """Invalid cantilever, photodiode or decoupling input."""


class HapticsError(ArsurfError, ValueError):
    """Invalid haptic-loop setting (unstable filter, gains outside the admissible range...)."""


class HapticsWarning(UserWarning):
    """A haptic setting that works but is probably not what was meant (ringing filter, tight gains)."""


class DeviceNotFound(HapticsError):
    """No haptic device answers where one was asked for (none connected, wrong port or index, in use)."""


class DeviceDisconnected(HapticsError):
    """A haptic device stopped answering mid-session; its adapter gave zero force and stopped the loop."""


class LoopError(ArsurfError):
    """The step function raised inside the servo thread; the loop stopped (the cause is chained)."""


class SessionError(ArsurfError):
    """A recorded session cannot be read or does not match its scan."""


class SessionFileNotFound(SessionError, FileNotFoundError):
    """The session file does not exist."""


class IsolatedReadFailure(SessionError):
    """The isolated reader of an HDF5 file crashed, hung or ran out of memory: the file is refused."""


class RecordingInterrupted(KeyboardInterrupt):
    """SIGINT or SIGTERM reached a recording that handles signals: the recording block unwinds.

    A :class:`KeyboardInterrupt` (not an :class:`ArsurfError`), so ``except Exception`` does not
    swallow it and a command line reports it as an interruption.
    """


class BatchError(ArsurfError, ValueError):
    """A batch run cannot start or resume as asked (no input file, a bad option, a results table
    written with other settings, an unreachable Dask scheduler). Errors of single items are not
    raised: they are written to the results table."""


class ItemTimeout(ArsurfError):
    """One batch item ran past the batch's per-item time limit (``--item-timeout``); the batch
    records it in that item's row and goes on with the next item."""


class ManipulationError(ArsurfError, ValueError):
    """Invalid nano-object model input (non-positive tube length, load point off the beam...)."""


class InstrumentError(ArsurfError, ValueError):
    """An instrument (virtual AFM or AFM controller) refused or cannot do what was asked: a target
    outside a stage's travel or the commanded box, bad LSPB limits, a bad setting."""


class ControllerError(InstrumentError):
    """The AFM controller answered a command with an error (the message quotes its description)."""


class InstrumentLinkLost(InstrumentError):
    """The link to the AFM controller stalled, closed or sent bytes that are not its protocol; the
    link is closed and the tip is left where it was (reopen the instrument to go on)."""


class VerifyError(ArsurfError, ValueError):
    """A scan after cannot be compared with the model (scans of different sizes, spacings or
    channels, no overlap, no objects found, a session without objects)."""


class ViewerError(ArsurfError, ValueError):
    """Invalid input to the viewer (a scene state with a bad shape, an unknown layer or colouring)."""


class FigureError(ArsurfError, ValueError):
    """Invalid input to a figure (an unknown file format, a dpi out of range, empty data)."""


class RenderingUnavailable(ArsurfError, RuntimeError):
    """No OpenGL context can be made (no display, no EGL, no OSMesa, no Xvfb)."""


#: what to install when VTK cannot render offscreen (one line; docs/install.rst, "Offscreen rendering")
RENDERING_HINT = (
    "install EGL (Debian/Ubuntu: apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri) or OSMesa "
    "(apt-get install libosmesa6; without root: docs/install.rst, Offscreen rendering), or run under a display"
)


def rendering_failed(what: str, exc: BaseException) -> RenderingUnavailable:
    """The one-line :class:`RenderingUnavailable` for ``what`` failing with ``exc``, saying what to install.

    Examples
    --------
    >>> str(rendering_failed("replay frames", RuntimeError("no context")))[:60]
    'replay frames: rendering failed (RuntimeError: no context); '
    """
    if isinstance(exc, RenderingUnavailable):
        return exc
    first = (str(exc).strip().splitlines() or [""])[0]
    return RenderingUnavailable(f"{what}: rendering failed ({type(exc).__name__}: {first}); {RENDERING_HINT}")


def require(module: str, extra: str, feature: str):
    """Import an optional dependency or raise :class:`MissingDependency` naming the extra.

    Examples
    --------
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
