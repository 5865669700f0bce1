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

Group ``/metadata``: one attribute per key, its value a JSON text (:func:`arsurf.assembly.session_metadata`
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
                            "substrate_margin" (m|null)}``. :func:`arsurf.assembly.build_model` then fits the
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

Examples
--------
>>> import tempfile, os, numpy as np
>>> from arsurf.force.cantilever import Cantilever
>>> from arsurf.contact.maugis_dugdale import MaugisDugdale
>>> d = tempfile.mkdtemp()
>>> from arsurf.assembly import session_metadata
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

import datetime
import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from arsurf.assembly import _jsonable, check_metadata, tube_count
from arsurf.errors import SessionError, SessionFileNotFound, require

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
    "contact_fields",
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
_INITIAL_CAPACITY = 1024


def _h5py():
    return require("h5py", "core", "session files")


def contact_fields(tick) -> dict:
    """The contact fields of :meth:`SessionWriter.append` from a :class:`~arsurf.model.ModelTick`.

    Examples
    --------
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
        Session metadata (:func:`arsurf.assembly.session_metadata`); checked here, so a recording that could
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

    Examples
    --------
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
        k = tube_count(self.metadata)
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
        k = tube_count(s.metadata)
        if k is None or poses.dtype.kind != "f" or poses.shape != (s.n_ticks, k, 3):
            raise SessionError(f"session {str(path)!r}: /ticks/tube_poses has shape {poses.shape} and dtype "
                               f"{poses.dtype}, expected float ({s.n_ticks}, k, 3) with k the number of tubes of "
                               f"the metadata's tube scene ({'none' if k is None else k})")
    return s
