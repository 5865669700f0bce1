r"""Session files: what the live loop records each tick, in one HDF5 file (h5py).

A session is everything needed to re-run the model offline (:func:`arsurf.replay.replay.replay`):
which scan file (with the SHA-256 of its bytes) and how it was turned into a surface, the tip,
contact law, friction and cantilever of the :class:`~arsurf.model.ARModel`, and per tick the
probe pose, the measured signals and what the loop did.

Schema (format ``arsurf-session``, version 1; SI units throughout)
------------------------------------------------------------------

Root attributes:

===================  ========  ===============================================================
attribute            type      meaning
===================  ========  ===============================================================
``format``           str       ``"arsurf-session"``
``format_version``   int       1 (readers refuse versions they do not know)
``arsurf_version``   str       version of arsurf that wrote the file
``created``          str       UTC time of writing, ISO 8601 (the only non-deterministic field)
``units``            str       ``"SI"`` (m, s, N, rad, Pa, J/m^2; quadrants in volts)
``complete``         bool      True once the writer closed normally; False: recording aborted
``n_ticks``          int64     number of ticks n (every dataset has n rows)
``aborted``          str       only when ``complete`` is False: why the recording stopped
===================  ========  ===============================================================

Group ``/metadata``: one attribute per key, its value a JSON text (:func:`session_metadata`
builds it):

==========================  ===================================================================
key                         JSON value
==========================  ===================================================================
``scan``                    ``{"path", "sha256" (hex of the file bytes), "channel" (str|null),
                            "processing": {"level" (str), "sigma" (m), "inpaint" (bool),
                            "control_shape" ([nu, nv]|null), "smoothing" (float)}}``
``tip_radius``              m
``contact``                 ``{"effective_modulus" (Pa), "work_of_adhesion" (J/m^2),
                            "dugdale_stress" (Pa|null)}`` (Maugis-Dugdale)
``friction``                coefficient mu of the simulated friction
``deform``                  bool, the model dented the surface
``cantilever``              the :class:`~arsurf.force.cantilever.Cantilever` constructor
                            arguments (length, width, thickness, tip_height, youngs_modulus,
                            poisson_ratio, normal_stiffness, torsional_stiffness, beta)
``calibration``             free object (photodiode sensitivities, gains...)
``haptics``                 free object (device, scaling, filter, coupling settings)
``loop_rate``               Hz (nominal rate of the loop), or null
``tubes``                   optional: the nano-objects the loop pushed, as
                            :meth:`arsurf.manipulation.scene.TubeScene.to_metadata` writes
                            them: ``{"tubes": [{"length", "diameter", "x", "y", "angle",
                            "base"}, ...] (the initial poses, m and rad), "friction_per_length"
                            (N/m), "middle_band", "max_substep" (m|null), "max_substeps",
                            "substrate_margin" (m|null)}``. :func:`build_model` then fits the
                            substrate (tube pixels masked and inpainted) and rebuilds the scene
any other key               free JSON, kept as is
==========================  ===================================================================

Group ``/ticks``: one dataset per field, n rows, written without timestamps (so two files with
the same content and ``created`` are byte-identical) and gzip-compressed. A field the loop did
not give for a tick holds the fill value.

========================  ========  ======  =====  ===========================================
dataset                   shape     dtype   fill   meaning
========================  ========  ======  =====  ===========================================
``t``                     (n,)      f8      req.   time of the tick, s
``stylus_position``       (n, 3)    f8      NaN    haptic stylus position, m (device frame)
``stylus_velocity``       (n, 3)    f8      NaN    stylus velocity, m/s
``buttons``               (n,)      i4      0      stylus button bit mask
``probe_position``        (n, 3)    f8      req.   tip-sphere centre C, m (scan frame)
``probe_velocity``        (n, 3)    f8      NaN    tip velocity v, m/s (replay needs it)
``signals``               (n, 2)    f8      NaN    measured (bending, torsion) angles, rad
``quadrants``             (n, 4)    f8      NaN    photodiode quadrants A, B, C, D, V
``force``                 (n, 3)    f8      NaN    force on the tip the loop used, N
``device_force``          (n, 3)    f8      NaN    force commanded to the haptic device, N
``contact_point``         (n, 3)    f8      NaN    closest surface point, m
``contact_normal``        (n, 3)    f8      NaN    unit contact normal (out of the sample)
``depth``                 (n,)      f8      NaN    indentation depth d = R - distance, m
``contact_radius``        (n,)      f8      NaN    Maugis-Dugdale contact radius a, m
``load``                  (n,)      f8      NaN    Maugis-Dugdale load P (> 0 compressive), N
``in_contact``            (n,)      i4      0      1 when the tip touches (MD status 0)
``md_status``             (n,)      i4      -99    MD status: 0 contact, 1 cohesive,
                                                   2 separated, < 0 solver error, -99 not given
``decoupling_flags``      (n,)      i4      0      :class:`~arsurf.force.decoupling.DecouplingFlag`
``tube_poses``            (n, k, 3) f8      NaN    optional, only with a ``tubes`` scene of k
                                                   tubes: each tube's pose after the tick,
                                                   x, y (m), axis angle (rad)
========================  ========  ======  =====  ===========================================

``tube_poses`` is the only optional dataset: the writer adds it when the metadata has a
``tubes`` scene, and readers accept its absence (sessions without nano-objects, and files
written before it existed), so ``format_version`` stays 1. When present its shape is checked
against the scene (k rows of 3 per tick).

Writing is cheap and atomic: :class:`SessionWriter` fills preallocated numpy buffers (doubling
when full) and writes the whole file once, at :meth:`SessionWriter.close`, to ``<path>.part``,
fsyncs it and renames it over ``<path>``, so a crash never leaves a half-written session.

Example
-------
>>> import tempfile, os, numpy as np
>>> from arsurf.force.cantilever import Cantilever
>>> from arsurf.contact.maugis_dugdale import MaugisDugdale
>>> d = tempfile.mkdtemp()
>>> meta = session_metadata(scan={"path": "scan.npz", "sha256": "0" * 64, "channel": None,
...                               "processing": {"level": "plane", "sigma": 0.0, "inpaint": True}},
...                         tip_radius=20e-9, contact=MaugisDugdale(20e-9, 50e9, 0.1),
...                         cantilever=Cantilever(450e-6, 50e-6, 2.5e-6, 15e-6, 169e9, 0.27))
>>> with SessionWriter(os.path.join(d, "s.h5"), meta) as w:
...     for k in range(3):
...         w.append(t=k * 1e-3, probe_position=(1e-7, 1e-7, 3e-8 - k * 1e-9), depth=-1e-8)
>>> s = load_session(os.path.join(d, "s.h5"))
>>> s.n_ticks, s.ticks["probe_position"].shape, bool(np.isnan(s.ticks["force"]).all())
(3, (3, 3), True)
"""
from __future__ import annotations

import dataclasses
import datetime
import hashlib
import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from arsurf.errors import ScanFileNotFound, SessionError, SessionFileNotFound, require

__all__ = [
    "FORMAT",
    "FORMAT_VERSION",
    "SUPPORTED_VERSIONS",
    "TICK_FIELDS",
    "TickField",
    "Session",
    "SessionFileNotFound",
    "SessionWriter",
    "load_session",
    "scan_sha256",
    "session_metadata",
    "contact_fields",
    "build_model",
    "ModelSetup",
    "TUBE_POSES",
]

FORMAT = "arsurf-session"
FORMAT_VERSION = 1
SUPPORTED_VERSIONS = (1,)
#: md_status of a tick for which the loop gave none
MD_STATUS_NOT_GIVEN = -99


@dataclass(frozen=True)
class TickField:
    """One per-tick dataset: name, row width (0: a scalar per tick), dtype, fill value, meaning."""

    name: str
    width: int
    dtype: str
    fill: float
    doc: str

    @property
    def shape_text(self) -> str:
        return "(n,)" if self.width == 0 else f"(n, {self.width})"

    @property
    def row_text(self) -> str:
        return "a scalar" if self.width == 0 else f"{self.width} numbers"


_NAN = math.nan
#: the per-tick datasets of a session, in file order
TICK_FIELDS: tuple[TickField, ...] = (
    TickField("t", 0, "f8", _NAN, "time of the tick, s"),
    TickField("stylus_position", 3, "f8", _NAN, "haptic stylus position, m (device frame)"),
    TickField("stylus_velocity", 3, "f8", _NAN, "stylus velocity, m/s"),
    TickField("buttons", 0, "i4", 0, "stylus button bit mask"),
    TickField("probe_position", 3, "f8", _NAN, "tip-sphere centre, m (scan frame)"),
    TickField("probe_velocity", 3, "f8", _NAN, "tip velocity, m/s"),
    TickField("signals", 2, "f8", _NAN, "measured (bending, torsion) angles, rad"),
    TickField("quadrants", 4, "f8", _NAN, "photodiode quadrants A, B, C, D, V"),
    TickField("force", 3, "f8", _NAN, "force on the tip the loop used, N"),
    TickField("device_force", 3, "f8", _NAN, "force commanded to the haptic device, N"),
    TickField("contact_point", 3, "f8", _NAN, "closest surface point, m"),
    TickField("contact_normal", 3, "f8", _NAN, "unit contact normal"),
    TickField("depth", 0, "f8", _NAN, "indentation depth, m"),
    TickField("contact_radius", 0, "f8", _NAN, "contact radius, m"),
    TickField("load", 0, "f8", _NAN, "Maugis-Dugdale load (> 0 compressive), N"),
    TickField("in_contact", 0, "i4", 0, "1 when the tip touches"),
    TickField("md_status", 0, "i4", MD_STATUS_NOT_GIVEN, "MD status (0 contact, 1 cohesive, 2 separated)"),
    TickField("decoupling_flags", 0, "i4", 0, "DecouplingFlag bits"),
)
#: the optional per-tick dataset of a session with a tube scene: (n, k, 3), k = number of tubes
TUBE_POSES = TickField("tube_poses", 3, "f8", _NAN, "tube poses x, y (m), angle (rad), k rows per tick")
_REQUIRED_TICK = ("t", "probe_position")
_REQUIRED_META = ("scan", "tip_radius", "contact", "friction", "cantilever")
_CANTILEVER_ARGS = ("length", "width", "thickness", "tip_height", "youngs_modulus", "poisson_ratio",
                    "normal_stiffness", "torsional_stiffness", "beta")
_INITIAL_CAPACITY = 1024


def _h5py():
    return require("h5py", "core", "session files")


# ---------------------------------------------------------------------------------------------
# metadata


def scan_sha256(path: str | os.PathLike) -> str:
    """SHA-256 (hex) of a file's bytes, read in 1 MiB blocks.

    Raises
    ------
    ScanFileNotFound
        The file does not exist.

    Example
    -------
    >>> import tempfile, os
    >>> p = os.path.join(tempfile.mkdtemp(), "x.bin")
    >>> _ = open(p, "wb").write(b"abc")
    >>> scan_sha256(p)[:16]
    'ba7816bf8f01cfea'
    """
    p = Path(path)
    if not p.is_file():
        raise ScanFileNotFound(f"scan file {str(p)!r} does not exist (or is not a file); pass the scan the "
                               "session was recorded on")
    h = hashlib.sha256()
    with open(p, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _jsonable(obj: Any, where: str) -> Any:
    """Plain JSON types from numpy scalars/arrays, tuples, paths, dataclasses; finite floats only."""
    if isinstance(obj, Mapping):
        out = {}
        for k, v in obj.items():
            if not isinstance(k, str):
                raise SessionError(f"metadata keys must be strings (got {k!r} in {where})")
            out[k] = _jsonable(v, f"{where}.{k}")
        return out
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return _jsonable(dataclasses.asdict(obj), where)
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v, f"{where}[{i}]") for i, v in enumerate(obj)]
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist(), where)
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        x = float(obj)
        if not math.isfinite(x):
            raise SessionError(f"metadata value {where} is {x!r}: JSON has no NaN/inf; use None for unknown values")
        return x
    if obj is None or isinstance(obj, str):
        return obj
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    raise SessionError(f"metadata value {where} is a {type(obj).__name__} ({obj!r}), which JSON cannot hold; "
                       "pass numbers, strings, booleans, None, lists or dicts")


def session_metadata(*, scan: Mapping | str | os.PathLike, tip_radius: float, contact, cantilever,
                     friction: float = 0.2, deform: bool = True, channel: str | None = None,
                     level: str = "plane", sigma: float = 0.0, inpaint: bool = True,
                     control_shape: tuple[int, int] | None = None, smoothing: float = 0.0,
                     calibration: Mapping | None = None, haptics: Mapping | None = None,
                     loop_rate: float | None = None, **extra) -> dict:
    """The metadata dict of a session, checked and JSON-ready.

    Parameters
    ----------
    scan : path-like or dict
        The scan file (its SHA-256 is computed here, and the processing is taken from
        ``channel``, ``level``, ``sigma``, ``inpaint``, ``control_shape``, ``smoothing``: the
        arguments of :func:`arsurf.scan.prepare.prepare_scan` and :func:`arsurf.fit_surface`), or a
        complete ``scan`` dict as in the schema.
    tip_radius : float, metres
    contact : MaugisDugdale or dict
        The contact law (or ``{"effective_modulus", "work_of_adhesion", "dugdale_stress"}``).
    cantilever : Cantilever or dict
        The cantilever (or its constructor arguments).
    friction : float
        Coefficient of the model's simulated friction.
    deform : bool
        Whether the model dents the surface.
    calibration, haptics : dict, optional
        Free JSON objects.
    loop_rate : float, Hz, optional
    **extra
        More JSON values to keep.

    Returns
    -------
    dict
        Validated metadata (a model can be built from it: :func:`build_model`).

    Raises
    ------
    SessionError
        A required value is missing or invalid, or a value cannot be stored as JSON.
    """
    if isinstance(scan, Mapping):
        scan_meta = dict(scan)
    else:
        scan_meta = {
            "path": os.fspath(scan), "sha256": scan_sha256(scan), "channel": channel,
            "processing": {"level": level, "sigma": sigma, "inpaint": inpaint,
                           "control_shape": control_shape, "smoothing": smoothing},
        }
    if isinstance(contact, Mapping):
        contact_meta = dict(contact)
    else:
        contact_meta = {"effective_modulus": contact.effective_modulus,
                        "work_of_adhesion": contact.work_of_adhesion,
                        "dugdale_stress": contact.dugdale_stress}
    if isinstance(cantilever, Mapping):
        lever_meta = dict(cantilever)
    else:
        lever_meta = {name: getattr(cantilever, name) for name in _CANTILEVER_ARGS}
    meta = {"scan": scan_meta, "tip_radius": tip_radius, "contact": contact_meta, "friction": friction,
            "deform": deform, "cantilever": lever_meta, "calibration": dict(calibration or {}),
            "haptics": dict(haptics or {}), "loop_rate": loop_rate, **extra}
    meta = _jsonable(meta, "metadata")
    check_metadata(meta)
    return meta


def _need(d: Mapping, key: str, where: str):
    if not isinstance(d, Mapping) or key not in d:
        raise SessionError(f"session metadata lacks {where}.{key}; record it with arsurf.replay.session_metadata")
    return d[key]


def check_metadata(meta: Mapping) -> None:
    """Raise :class:`SessionError` unless ``meta`` describes a model that can be rebuilt."""
    if not isinstance(meta, Mapping):
        raise SessionError(f"session metadata must be a dict (got {type(meta).__name__})")
    missing = [k for k in _REQUIRED_META if k not in meta]
    if missing:
        raise SessionError(f"session metadata lacks {missing}; build it with arsurf.replay.session_metadata")
    scan = meta["scan"]
    path = _need(scan, "path", "scan")
    if not isinstance(path, str) or not path:
        raise SessionError(f"metadata scan.path must be a non-empty string (got {path!r})")
    digest = _need(scan, "sha256", "scan")
    if not (isinstance(digest, str) and len(digest) == 64 and all(c in "0123456789abcdef" for c in digest)):
        raise SessionError(f"metadata scan.sha256 must be 64 lowercase hex digits (got {digest!r}); "
                           "compute it with arsurf.replay.scan_sha256(path)")
    channel = scan.get("channel")
    if channel is not None and not isinstance(channel, str):
        raise SessionError(f"metadata scan.channel must be a string or null (got {channel!r})")
    proc = _need(scan, "processing", "scan")
    lv = _need(proc, "level", "scan.processing")
    if not isinstance(lv, str):
        raise SessionError(f"metadata scan.processing.level must be a method name (got {lv!r})")
    sg = _need(proc, "sigma", "scan.processing")
    if isinstance(sg, bool) or not isinstance(sg, (int, float)) or not sg >= 0.0:
        raise SessionError(f"metadata scan.processing.sigma must be >= 0 metres (got {sg!r})")
    ip = _need(proc, "inpaint", "scan.processing")
    if not isinstance(ip, bool):
        raise SessionError(f"metadata scan.processing.inpaint must be true or false (got {ip!r})")
    cs = proc.get("control_shape")
    if cs is not None and not (isinstance(cs, (list, tuple)) and len(cs) == 2
                               and all(isinstance(c, int) and not isinstance(c, bool) and c >= 4 for c in cs)):
        raise SessionError(f"metadata scan.processing.control_shape must be null or two integers >= 4 (got {cs!r})")
    sm = proc.get("smoothing", 0.0)
    if isinstance(sm, bool) or not isinstance(sm, (int, float)) or not sm >= 0.0:
        raise SessionError(f"metadata scan.processing.smoothing must be >= 0 (got {sm!r})")
    lever = meta["cantilever"]
    if not isinstance(lever, Mapping):
        raise SessionError(f"metadata cantilever must be an object of constructor arguments (got {lever!r})")
    unknown = sorted(set(lever) - set(_CANTILEVER_ARGS))
    if unknown:
        raise SessionError(f"metadata cantilever has unknown arguments {unknown}; allowed: {list(_CANTILEVER_ARGS)}")
    for k in ("effective_modulus", "work_of_adhesion"):
        _need(meta["contact"], k, "contact")
    _model_parts(meta)  # builds the contact law and the cantilever: their own checks apply
    _tube_scene(meta)


def _tube_scene(meta: Mapping):
    """The :class:`~arsurf.manipulation.scene.TubeScene` of the metadata (None without ``tubes``)."""
    spec = meta.get("tubes")
    if spec is None:
        return None
    from arsurf.errors import ArsurfError
    from arsurf.manipulation.scene import TubeScene

    try:
        return TubeScene.from_metadata(spec)
    except (ArsurfError, TypeError, ValueError) as exc:
        raise SessionError(f"metadata tubes does not describe a tube scene: {exc}") from exc


def _tube_count(meta: Mapping) -> int | None:
    """Number of tubes of the metadata's scene (None without ``tubes``); metadata checked."""
    spec = meta.get("tubes")
    return None if spec is None else len(spec["tubes"])


def _model_parts(meta: Mapping):
    """(tip_radius, MaugisDugdale, Cantilever, friction, deform) from checked metadata."""
    from arsurf.contact.maugis_dugdale import MaugisDugdale
    from arsurf.errors import ArsurfError
    from arsurf.force.cantilever import Cantilever

    c = meta["contact"]
    try:
        tip_radius = float(meta["tip_radius"])
        md = MaugisDugdale(tip_radius, c["effective_modulus"], c["work_of_adhesion"], c.get("dugdale_stress"))
        lever = Cantilever(**meta["cantilever"])
        friction = float(meta["friction"])
    except (ArsurfError, TypeError, ValueError) as exc:
        raise SessionError(f"the session metadata does not describe a valid model: {exc}") from exc
    if not (math.isfinite(friction) and friction >= 0.0):
        raise SessionError(f"metadata friction must be >= 0 (got {friction!r})")
    return tip_radius, md, lever, friction, bool(meta.get("deform", True))


@dataclass(frozen=True)
class ModelSetup:
    """What :func:`build_model` made: the processed scan (the substrate when there is a tube scene),
    the fitted (live) surface, the model, and the tube scene (None without ``tubes`` metadata)."""

    scan: Any
    surface: Any
    model: Any
    scene: Any = None


def build_model(metadata: Mapping, scan_path: str | os.PathLike | None = None) -> ModelSetup:
    """Rebuild the recording's model: prepare the scan as recorded, fit it, make the ARModel.

    The steps are exactly those of the recording (:func:`arsurf.scan.prepare.prepare_scan` with the
    recorded channel, levelling, smoothing and inpainting, then :func:`arsurf.fit_surface`
    with the recorded control shape and smoothing). A live loop that builds its model with this
    function is guaranteed to be replayed bit for bit.

    Parameters
    ----------
    metadata : dict
        Session metadata (:func:`session_metadata`).
    scan_path : path-like, optional
        The scan file; default ``metadata["scan"]["path"]``. Its hash is not checked here
        (:func:`arsurf.replay.replay.replay` does).

    Returns
    -------
    ModelSetup
    """
    check_metadata(metadata)
    from arsurf.scan.prepare import prepare_scan  # the one definition of the scan preprocessing
    from arsurf.model import ARModel
    from arsurf.spline.fit import fit_surface

    scan_meta = metadata["scan"]
    proc = scan_meta["processing"]
    path = scan_meta["path"] if scan_path is None else scan_path
    scan = prepare_scan(path, scan_meta.get("channel"), proc["level"], float(proc["sigma"]), bool(proc["inpaint"]))
    scene = _tube_scene(metadata)
    if scene is not None:  # the tubes are scene objects: the spline holds only the substrate
        scan = scene.substrate(scan)
    cs = proc.get("control_shape")
    surface = fit_surface(scan, control_shape=tuple(cs) if cs is not None else None,
                          smoothing=float(proc.get("smoothing", 0.0)))
    tip_radius, md, lever, friction, deform = _model_parts(metadata)
    model = ARModel(surface, tip_radius, md, lever, friction=friction, deform=deform)
    return ModelSetup(scan, surface, model, scene)


def contact_fields(tick) -> dict:
    """The contact fields of :meth:`SessionWriter.append` from a :class:`~arsurf.model.ModelTick`.

    Example
    -------
    >>> # writer.append(t=t, probe_position=c, probe_velocity=v, force=f, **contact_fields(tick))
    """
    return {"contact_point": tick.point, "contact_normal": tick.normal, "depth": tick.depth,
            "contact_radius": tick.contact_radius, "load": tick.load, "in_contact": int(tick.in_contact),
            "md_status": tick.md_status, "decoupling_flags": tick.decoupling_flags}


# ---------------------------------------------------------------------------------------------
# writing


def _fsync_dir(path: Path) -> None:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:  # pragma: no cover - platforms without directory fds (Windows)
        return
    try:
        os.fsync(fd)
    except OSError:  # pragma: no cover
        pass
    finally:
        os.close(fd)


def write_h5(path: str | os.PathLike, attrs: Mapping[str, Any], metadata: Mapping[str, Any],
             datasets: Mapping[str, np.ndarray]) -> Path:
    """Write root ``attrs``, ``/metadata`` (JSON per key) and ``/ticks/<name>`` datasets atomically.

    The file goes to ``<path>.part``, is fsynced and renamed over ``path``; datasets carry no
    timestamps, so equal inputs give equal bytes. Used for sessions and replay outputs.
    """
    h5py = _h5py()
    path = Path(path)
    part = path.with_name(path.name + ".part")
    try:
        with h5py.File(part, "w") as f:
            for key, value in attrs.items():
                f.attrs[key] = value
            mg = f.create_group("metadata")
            for key in sorted(metadata):
                mg.attrs[key] = json.dumps(metadata[key], sort_keys=True, allow_nan=False)
            tg = f.create_group("ticks")
            for name, data in datasets.items():
                data = np.ascontiguousarray(data)
                opts = {"compression": "gzip", "compression_opts": 4, "shuffle": True} if data.shape[0] else {}
                tg.create_dataset(name, data=data, track_times=False, **opts)
        with open(part, "rb+") as fh:
            os.fsync(fh.fileno())
        os.replace(part, path)
    except BaseException:
        if part.exists():
            part.unlink()
        raise
    _fsync_dir(path.parent if str(path.parent) else Path("."))
    return path


def _utc_now() -> str:
    return datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")


class SessionWriter:
    """Record a session tick by tick; write it atomically at :meth:`close`.

    Parameters
    ----------
    path : path-like
        The session file (``.h5``); written only at :meth:`close`, via ``<path>.part``.
    metadata : dict
        Session metadata (:func:`session_metadata`); checked here, so a recording that could
        not be replayed fails before it starts.
    capacity : int
        Initial number of ticks the buffers hold (they double when full).
    created : str, optional
        The ``created`` attribute (default: the UTC time at :meth:`close`); pass a fixed value
        to make the file byte-reproducible.

    Notes
    -----
    :meth:`append` costs one numpy row assignment per given field (a few microseconds in all,
    no allocation except when the buffers double). Used as a context manager, the file is
    written at exit; if the block raised, it is still written but marked ``complete=False``
    (with the reason in ``aborted``), and :func:`load_session` refuses it unless asked.

    Example
    -------
    >>> # with SessionWriter("run.h5", meta) as w:
    >>> #     w.append(t=t, probe_position=c, probe_velocity=v, signals=s, force=f)
    """

    def __init__(self, path: str | os.PathLike, metadata: Mapping, *, capacity: int = _INITIAL_CAPACITY,
                 created: str | None = None):
        self.path = Path(path)
        if self.path.is_dir():
            raise SessionError(f"session path {str(self.path)!r} is a directory; pass a file name such as run.h5")
        if not self.path.parent.is_dir():
            raise SessionError(f"the folder of the session file {str(self.path)!r} does not exist; create it first")
        self.metadata = _jsonable(metadata, "metadata")
        check_metadata(self.metadata)
        capacity = int(capacity)
        if capacity < 1:
            raise SessionError(f"`capacity` must be >= 1 tick (got {capacity})")
        self._created = created
        self._n = 0
        self._cap = capacity
        k = _tube_count(self.metadata)
        # field -> row shape; tube_poses only with a tube scene (k rows of x, y, angle)
        self._rows = {f.name: (() if f.width == 0 else (f.width,)) for f in TICK_FIELDS}
        self._fields = {f.name: f for f in TICK_FIELDS}
        if k is not None:
            self._rows[TUBE_POSES.name] = (k, TUBE_POSES.width)
            self._fields[TUBE_POSES.name] = TUBE_POSES
        self._buf = {name: self._alloc(f, capacity) for name, f in self._fields.items()}
        self._closed = False

    def _alloc(self, f: TickField, n: int) -> np.ndarray:
        return np.full((n, *self._rows[f.name]), f.fill, dtype=np.dtype(f.dtype))

    @property
    def n_ticks(self) -> int:
        """Ticks appended so far."""
        return self._n

    def _grow(self) -> None:
        cap = 2 * self._cap
        for f in self._fields.values():
            new = self._alloc(f, cap)
            new[: self._n] = self._buf[f.name][: self._n]
            self._buf[f.name] = new
        self._cap = cap

    def _clear_row(self, i: int) -> None:
        for f in self._fields.values():
            self._buf[f.name][i] = f.fill

    def append(self, **fields) -> None:
        """Record one tick.

        Parameters
        ----------
        **fields
            ``t`` (s) and ``probe_position`` ((3,) m) are required; every other field of
            :data:`TICK_FIELDS` is optional (missing: NaN, or the integer fill value), and so is
            ``tube_poses`` ((k, 3): x, y, angle per tube) when the metadata has a tube scene.

        Raises
        ------
        SessionError
            Unknown field name, wrong shape, missing ``t``/``probe_position``, writer closed.
        """
        if self._closed:
            raise SessionError(f"the session writer of {str(self.path)!r} is closed; open a new one")
        i = self._n
        if i == self._cap:
            self._grow()
        buf = self._buf
        try:
            for name, value in fields.items():
                buf[name][i] = value
        except KeyError:
            self._clear_row(i)
            unknown = sorted(set(fields) - set(buf))
            hint = (" (tube_poses needs a tube scene in the metadata: tubes=TubeScene.to_metadata())"
                    if TUBE_POSES.name in unknown else "")
            raise SessionError(f"unknown session field(s) {unknown}; the fields are "
                               f"{list(self._fields)}{hint}") from None
        except (ValueError, TypeError) as exc:
            self._clear_row(i)
            bad = self._fields[name]
            rows = bad.row_text if name != TUBE_POSES.name else f"{self._rows[name][0]} x 3 numbers"
            raise SessionError(f"session field {name!r} must be {rows} per tick "
                               f"({bad.doc}); got {value!r}: {exc}") from None
        if "t" not in fields or "probe_position" not in fields:
            self._clear_row(i)
            raise SessionError(f"every tick needs `t` (s) and `probe_position` ((3,) m); got only {sorted(fields)}")
        self._n = i + 1

    def close(self, complete: bool = True, reason: str = "") -> Path:
        """Write the file atomically (once; later calls return the path) and return its path."""
        if self._closed:
            return self.path
        from arsurf import __version__

        n = self._n
        attrs = {"format": FORMAT, "format_version": np.int64(FORMAT_VERSION), "arsurf_version": __version__,
                 "created": self._created if self._created is not None else _utc_now(), "units": "SI",
                 "complete": np.bool_(complete), "n_ticks": np.int64(n)}
        if not complete:
            attrs["aborted"] = reason or "the recording stopped before the writer was closed"
        write_h5(self.path, attrs, self.metadata, {name: self._buf[name][:n] for name in self._fields})
        self._closed = True
        return self.path

    def __enter__(self) -> "SessionWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.close(complete=False, reason=f"{exc_type.__name__}: {exc}")


# ---------------------------------------------------------------------------------------------
# reading


@dataclass
class Session:
    """A loaded session (or replay output): metadata, per-tick arrays and root attributes."""

    metadata: dict
    ticks: dict
    n_ticks: int
    attrs: dict = field(default_factory=dict)
    path: Path | None = None


def _attr(value):
    if isinstance(value, bytes):
        return value.decode("utf-8", "replace")
    if isinstance(value, np.generic):
        return value.item()
    return value


def read_h5(path: str | os.PathLike, *, fmt: str, versions: tuple[int, ...], fields: tuple[TickField, ...],
            allow_incomplete: bool = False, what: str = "session") -> Session:
    """Read a file written by :func:`write_h5` and check it against ``fields`` (SessionError if bad)."""
    h5py = _h5py()
    p = Path(path)
    if not p.exists():
        raise SessionFileNotFound(f"{what} file {str(p)!r} does not exist")
    if p.is_dir():
        raise SessionError(f"{what} path {str(p)!r} is a directory, not a {what} file")
    try:
        f = h5py.File(p, "r")
    except OSError as exc:
        raise SessionError(f"{str(p)!r} is not a readable HDF5 {what} file (truncated, corrupt or another "
                           f"format): {exc}") from exc
    try:
        with f:
            attrs = {k: _attr(f.attrs[k]) for k in f.attrs}
            got = attrs.get("format")
            if got != fmt:
                raise SessionError(f"{str(p)!r} is not an {fmt} file (its format attribute is {got!r}); "
                                   f"record sessions with arsurf.replay.SessionWriter")
            version = attrs.get("format_version")
            if isinstance(version, bool) or not isinstance(version, int) or version not in versions:
                raise SessionError(f"{str(p)!r} has format_version {version!r}, which this arsurf cannot read "
                                   f"(supported versions: {', '.join(map(str, versions))}); "
                                   "upgrade arsurf or re-record the session")
            complete = attrs.get("complete")
            if complete is not True and not allow_incomplete:
                why = attrs.get("aborted", "the writer was never closed")
                raise SessionError(f"{what} {str(p)!r} is incomplete (complete={complete!r}: {why}); "
                                   "pass allow_incomplete=True to read the ticks it holds")
            if "metadata" not in f or "ticks" not in f:
                absent = [g for g in ("metadata", "ticks") if g not in f]
                raise SessionError(f"{what} {str(p)!r} lacks the group(s) {absent}")
            metadata = {}
            for key in f["metadata"].attrs:
                text = _attr(f["metadata"].attrs[key])
                try:
                    metadata[key] = json.loads(text)
                except (TypeError, ValueError) as exc:
                    raise SessionError(f"metadata {key!r} of {str(p)!r} is not valid JSON ({exc})") from exc
            g = f["ticks"]
            absent = [fl.name for fl in fields if fl.name not in g]
            if absent:
                raise SessionError(f"{what} {str(p)!r} lacks the per-tick dataset(s) {absent}")
            ticks = {}
            for fl in fields:
                ds = g[fl.name]
                if not isinstance(ds, h5py.Dataset):
                    raise SessionError(f"/ticks/{fl.name} in {str(p)!r} is not a dataset")
                want = np.dtype(fl.dtype)
                if ds.dtype.kind != want.kind:
                    raise SessionError(f"/ticks/{fl.name} in {str(p)!r} has dtype {ds.dtype}, expected {want}")
                rows = ds.shape[1:] if ds.ndim else None
                if rows != (() if fl.width == 0 else (fl.width,)):
                    raise SessionError(f"/ticks/{fl.name} in {str(p)!r} has shape {ds.shape}, expected {fl.shape_text}")
                ticks[fl.name] = ds[()].astype(want, copy=False)
            for name in g:  # extra datasets are kept as they are
                if name not in ticks and isinstance(g[name], h5py.Dataset):
                    ticks[name] = g[name][()]
    except SessionError:
        raise
    except (OSError, KeyError, RuntimeError, ValueError) as exc:  # h5py's errors on damaged files
        raise SessionError(f"{str(p)!r} is damaged (truncated or corrupt HDF5): {exc}") from exc
    lengths = {name: a.shape[0] for name, a in ticks.items()}
    n = attrs.get("n_ticks")
    if len(set(lengths.values())) > 1 or (lengths and n not in set(lengths.values())):
        raise SessionError(f"{what} {str(p)!r} is inconsistent: n_ticks={n!r} but the datasets have "
                           f"lengths {lengths}")
    return Session(metadata=metadata, ticks=ticks, n_ticks=int(n), attrs=attrs, path=p)


def load_session(path: str | os.PathLike, *, allow_incomplete: bool = False) -> Session:
    """Read and check a session file.

    Parameters
    ----------
    path : path-like
    allow_incomplete : bool
        Accept a session whose recording was aborted (``complete`` False).

    Returns
    -------
    Session
        ``metadata`` (dict), ``ticks`` (dict name -> array, see :data:`TICK_FIELDS`; plus
        ``tube_poses`` (n, k, 3) when the session recorded a tube scene),
        ``n_ticks``, ``attrs`` (root attributes), ``path``.

    Raises
    ------
    SessionError
        Missing file (:class:`SessionFileNotFound`), not HDF5 or truncated, another format, an
        unknown ``format_version``, missing datasets or wrong shapes, datasets of different
        lengths, an incomplete recording, metadata that cannot rebuild the model.
    """
    s = read_h5(path, fmt=FORMAT, versions=SUPPORTED_VERSIONS, fields=TICK_FIELDS,
                allow_incomplete=allow_incomplete)
    try:
        check_metadata(s.metadata)
    except SessionError as exc:
        raise SessionError(f"session {str(path)!r}: {exc}") from exc
    poses = s.ticks.get(TUBE_POSES.name)
    if poses is not None:  # optional: checked against the scene when present
        k = _tube_count(s.metadata)
        if k is None or poses.dtype.kind != "f" or poses.shape != (s.n_ticks, k, 3):
            raise SessionError(f"session {str(path)!r}: /ticks/tube_poses has shape {poses.shape} and dtype "
                               f"{poses.dtype}, expected float ({s.n_ticks}, k, 3) with k the number of tubes of "
                               f"the metadata's tube scene ({'none' if k is None else k})")
    return s
