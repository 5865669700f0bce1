"""arsurf: an augmented-reality surface-model engine for AFM nanomanipulation.

A scanned height map is levelled, smoothed and fitted with a bicubic B-spline; a spherical tip
is projected onto it (Newton), dents it (Maugis-Dugdale), and the contact normal turns the two
measured cantilever angles into a 3D force for a haptic loop and a 3D view.

The public names below are imported lazily (PEP 562), so ``import arsurf`` is cheap, compiles no
kernel and never imports the viewer (pyvista/VTK).

Examples
--------
>>> import arsurf
>>> scan = arsurf.synthetic.sinusoid(shape=(32, 32), pixel=10e-9, amplitude=5e-9, period=160e-9)
>>> surface = arsurf.fit_surface(scan)
>>> contact = arsurf.collide(surface, center=(150e-9, 150e-9, 30e-9), radius=20e-9)
"""
from __future__ import annotations

import hashlib
import importlib
import os
import sys
from pathlib import Path

__version__ = "0.1.0"


def _configure_numba_cache() -> None:
    """Cache compiled kernels in a folder named after a hash of arsurf's sources.

    numba's ``cache=True`` checks only the timestamp of the file that defines a kernel, so a
    kernel that inlines another module's kernel keeps the stale machine code after that module
    changes. Keying the cache folder on the sources recompiles everything once after any change
    (an upgrade, a local edit) and never runs stale code. A user-set ``NUMBA_CACHE_DIR`` wins.
    """
    if "NUMBA_CACHE_DIR" in os.environ:
        return
    digest = hashlib.sha256()
    for path in sorted(Path(__file__).resolve().parent.rglob("*.py")):
        digest.update(path.read_bytes())
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    folder = str(base / "arsurf" / f"numba-{__version__}-{digest.hexdigest()[:16]}")
    os.environ["NUMBA_CACHE_DIR"] = folder
    if "numba" in sys.modules:  # numba read its config already: set it there too
        sys.modules["numba"].config.CACHE_DIR = folder


_configure_numba_cache()

from arsurf import _logging  # noqa: E402,F401  (the "arsurf" logger and its NullHandler, before any module logs)

# public name -> module that defines it (the pipeline order: scan, spline, contact, force,
# haptics, manipulation, replay)
_EXPORTS = {
    # errors
    "ArsurfError": "arsurf.errors",
    "ScanError": "arsurf.errors",
    # scan
    "Scan": "arsurf.scan.scan",
    "load_scan": "arsurf.scan.io",
    "save_scan": "arsurf.scan.io",
    "level": "arsurf.scan.level",
    "smooth": "arsurf.scan.smooth",
    "prepare_scan": "arsurf.scan.prepare",
    "inpaint": "arsurf.scan.inpaint",
    "dropout_mask": "arsurf.scan.inpaint",
    "detect_format": "arsurf.scan.io",
    # spline
    "BSplineSurface": "arsurf.spline.surface",
    "fit_surface": "arsurf.spline.fit",
    "save_surface": "arsurf.spline.storage",
    "load_surface": "arsurf.spline.storage",
    # contact
    "Projection": "arsurf.contact.projection",
    "Contact": "arsurf.contact.projection",
    "project": "arsurf.contact.projection",
    "project_many": "arsurf.contact.projection",
    "collide": "arsurf.contact.projection",
    "collide_many": "arsurf.contact.projection",
    "Projector": "arsurf.contact.projection",
    "projector": "arsurf.contact.projection",
    "refresh_region": "arsurf.contact.projection",
    "Hertz": "arsurf.contact.mechanics",
    "DMT": "arsurf.contact.mechanics",
    "JKR": "arsurf.contact.mechanics",
    "MaugisDugdale": "arsurf.contact.maugis_dugdale",
    "ContactState": "arsurf.contact.mechanics",
    "work_of_adhesion": "arsurf.contact.materials",
    "Material": "arsurf.contact.materials",
    "MATERIALS": "arsurf.contact.materials",
    "effective_modulus": "arsurf.contact.materials",
    # force
    "Cantilever": "arsurf.force.cantilever",
    "ForceEstimate": "arsurf.force.decoupling",
    "decouple": "arsurf.force.decoupling",
    "decouple_by_motion": "arsurf.force.decoupling",
    "decouple_many": "arsurf.force.decoupling",
    "DecouplingFlag": "arsurf.force.decoupling",
    "Photodiode": "arsurf.force.photodiode",
    "signal_to_haptic_force_gain": "arsurf.force.haptic_gains",
    "Deformer": "arsurf.contact.deformation",
    # the model and the haptic loop
    "ARModel": "arsurf.model",
    "HapticLoop": "arsurf.haptics.loop",
    "LoopConfig": "arsurf.haptics.loop",
    "Device": "arsurf.haptics.device",
    "DeviceInfo": "arsurf.haptics.device",
    "DeviceState": "arsurf.haptics.device",
    "VirtualDevice": "arsurf.haptics.virtual_device",
    "HandModel": "arsurf.haptics.virtual_device",
    "ReplayDevice": "arsurf.haptics.replay_device",
    "UdpBridgeDevice": "arsurf.haptics.udp_bridge",
    "PositionScaling": "arsurf.haptics.scaling",
    "ForceScaling": "arsurf.haptics.scaling",
    "LowPass": "arsurf.haptics.filters",
    "ButterworthLowPass": "arsurf.haptics.filters",
    "check_forward_euler": "arsurf.haptics.filters",
    "DirectCoupling": "arsurf.haptics.coupling",
    "ForcePositionCoupling": "arsurf.haptics.coupling",
    "check_gains": "arsurf.haptics.gains",
    "suggest_gains": "arsurf.haptics.gains",
    "SafetyLayer": "arsurf.haptics.safety",
    "Scheduler": "arsurf.haptics.scheduler",
    "make_device": "arsurf.haptics.backends",
    # manipulation
    "Nanotube": "arsurf.manipulation.nanotube",
    "push_tube": "arsurf.manipulation.nanotube",
    "rotation_centre": "arsurf.manipulation.nanotube",
    "plan_z_pushes": "arsurf.manipulation.z_strategy",
    "RollingProbe": "arsurf.manipulation.sphere_rolling",
    "SphereRolling": "arsurf.manipulation.sphere_rolling",
    "LSPB": "arsurf.instrument.lspb",
    "VirtualAFM": "arsurf.instrument.instrument",
    "engage": "arsurf.instrument.engage",
    "TubeScene": "arsurf.manipulation.scene",
    "rigid_motion": "arsurf.manipulation.scene",
    # export
    "surface_mesh": "arsurf.export",
    "export_surface": "arsurf.export",
    # sessions
    "SessionWriter": "arsurf.sessions.writer",
    "load_session": "arsurf.sessions.reader",
    "recover_session": "arsurf.sessions.recover",
    "replay_session": "arsurf.replay.replay",  # arsurf.replay is the subpackage
    "run_live": "arsurf.live",
    # model assembly
    "PRESETS": "arsurf.assembly",
    "Preset": "arsurf.assembly",
    "preset_metadata": "arsurf.assembly",
    "session_metadata": "arsurf.assembly",
    "build_model": "arsurf.assembly",
    "build_loop": "arsurf.assembly",
    "make_model": "arsurf.assembly",
    "scan_sha256": "arsurf.assembly",
}
_SUBMODULES = {"synthetic": "arsurf.scan.synthetic", "meshes": "arsurf.meshes"}

__all__ = sorted([*_EXPORTS, *_SUBMODULES])


def __getattr__(name: str):
    if name in _EXPORTS:
        value = getattr(importlib.import_module(_EXPORTS[name]), name)
    elif name in _SUBMODULES:
        value = importlib.import_module(_SUBMODULES[name])
    else:
        raise AttributeError(f"module 'arsurf' has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__():
    return __all__
