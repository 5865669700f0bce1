r"""Session files: what the live loop records each tick, in one HDF5 file (h5py).

A session is everything needed to re-run the model offline (:func:`arsurf.replay.replay.replay`):
which scan file (with the SHA-256 of its bytes) and how it was turned into a surface, the tip,
contact law, friction and cantilever of the :class:`~arsurf.model.ARModel`, and per tick the
probe pose, the measured signals and what the loop did.

Schema (format ``arsurf-session``, version 2; SI units throughout)
------------------------------------------------------------------

Root attributes:

===================  ========  ===============================================================
attribute            type      meaning
===================  ========  ===============================================================
``format``           str       ``"arsurf-session"``
``format_version``   int       2 (1: written before checksums; readers refuse versions they do
                               not know)
``arsurf_version``   str       version of arsurf that wrote the file
``created``          str       UTC time of writing, ISO 8601 (the only non-deterministic field)
``units``            str       ``"SI"`` (m, s, N, rad, Pa, J/m^2; quadrants in volts)
``complete``         bool      True once the writer closed normally; False: recording aborted
``n_ticks``          int64     number of ticks n (every dataset has n rows)
``aborted``          str       only when ``complete`` is False: why the recording stopped
``dropped_ticks``    int64     ticks the recorder dropped because the disk fell behind (0)
``checksums``        str       JSON ``{"algorithm": "sha256", "attrs": hex, "metadata": hex,
                               "ticks/<name>": hex, ...}``: SHA-256 of the other root attributes
                               (canonical JSON), of the ``/metadata`` texts (canonical JSON) and
                               of each dataset (dtype, shape, then its C-order bytes); version 2
===================  ========  ===============================================================

The file is *sealed* (:mod:`arsurf.replay.sealed`): its first 512 bytes (the HDF5 user block)
hold its length and a SHA-256 of all its bytes.

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
``material``                optional: the material map the model looked E* and w up in
                            (:meth:`arsurf.contact.material_map.MaterialMap.to_metadata`):
                            ``{"channels": {role: channel name}, "units": {role: unit} (given for
                            a file that does not state them), "conversion": {...}
                            (:class:`~arsurf.contact.material_conversion.MaterialConversion`, SI),
                            "offset": [x0, y0] (m), "processing": {"sigma" (m), "smoothing",
                            "control_shape"}, "sha256" (the map's hash), "path" (null: the scan
                            file), "file_sha256" (with a path)}``. :func:`arsurf.assembly.build_model`
                            rebuilds the map and refuses one whose hash differs
any other key               free JSON, kept as is
==========================  ===================================================================

Group ``/ticks``: one dataset per field, n rows, written without timestamps (so two files with
the same content and ``created`` are byte-identical) and gzip-compressed. A field the loop did
not give for a tick holds the fill value. Each dataset carries its SI unit in a ``units``
attribute (:mod:`arsurf.units`: the unit named last in the table below, ``"1"`` for the
dimensionless ones, ``"m,m,rad"`` for ``tube_poses``); readers check it when present and take
the table's unit for files written before it existed (:attr:`Session.units`).

========================  ========  ======  =====  ===========================================
dataset                   shape     dtype   fill   meaning
========================  ========  ======  =====  ===========================================
``t``                     (n,)      f8      req.   time of the tick, s
``stylus_position``       (n, 3)    f8      NaN    haptic stylus position, m (device frame)
``stylus_velocity``       (n, 3)    f8      NaN    stylus velocity, m/s
``buttons``               (n,)      i4      0      stylus button bit mask
``probe_position``        (n, 3)    f8      req.   target tip centre C (the scaled stylus), m (scan frame)
``probe_velocity``        (n, 3)    f8      NaN    velocity of C, m/s
``tip_position``          (n, 3)    f8      NaN    tip centre behind the virtual coupling, m
``energy``                (n,)      f8      NaN    passivity observer's port energy, J
``passivity_damping``     (n,)      f8      NaN    damping the passivity controller added, N s/m
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
``safety_flags``          (n,)      i4      -1     optional: the haptic loop's safety flag bits
                                                   after the tick (:mod:`arsurf.status`:
                                                   SATURATED, WATCHDOG, PASSIVITY...), -1 not
                                                   recorded
``tube_poses``            (n, k, 3) f8      NaN    optional, only with a ``tubes`` scene of k
                                                   tubes: each tube's pose after the tick,
                                                   x, y (m), axis angle (rad)
``instrument_position``   (n, 3)    f8      NaN    optional, only with an ``instrument`` in the
                                                   metadata (a session driven by an AFM,
                                                   :mod:`arsurf.replay.instrument_session`): the
                                                   tip position the instrument measured, m (scan
                                                   frame, tip-sphere centre)
========================  ========  ======  =====  ===========================================

``safety_flags``, ``tube_poses`` and ``instrument_position`` are the optional datasets: the
writer always adds the first, the second when the metadata has a ``tubes`` scene and the third
when it has an ``instrument``; readers accept their absence (files written before they existed,
sessions without nano-objects or an instrument), so ``format_version`` does not change. When
present, ``safety_flags`` must be integers, one per tick, and the shapes of the others are
checked (k rows of 3 per tick for the tubes, 3 per tick for the instrument).

Recording survives the process dying
------------------------------------
:class:`SessionWriter` streams the ticks, while it records, into ``<path>.journal``
(:mod:`arsurf.replay.journal`: an append-only file of self-checking records, written and
fsynced by a background thread at least every ``flush_interval`` = 50 ms; why a journal
rather than HDF5 SWMR or segment files is argued there). :meth:`SessionWriter.append` writes
one row into a preallocated chunk and returns: O(1), no allocation, never blocks (when the disk
falls behind by more than the chunk pool, ticks are dropped, counted in ``dropped_ticks``).
Memory stays flat for any session length. :meth:`SessionWriter.close` merges the journal into
an exclusive temporary beside ``<path>`` (:func:`arsurf._files.atomic_write`: created
``O_EXCL | O_NOFOLLOW`` under an unpredictable name; gzip, checksums, seal), fsyncs it, renames it
over ``<path>`` (a symbolic link there is refused) and deletes the journal. If the process is killed (SIGKILL, crash, power cut) the journal remains:
:func:`load_session` with ``allow_incomplete=True`` (``arsurf replay --allow-incomplete``) reads
every tick of its intact records - everything appended more than ~50 ms (plus one write) before
the kill - and :func:`recover_session` turns it into a session file marked incomplete. With
``handle_signals=True`` (the process owns the recording, as the command line does) SIGTERM and
SIGINT unwind the recording block and the file is closed with every tick, marked incomplete
with the signal as the reason.

Reading never crashes, hangs or explodes
----------------------------------------
:func:`load_session` refuses, with a :class:`~arsurf.errors.SessionError` naming what is wrong,
anything that is not exactly what a writer wrote:

1. the seal is checked (length and SHA-256 of every byte) before libhdf5 parses anything, and
   libhdf5 then parses the checked bytes from memory: a bit flip, truncation or overwrite
   anywhere is refused there;
2. the schema is checked before any array is read: attribute types, format and version, groups,
   dataset names, dtypes, row shapes, every length against ``n_ticks``, and the total size
   against what the file can hold (gzip inflates at most ~1032x);
3. the arrays are read and compared with the ``checksums`` (then the metadata must rebuild a
   model).

Guarantees of the Python API: a sealed file is read in-process and any damage to it is refused
before libhdf5 sees it. A file without a seal (written by arsurf before the seal existed,
``format_version`` 1, or by another program) is read by default (``isolate="auto"``) in a child
process with time and memory limits (:func:`arsurf.replay.sealed.run_isolated`), so a libhdf5
crash or hang on it becomes a SessionError; ``isolate=True`` does that for every file (a file
crafted to carry a valid seal is then harmless too) and is what ``arsurf replay`` uses;
``isolate=False`` reads unsealed files in-process (trusted files, no child process). Version 1
files load with ``Session.verified`` False: they carry no checksums.

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
>>> s.n_ticks, s.ticks["probe_position"].shape, bool(np.isnan(s.ticks["force"]).all()), s.verified
(3, (3, 3), True, True)
"""
from __future__ import annotations

import atexit
import datetime
import hashlib
import json
import logging
import math
import os
import re
import signal
import stat
import threading
import weakref
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from arsurf._files import atomic_write, check_regular, check_target, read_regular
from arsurf._h5safe import GZIP_LIMIT, open_hdf5
from arsurf.assembly import _jsonable, check_metadata, tube_count
from arsurf.errors import RecordingInterrupted, SessionError, SessionFileNotFound, require
from arsurf.replay import journal as _journal
from arsurf.replay.sealed import SEAL_SIZE, check_superblock, read_sealed, run_isolated, seal_open
from arsurf.units import UNITS_ATTR

_log = logging.getLogger("arsurf.session")

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
    "recover_session",
    "journal_path",
    "contact_fields",
    "record_loop_tick",
    "TUBE_POSES",
    "SAFETY_FLAGS",
    "INSTRUMENT_POSITION",
]

FORMAT = "arsurf-session"
FORMAT_VERSION = 2
SUPPORTED_VERSIONS = (1, 2)
#: versions whose files must carry ``checksums`` (older ones load unverified)
_CHECKSUMMED_FROM = 2
#: md_status of a tick for which the loop gave none
MD_STATUS_NOT_GIVEN = -99


@dataclass(frozen=True)
class TickField:
    """One per-tick dataset: name, row width (0: a scalar per tick), dtype, fill value, meaning and
    SI unit (the dataset's ``units`` attribute, :mod:`arsurf.units`: ``"1"`` dimensionless, one unit
    per column where they differ)."""

    name: str
    width: int
    dtype: str
    fill: float
    doc: str
    unit: str = "1"

    @property
    def shape_text(self) -> str:
        return "(n,)" if self.width == 0 else f"(n, {self.width})"

    @property
    def row_text(self) -> str:
        return "a scalar" if self.width == 0 else f"{self.width} numbers"

    @property
    def row_shape(self) -> tuple:
        return () if self.width == 0 else (self.width,)


_NAN = math.nan
#: the per-tick datasets of a session, in file order
TICK_FIELDS: tuple[TickField, ...] = (
    TickField("t", 0, "f8", _NAN, "time of the tick, s", "s"),
    TickField("stylus_position", 3, "f8", _NAN, "haptic stylus position, m (device frame)", "m"),
    TickField("stylus_velocity", 3, "f8", _NAN, "stylus velocity, m/s", "m/s"),
    TickField("buttons", 0, "i4", 0, "stylus button bit mask"),
    TickField("probe_position", 3, "f8", _NAN, "tip-sphere centre, m (scan frame)", "m"),
    TickField("probe_velocity", 3, "f8", _NAN, "tip velocity, m/s", "m/s"),
    TickField("tip_position", 3, "f8", _NAN, "tip centre behind the virtual coupling, m", "m"),
    TickField("energy", 0, "f8", _NAN, "passivity observer's port energy, J", "J"),
    TickField("passivity_damping", 0, "f8", _NAN, "damping the passivity controller added, N s/m", "N s/m"),
    TickField("signals", 2, "f8", _NAN, "measured (bending, torsion) angles, rad", "rad"),
    TickField("quadrants", 4, "f8", _NAN, "photodiode quadrants A, B, C, D, V", "V"),
    TickField("force", 3, "f8", _NAN, "force on the tip the loop used, N", "N"),
    TickField("device_force", 3, "f8", _NAN, "force commanded to the haptic device, N", "N"),
    TickField("contact_point", 3, "f8", _NAN, "closest surface point, m", "m"),
    TickField("contact_normal", 3, "f8", _NAN, "unit contact normal"),
    TickField("depth", 0, "f8", _NAN, "indentation depth, m", "m"),
    TickField("contact_radius", 0, "f8", _NAN, "contact radius, m", "m"),
    TickField("load", 0, "f8", _NAN, "Maugis-Dugdale load (> 0 compressive), N", "N"),
    TickField("in_contact", 0, "i4", 0, "1 when the tip touches"),
    TickField("md_status", 0, "i4", MD_STATUS_NOT_GIVEN, "MD status (0 contact, 1 cohesive, 2 separated)"),
    TickField("decoupling_flags", 0, "i4", 0, "DecouplingFlag bits"),
)
#: the optional per-tick safety flag word of the haptic loop (written by every writer since it
#: exists; older files lack it): -1 when the loop gave none
SAFETY_FLAGS = TickField("safety_flags", 0, "i4", -1, "haptic loop safety flag bits (arsurf.status), -1 not recorded")
#: the optional per-tick dataset of a session with a tube scene: (n, k, 3), k = number of tubes
TUBE_POSES = TickField("tube_poses", 3, "f8", _NAN, "tube poses x, y (m), angle (rad), k rows per tick", "m,m,rad")
#: the optional per-tick dataset of a session driven by an instrument (metadata key ``instrument``)
INSTRUMENT_POSITION = TickField("instrument_position", 3, "f8", _NAN,
                                "tip position the instrument measured, m (scan frame, tip-sphere centre)", "m")
#: optional datasets whose unit is known (checked when the file gives one)
_KNOWN_EXTRA = {TUBE_POSES.name: TUBE_POSES, INSTRUMENT_POSITION.name: INSTRUMENT_POSITION}
_REQUIRED_TICK = ("t", "probe_position")
#: ticks per chunk of the recorder (and per journal record), chunks in its pool
_CHUNK_TICKS = 256
_QUEUE_CHUNKS = 32
#: the recorder writes the chunk being filled at least this often, s
FLUSH_INTERVAL = 0.05
#: gzip cannot inflate more than ~1032x: data claiming more than this per file byte is damage
_MAX_INFLATION = 1100
_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]{0,63}$")


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


def record_loop_tick(writer: "SessionWriter", loop, t: float, state) -> None:
    """Append the tick a :class:`~arsurf.haptics.loop.HapticLoop` just ran to ``writer``.

    The one way a loop is recorded (``arsurf demo``, the live loops of ``arsurf view``): the
    device sample ``state`` (:class:`~arsurf.haptics.device.DeviceState`: stylus position,
    velocity, buttons), what the tick computed (``loop.out``: probe, tip, energy, passivity
    damping, signals, probe force, device force, safety flags), the contact of ``loop.model.out``
    (:func:`contact_fields`) and, with a scene, the tube poses after the tick. ``t`` is the
    loop time the tick was given (s). A button word the loop took as malformed is recorded as
    the no-press it was given (0).

    Examples
    --------
    >>> # f = loop.step(state, now); record_loop_tick(writer, loop, now, state)
    """
    from arsurf.haptics.loop import LOOP_OUT, _valid_buttons

    o = loop.out
    get = LOOP_OUT.get
    extra = {} if loop.scene is None else {TUBE_POSES.name: loop.scene.poses}
    writer.append(t=t, stylus_position=state.position, stylus_velocity=state.velocity,
                  buttons=_valid_buttons(state.buttons)[0], probe_position=get(o, "probe"),
                  probe_velocity=get(o, "probe_velocity"), tip_position=get(o, "tip"), energy=get(o, "energy"),
                  passivity_damping=get(o, "passivity_damping"), signals=get(o, "signals"),
                  force=get(o, "probe_force"), device_force=get(o, "device_force"),
                  safety_flags=int(get(o, "safety_flags")),
                  **contact_fields(loop.model.record(loop.model.out)), **extra)


def journal_path(path: str | os.PathLike) -> Path:
    """The journal a recording to ``path`` streams into: ``<path>.journal``."""
    p = Path(path)
    return p.with_name(p.name + _journal.JOURNAL_SUFFIX)


def _session_fields(metadata: Mapping) -> dict:
    """name -> (TickField, row shape) of a session with this (checked) metadata, in file order."""
    out = {f.name: (f, f.row_shape) for f in TICK_FIELDS}
    out[SAFETY_FLAGS.name] = (SAFETY_FLAGS, SAFETY_FLAGS.row_shape)
    k = tube_count(metadata)
    if k is not None:
        out[TUBE_POSES.name] = (TUBE_POSES, (k, TUBE_POSES.width))
    if metadata.get("instrument") is not None:
        out[INSTRUMENT_POSITION.name] = (INSTRUMENT_POSITION, INSTRUMENT_POSITION.row_shape)
    return out


def _layout(fields: dict) -> _journal.Layout:
    return _journal.Layout(tuple(fields), tuple(np.dtype(f.dtype).newbyteorder("<").str for f, _ in fields.values()),
                           tuple(s for _, s in fields.values()), tuple(f.fill for f, _ in fields.values()))


# ---------------------------------------------------------------------------------------------
# checksums


def _attr(value):
    if isinstance(value, bytes):
        return value.decode("utf-8", "replace")
    if isinstance(value, np.generic):
        return value.item()
    return value


def _canonical(obj) -> bytes:
    return json.dumps(obj, sort_keys=True, allow_nan=True, separators=(",", ":")).encode()


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _dataset_hasher(dtype: np.dtype, shape: tuple):
    h = hashlib.sha256()
    h.update(f"{np.dtype(dtype).newbyteorder('<').str}|{','.join(map(str, shape))}|".encode())
    return h


def _array_digest(a: np.ndarray) -> str:
    h = _dataset_hasher(a.dtype, a.shape)
    h.update(np.ascontiguousarray(a, dtype=a.dtype.newbyteorder("<")).data)
    return h.hexdigest()


# ---------------------------------------------------------------------------------------------
# writing HDF5


def _fsync_dir(path: Path) -> None:
    _journal._fsync_dir(path)


def _rows_per_chunk(row_bytes: int) -> int:
    return int(min(4096, max(1, (1 << 20) // max(row_bytes, 1))))


class _H5Out:
    """A sealed HDF5 file being written: root attrs, ``/metadata`` texts, ``/ticks`` datasets.

    The datasets are created with their final shape and filled by blocks in row order
    (:meth:`write`); each carries its SI unit in a ``units`` attribute (:mod:`arsurf.units`);
    :meth:`finish` adds the ``checksums`` attribute, seals the file, fsyncs it and renames it
    over ``path``. Equal inputs give equal bytes (no timestamps, fixed chunks).
    """

    def __init__(self, path: Path, attrs: Mapping, metadata: Mapping, shapes: Mapping[str, tuple],
                 dtypes: Mapping[str, np.dtype], units: Mapping[str, str]):
        h5py = _h5py()
        self.path = Path(path)
        self._f = None
        # an exclusive temporary in the target's folder (arsurf._files): a planted link is never written
        self._cm = atomic_write(self.path, "wb", what="session file", error=SessionError)
        self._fh = self._cm.__enter__()
        self.part = self._fh.temp
        try:
            self._f = h5py.File(self._fh, "w", userblock_size=SEAL_SIZE)
            f = self._f
            self._attrs = {}
            for key, value in attrs.items():
                f.attrs[key] = value
                self._attrs[key] = _attr(value)
            texts = {key: json.dumps(metadata[key], sort_keys=True, allow_nan=False) for key in sorted(metadata)}
            mg = f.create_group("metadata")
            for key, text in texts.items():
                mg.attrs[key] = text
            self._sums = {"algorithm": "sha256", "metadata": _sha(_canonical(texts))}
            tg = f.create_group("ticks")
            self._ds, self._hash, self._next = {}, {}, {}
            row_bytes = max(np.dtype(dtypes[n]).itemsize * int(np.prod(shapes[n][1:], dtype=np.int64))
                            for n in shapes) if shapes else 1
            self.block = _rows_per_chunk(row_bytes)
            for name, shape in shapes.items():
                dt = np.dtype(dtypes[name]).newbyteorder("<")
                opts = ({"chunks": (min(shape[0], self.block), *shape[1:]), "compression": "gzip",
                         "compression_opts": 4, "shuffle": True} if shape[0] else {})
                self._ds[name] = tg.create_dataset(name, shape=shape, dtype=dt, track_times=False, **opts)
                self._ds[name].attrs[UNITS_ATTR] = units[name]
                self._hash[name] = _dataset_hasher(dt, shape)
                self._next[name] = 0
        except BaseException:
            self.abort()
            raise

    def write(self, name: str, start: int, block: np.ndarray) -> None:
        """Write rows ``start .. start + len(block)`` of dataset ``name`` (in order)."""
        ds = self._ds[name]
        if start != self._next[name]:
            raise SessionError(f"internal: /ticks/{name} written out of order (row {start}, expected "
                               f"{self._next[name]})")
        block = np.ascontiguousarray(block, dtype=ds.dtype)
        n = block.shape[0]
        if n:
            ds[start:start + n] = block
            self._hash[name].update(block.data)
        self._next[name] = start + n

    def finish(self) -> Path:
        try:
            for name, ds in self._ds.items():
                if self._next[name] != ds.shape[0]:
                    raise SessionError(f"internal: /ticks/{name} has {self._next[name]} of {ds.shape[0]} rows")
                self._sums[f"ticks/{name}"] = self._hash[name].hexdigest()
            self._sums["attrs"] = _sha(_canonical(self._attrs))
            self._f.attrs["checksums"] = json.dumps(self._sums, sort_keys=True)
            self._f.close()
            seal_open(self._fh)
            cm, self._cm = self._cm, None
            cm.__exit__(None, None, None)  # fsynced, renamed over the path, folder fsynced
        except BaseException:
            self.abort()
            raise
        return self.path

    def abort(self) -> None:
        try:
            if self._f is not None:
                self._f.close()
        except Exception:  # pragma: no cover - already closed or never opened
            pass
        if self._cm is not None:  # the temporary is removed, the target left as it was
            cm, self._cm = self._cm, None
            cm.__exit__(SessionError, SessionError("aborted"), None)


def write_h5(path: str | os.PathLike, attrs: Mapping[str, Any], metadata: Mapping[str, Any],
             datasets: Mapping[str, np.ndarray], units: Mapping[str, str]) -> Path:
    """Write root ``attrs``, ``/metadata`` (JSON per key) and ``/ticks/<name>`` datasets atomically.

    The file goes to an exclusive temporary beside ``path`` (:func:`arsurf._files.atomic_write`)
    with ``checksums`` and a seal (:func:`arsurf.replay.sealed.seal_open`), is fsynced and renamed
    over ``path`` (a symbolic link there is refused); each dataset
    gets the ``units`` attribute ``units[name]`` (:mod:`arsurf.units`); datasets carry no
    timestamps, so equal inputs give equal bytes. Used for sessions and replay outputs.
    """
    arrays = {name: np.asarray(a) for name, a in datasets.items()}
    missing = sorted(set(arrays) - set(units))
    if missing:
        raise SessionError(f"internal: no unit given for the dataset(s) {missing}")
    out = _H5Out(Path(path), attrs, metadata, {n: a.shape for n, a in arrays.items()},
                 {n: a.dtype for n, a in arrays.items()}, units)
    try:
        for name, a in arrays.items():
            for start in range(0, a.shape[0], out.block):
                out.write(name, start, a[start:start + out.block])
    except BaseException:
        out.abort()
        raise
    return out.finish()


def _utc_now() -> str:
    return datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")


def _dropped(index: _journal.JournalIndex) -> int:
    """Ticks dropped while recording: gaps between records, and after the last one (end record)."""
    told = (index.end or {}).get("dropped_ticks")
    told = told if isinstance(told, int) and not isinstance(told, bool) and told >= 0 else 0
    return max(index.dropped_ticks, told)


def _merge_journal(index: _journal.JournalIndex, path: Path, *, complete: bool, reason: str,
                   created: str | None) -> Path:
    """Write the ticks of a scanned journal into the sealed session file ``path`` (streaming)."""
    from arsurf import __version__

    header = index.header
    metadata = header["metadata"]
    fields = _session_fields(metadata)
    n = index.n_ticks
    attrs = {"format": FORMAT, "format_version": np.int64(FORMAT_VERSION),
             "arsurf_version": str(header.get("arsurf_version", __version__)),
             "created": created if created is not None else str(header.get("started", _utc_now())), "units": "SI",
             "complete": np.bool_(complete), "n_ticks": np.int64(n), "dropped_ticks": np.int64(_dropped(index))}
    if not complete:
        attrs["aborted"] = reason or "the recording stopped before the writer was closed"
    lay = index.layout
    out = _H5Out(path, attrs, metadata, {name: (n, *fields[name][1]) for name in fields},
                 {name: np.dtype(fields[name][0].dtype) for name in fields},
                 {name: fields[name][0].unit for name in fields})
    try:
        block = out.block
        stage = [np.empty((block, *s), dtype=d) for d, s in zip(lay.dtypes, lay.shapes)]
        state = {"done": 0, "fill": 0}

        def flush():
            k = state["fill"]
            if k:
                for name, buf in zip(lay.names, stage):
                    out.write(name, state["done"], buf[:k])
                state["done"] += k
                state["fill"] = 0

        def sink(row, arrays):
            m = arrays[0].shape[0]
            at = 0
            while at < m:
                take = min(block - state["fill"], m - at)
                for buf, a in zip(stage, arrays):
                    buf[state["fill"]:state["fill"] + take] = a[at:at + take]
                state["fill"] += take
                at += take
                if state["fill"] == block:
                    flush()

        _journal.read_rows(index, sink)
        flush()
    except BaseException:
        out.abort()
        raise
    return out.finish()


# ---------------------------------------------------------------------------------------------
# the recorder

_OPEN_WRITERS: "weakref.WeakSet[SessionWriter]" = weakref.WeakSet()


@atexit.register
def _close_open_writers() -> None:  # pragma: no cover - runs at interpreter exit
    for w in list(_OPEN_WRITERS):
        try:
            w.close(complete=False, reason="the process exited without closing the writer")
        except Exception:
            pass


def _abandon(stream: _journal.TickStreamer, file: _journal.JournalFile) -> None:
    stream.stop()
    file.close()


class SessionWriter:
    """Record a session tick by tick, streamed to a crash-safe journal; the ``.h5`` is written at :meth:`close`.

    Parameters
    ----------
    path : path-like
        The session file (``.h5``; not a symbolic link); written at :meth:`close` through an
        exclusive temporary (:func:`arsurf._files.atomic_write`). While
        recording, ticks stream into ``<path>.journal`` (:func:`journal_path`), which must not
        exist.
    metadata : dict
        Session metadata (:func:`arsurf.assembly.session_metadata`); checked here, so a recording that could
        not be replayed fails before it starts.
    capacity : int
        Ticks per chunk (1..65536): the writer thread takes a chunk when it is full, and the
        chunk being filled every ``flush_interval``.
    created : str, optional
        The ``created`` attribute (default: the UTC time at :meth:`close`); pass a fixed value
        to make the file byte-reproducible.
    queue_chunks : int
        Chunks the disk may lag behind (``queue_chunks * capacity`` ticks, 8192 by default:
        8 s at 1 kHz) before ticks are dropped.
    flush_interval : float, s
        The longest a tick waits before the writer thread writes and fsyncs it (0.001..1).
    when_full : {"drop", "wait"}
        ``"drop"`` (real-time loops): :meth:`append` never blocks; when the disk is so far
        behind that the pool is empty, the chunk being filled is dropped and counted
        (``dropped_ticks`` in the file). ``"wait"`` (batch producers faster than the disk):
        :meth:`append` waits for the writer thread instead.
    fsync : bool
        fsync the journal at every flush (power-loss safety; a killed process loses nothing
        written either way).
    handle_signals : bool
        Install SIGINT/SIGTERM handlers (only from the main thread; the previous ones come back
        at :meth:`close`) that raise :class:`~arsurf.errors.RecordingInterrupted`, so a ``with``
        block unwinds and the file is closed with every tick, marked incomplete with the
        signal as the reason. For processes that own the recording (command lines), not
        libraries. Ticks may be appended from another thread (a live loop's servo thread): the
        signal then interrupts the main thread, which should stop that thread before the
        ``with`` block closes the writer.

    Notes
    -----
    :meth:`append` costs one lock and one numpy row assignment per given field (a few
    microseconds in all) and allocates nothing: memory stays flat for any session length.
    Used as a context manager, the file is written at exit; if the block raised, it is still
    written but marked ``complete=False`` (with the reason in ``aborted``), and
    :func:`load_session` refuses it unless asked. A writer never closed is closed (incomplete)
    at interpreter exit; a process killed outright leaves the journal, which
    :func:`load_session` (``allow_incomplete=True``) and :func:`recover_session` read.

    Examples
    --------
    >>> # with SessionWriter("run.h5", meta) as w:
    >>> #     w.append(t=t, probe_position=c, probe_velocity=v, signals=s, force=f)
    """

    def __init__(self, path: str | os.PathLike, metadata: Mapping, *, capacity: int = _CHUNK_TICKS,
                 created: str | None = None, queue_chunks: int = _QUEUE_CHUNKS,
                 flush_interval: float = FLUSH_INTERVAL, when_full: str = "drop", fsync: bool = True,
                 handle_signals: bool = False):
        from arsurf import __version__

        self.path = Path(path)
        if self.path.is_dir():
            raise SessionError(f"session path {str(self.path)!r} is a directory; pass a file name such as run.h5")
        if not self.path.parent.is_dir():
            raise SessionError(f"the folder of the session file {str(self.path)!r} does not exist; create it first")
        check_target(self.path, "session file", error=SessionError)  # a planted link: refused before recording
        self.metadata = _jsonable(metadata, "metadata")
        check_metadata(self.metadata)
        capacity = int(capacity)
        if not 1 <= capacity <= _journal.MAX_RECORD_TICKS:
            raise SessionError(f"`capacity` must be 1..{_journal.MAX_RECORD_TICKS} ticks per chunk (got {capacity})")
        queue_chunks = int(queue_chunks)
        if not 1 <= queue_chunks <= 4096:
            raise SessionError(f"`queue_chunks` must be 1..4096 (got {queue_chunks})")
        flush_interval = float(flush_interval)
        if not 1e-3 <= flush_interval <= 1.0:
            raise SessionError(f"`flush_interval` must be 0.001..1 s (got {flush_interval}); it bounds how long a "
                               "tick waits before it is on disk")
        if when_full not in ("drop", "wait"):
            raise SessionError(f"`when_full` must be 'drop' or 'wait' (got {when_full!r})")
        self._created = created
        self._fields = _session_fields(self.metadata)
        self._index = {name: i for i, name in enumerate(self._fields)}
        self._fills = [f.fill for f, _ in self._fields.values()]
        layout = _layout(self._fields)
        self.journal = journal_path(self.path)
        header = {"format": _journal.JOURNAL_FORMAT, "journal_version": _journal.JOURNAL_VERSION,
                  "session_format_version": FORMAT_VERSION, "arsurf_version": __version__, "started": _utc_now(),
                  "metadata": self.metadata, "fields": layout.describe()}
        self._file = _journal.JournalFile(self.journal, header, fsync=fsync)
        self._stream = _journal.TickStreamer(layout, self._file, chunk_ticks=capacity, queue_chunks=queue_chunks,
                                             interval=flush_interval, when_full=when_full)
        self._closed = False
        #: True once an append saw that the journal could not be written (full disk, I/O error)
        self.failed = False
        self._written: Path | None = None
        self._end: dict | None = None
        self._signal: str | None = None
        self._busy = False      # inside append's critical section: a signal waits until it ends
        self._pending = False
        self._old_handlers: dict = {}
        if handle_signals and threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self._old_handlers[sig] = signal.signal(sig, self._on_signal)
        _OPEN_WRITERS.add(self)
        # a writer dropped without close: stop its thread, close the journal (kept, recoverable)
        self._finalizer = weakref.finalize(self, _abandon, self._stream, self._file)
        self._finalizer.atexit = False  # at exit, _close_open_writers closes live writers properly

    def _on_signal(self, signum, frame) -> None:
        self._signal = signal.Signals(signum).name
        if self._busy:  # never unwind half-way through a chunk hand-over
            self._pending = True
            return
        raise RecordingInterrupted(f"recording to {str(self.path)!r} stopped by {self._signal}")

    def _restore_signals(self) -> None:
        for sig, old in self._old_handlers.items():
            try:
                signal.signal(sig, old)
            except (ValueError, TypeError):  # pragma: no cover - not the main thread any more
                pass
        self._old_handlers = {}

    @property
    def n_ticks(self) -> int:
        """Ticks appended and kept so far (dropped ones excluded)."""
        return self._stream.appended - self._stream.dropped

    @property
    def dropped_ticks(self) -> int:
        """Ticks dropped because the disk fell behind (``when_full="drop"``)."""
        return self._stream.dropped

    @property
    def write_error(self) -> BaseException | None:
        """The error that stopped the journal (a full disk: ``OSError`` ENOSPC), or None.

        Set by the writer thread at the failed write (it writes at least every
        ``flush_interval``); the next :meth:`append` then flags it (:attr:`failed`, a warning
        on the ``arsurf.session`` logger) without raising, so a real-time loop keeps running and
        :meth:`close` says it again."""
        return self._stream.error

    @property
    def unrecorded_ticks(self) -> int:
        """Ticks appended but not in the journal because writing failed (0 while it works)."""
        st = self._stream
        return 0 if st.error is None else max(0, st.appended - st.dropped - st.written)

    def _flag_failure(self) -> None:
        self.failed = True
        _log.warning("recording to %r failed: %s; from tick %d on nothing more is recorded (the journal %r "
                     "keeps the %d ticks before; free disk space and recover_session it)", str(self.path),
                     self._stream.error, self._stream.written, str(self.journal), self._stream.written)

    def _clear_row(self, arrays, i: int) -> None:
        for a, fill in zip(arrays, self._fills):
            a[i] = fill

    def append(self, **fields) -> None:
        """Record one tick.

        Parameters
        ----------
        **fields
            ``t`` (s) and ``probe_position`` ((3,) m) are required; every other field of
            :data:`TICK_FIELDS` is optional (missing: NaN, or the integer fill value), and so are
            ``safety_flags`` (the loop's flag word, :data:`SAFETY_FLAGS`) and ``tube_poses``
            ((k, 3): x, y, angle per tube) when the metadata has a tube scene.

        Raises
        ------
        SessionError
            Unknown field name, wrong shape, missing ``t``/``probe_position``, writer closed.
        """
        if self._closed:
            raise SessionError(f"the session writer of {str(self.path)!r} is closed; open a new one")
        st = self._stream
        index = self._index
        if threading.current_thread() is not threading.main_thread():
            # signal handlers run in the main thread: one arriving now interrupts the main thread
            # at once (it is not inside this append), never this one (a live loop's servo thread)
            self._append_locked(st, index, fields)
            return
        self._busy = True
        try:
            self._append_locked(st, index, fields)
        finally:
            self._busy = False
            if self._pending:
                self._pending = False
                raise RecordingInterrupted(f"recording to {str(self.path)!r} stopped by {self._signal}")

    def _append_locked(self, st, index, fields) -> None:
        with st.lock:
            c = st.current
            i = c.n
            arrays = c.arrays
            try:
                for name, value in fields.items():
                    arrays[index[name]][i] = value
            except KeyError:
                self._clear_row(arrays, i)
                unknown = sorted(set(fields) - set(index))
                hint = (" (tube_poses needs a tube scene in the metadata: tubes=TubeScene.to_metadata())"
                        if TUBE_POSES.name in unknown else "")
                raise SessionError(f"unknown session field(s) {unknown}; the fields are "
                                   f"{list(self._fields)}{hint}") from None
            except (ValueError, TypeError) as exc:
                self._clear_row(arrays, i)
                bad, shape = self._fields[name]
                rows = bad.row_text if name != TUBE_POSES.name else f"{shape[0]} x 3 numbers"
                raise SessionError(f"session field {name!r} must be {rows} per tick "
                                   f"({bad.doc}); got {value!r}: {exc}") from None
            if "t" not in fields or "probe_position" not in fields:
                self._clear_row(arrays, i)
                raise SessionError(f"every tick needs `t` (s) and `probe_position` ((3,) m); got only {sorted(fields)}")
            st.commit_locked()
            if st.error is not None and not self.failed:  # one attribute read per tick while the disk works
                self._flag_failure()

    def close(self, complete: bool = True, reason: str = "") -> Path:
        """Stop recording, merge the journal into the sealed session file and return its path.

        Idempotent once it succeeded. If writing the ``.h5`` fails (full disk...), the error is
        raised and the journal stays, complete, for :func:`recover_session` (or another
        :meth:`close`).
        """
        if self._written is not None:
            return self.path
        if not self._closed:
            self._closed = True
            self._restore_signals()
            st = self._stream
            st.stop()
            if self._signal is not None and complete is not True:
                reason = f"stopped by {self._signal}"
            error = st.error
            if error is not None:
                complete, reason = False, f"the journal could not be written: {error}"
            self._end = {"complete": bool(complete), "reason": reason or "", "n_ticks": st.written,
                         "dropped_ticks": st.dropped,
                         "created": self._created if self._created is not None else _utc_now()}
            try:
                if error is None:
                    self._file.write(_journal.END, [json.dumps(self._end, sort_keys=True).encode()])
                    self._file.sync()
            finally:
                self._file.close()
            if error is not None:
                _OPEN_WRITERS.discard(self)
                raise SessionError(f"recording to {str(self.path)!r} failed: the journal {str(self.journal)!r} could "
                                   f"not be written ({error}); the ticks written before are in it "
                                   "(load_session(..., allow_incomplete=True))") from error
        end = self._end
        index = _journal.scan_journal(self.journal)
        _merge_journal(index, self.path, complete=end["complete"], reason=end["reason"], created=end["created"])
        self.journal.unlink()
        _fsync_dir(self.journal.parent)
        self._written = self.path
        _OPEN_WRITERS.discard(self)
        return self.path

    def __enter__(self) -> "SessionWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        elif self._signal is not None:
            self.close(complete=False, reason=f"stopped by {self._signal}")
        else:
            self.close(complete=False, reason=f"{exc_type.__name__}: {exc}")


# ---------------------------------------------------------------------------------------------
# reading


@dataclass
class Session:
    """A loaded session (or replay output): metadata, per-tick arrays and root attributes.

    ``verified`` is True when the arrays, metadata and attributes matched the file's SHA-256
    checksums; ``recovered`` when they were read from the journal of a recording that was not
    closed (or whose ``.h5`` was never written); ``notes`` says anything a reader should know;
    ``units`` maps each dataset to its SI unit (:mod:`arsurf.units`).
    """

    metadata: dict
    ticks: dict
    n_ticks: int
    attrs: dict = field(default_factory=dict)
    path: Path | None = None
    verified: bool = False
    recovered: bool = False
    notes: tuple = ()
    units: dict = field(default_factory=dict)
    _checksums: Any = field(default=None, repr=False, compare=False)

    @property
    def complete(self) -> bool:
        """True when the recording was closed normally."""
        return self.attrs.get("complete") is True

    def _repr_html_(self) -> str:
        """Ticks, duration, rate, scan, tip, contact law, status and a force thumbnail (IPython)."""
        from arsurf.replay.display import session_html

        return session_html(self)

    def _repr_png_(self) -> bytes | None:
        """|force on the tip| against time, contact shaded (IPython)."""
        from arsurf.replay.display import session_png

        return session_png(self)


def _spec(fmt: str, versions: tuple, fields: tuple, what: str) -> dict:
    return {"fmt": fmt, "versions": list(versions), "what": what,
            "fields": [[f.name, f.width, f.dtype, f.unit] for f in fields]}


def _fields_from_spec(spec: dict) -> tuple:
    return tuple(TickField(name, width, dtype, _NAN, "", unit) for name, width, dtype, unit in spec["fields"])


_ATTR_TYPES = {"format": str, "format_version": int, "arsurf_version": str, "created": str, "units": str,
               "complete": bool, "n_ticks": int, "aborted": str, "dropped_ticks": int, "checksums": str,
               "session_sha256": str, "scan_sha256": str, "session_format_version": int}


def _read_attrs(f, name: str) -> dict:
    keys = list(f.attrs.keys())
    if len(keys) > 64:
        raise SessionError(f"{name} has {len(keys)} root attributes; a session has about ten (damaged)")
    attrs = {}
    for k in keys:
        if not isinstance(k, str):
            raise SessionError(f"{name} has a root attribute whose name is not text ({k!r}): damaged")
        v = _attr(f.attrs[k])
        want = _ATTR_TYPES.get(k)
        if want is not None:
            ok = isinstance(v, want) and (want is bool or not isinstance(v, bool))
            if not ok:
                raise SessionError(f"{name}: root attribute {k!r} is {v!r} ({type(v).__name__}), expected a "
                                   f"{want.__name__} (damaged or not an arsurf file)")
        elif not isinstance(v, (str, int, float, bool)):
            continue  # a foreign non-scalar attribute: not ours, not kept
        attrs[k] = v
    return attrs


def _n_text(f) -> str:
    """The ``n_ticks`` attribute of an open file as text, for messages ('?' if unreadable)."""
    try:
        return str(int(f.attrs["n_ticks"]))
    except Exception:
        return "?"


def _read_open(f, p: Path, size: int, fmt: str, versions: tuple, fields: tuple, allow_incomplete: bool,
               what: str) -> Session:
    """Check the schema of an open h5py file, then read it (caller catches h5py's errors)."""
    h5py = _h5py()
    name = f"{what} {str(p)!r}"
    attrs = _read_attrs(f, name)
    got = attrs.get("format")
    if got != fmt:
        raise SessionError(f"{str(p)!r} is not an {fmt} file (its format attribute is {got!r}); "
                           f"record sessions with arsurf.replay.SessionWriter")
    version = attrs.get("format_version")
    if version not in versions:
        raise SessionError(f"{str(p)!r} has format_version {version!r}, which this arsurf cannot read "
                           f"(supported versions: {', '.join(map(str, versions))}); "
                           "upgrade arsurf or re-record the session")
    complete = attrs.get("complete")
    if complete is not True and not allow_incomplete:
        why = attrs.get("aborted", "the writer was never closed")
        raise SessionError(f"{name} is incomplete (complete={complete!r}: {why}); "
                           f"pass allow_incomplete=True to read the {_n_text(f)} ticks it holds"
                           + (" (arsurf replay --allow-incomplete)" if what == "session" else ""))
    for g in ("metadata", "ticks"):
        if g not in f:
            absent = [x for x in ("metadata", "ticks") if x not in f]
            raise SessionError(f"{name} lacks the group(s) {absent}")
        if not isinstance(f[g], h5py.Group):
            raise SessionError(f"/{g} in {str(p)!r} is not a group")
    mg = f["metadata"]
    keys = list(mg.attrs.keys())
    if len(keys) > 256:
        raise SessionError(f"{name}: /metadata has {len(keys)} keys (damaged)")
    metadata, texts = {}, {}
    for key in keys:
        if not isinstance(key, str):
            raise SessionError(f"{name}: a /metadata key is not text ({key!r}): damaged")
        text = _attr(mg.attrs[key])
        if not isinstance(text, str):
            raise SessionError(f"metadata {key!r} of {str(p)!r} is not a JSON text (got {type(text).__name__})")
        texts[key] = text
        try:
            metadata[key] = json.loads(text)
        except (TypeError, ValueError, RecursionError) as exc:
            raise SessionError(f"metadata {key!r} of {str(p)!r} is not valid JSON ({exc})") from None
    g = f["ticks"]
    names = list(g.keys())
    odd = [x for x in names if not isinstance(x, str)]
    if odd:
        raise SessionError(f"{name}: a /ticks dataset name is not text ({odd[0]!r}): damaged")
    absent = [fl.name for fl in fields if fl.name not in names]
    if absent:
        raise SessionError(f"{name} lacks the per-tick dataset(s) {absent}")
    n = attrs.get("n_ticks")
    if not isinstance(n, int) or isinstance(n, bool) or n < 0:
        raise SessionError(f"{name} has n_ticks={n!r}; it must be a count >= 0 (damaged)")
    expected = {fl.name: fl for fl in fields}
    plan, lengths, total, units = [], {}, 0, {}
    for dname in names:
        ds = g[dname]
        if not isinstance(ds, h5py.Dataset):
            if dname in expected:
                raise SessionError(f"/ticks/{dname} in {str(p)!r} is not a dataset")
            continue
        dt, shape = ds.dtype, ds.shape
        fl = expected.get(dname)
        unit = _dataset_unit(ds, dname, p, (fl or _KNOWN_EXTRA.get(dname)))
        if unit is not None:
            units[dname] = unit
        if fl is not None:
            want = np.dtype(fl.dtype)
            if dt.kind != want.kind or dt.itemsize != want.itemsize:
                raise SessionError(f"/ticks/{dname} in {str(p)!r} has dtype {dt}, expected {want}")
            if shape is None or shape[1:] != fl.row_shape:
                raise SessionError(f"/ticks/{dname} in {str(p)!r} has shape {shape}, expected {fl.shape_text}")
        else:  # extra datasets (tube_poses, ...) are kept as they are: plain numbers, one row per tick
            if not _NAME.match(dname) or dt.kind not in "fiu" or dt.itemsize > 8 or shape is None \
                    or not 1 <= len(shape) <= 3:
                raise SessionError(f"/ticks/{dname} in {str(p)!r} is not a per-tick numeric dataset "
                                   f"(dtype {dt}, shape {shape}); the file is damaged or not a session")
            want = dt.newbyteorder("=")
        lengths[dname] = shape[0]
        total += int(np.prod(shape, dtype=np.float64)) * want.itemsize
        plan.append((dname, want, shape))
    if len(set(lengths.values())) > 1 or (lengths and n not in set(lengths.values())):
        raise SessionError(f"{name} is inconsistent: n_ticks={n!r} but the datasets have lengths {lengths}")
    if total > max(1 << 20, _MAX_INFLATION * size):
        raise SessionError(f"{name} is damaged: its datasets claim {total} bytes of data, more than a "
                           f"{size}-byte file can hold")
    ticks = {}
    for dname, want, shape in plan:
        a = np.asarray(g[dname][()])
        if a.shape != shape or a.dtype.kind != want.kind or a.dtype.itemsize != want.itemsize:
            raise SessionError(f"/ticks/{dname} in {str(p)!r} read as {a.dtype} {a.shape}, expected {shape}")
        ticks[dname] = np.ascontiguousarray(a, dtype=want)
    return Session(metadata=metadata, ticks=ticks, n_ticks=n, attrs=attrs, path=p, units=units,
                   _checksums=(attrs.get("checksums"), texts))


def _dataset_unit(ds, dname: str, p: Path, fl: TickField | None) -> str | None:
    """The ``units`` attribute of a dataset (None: the file predates it), checked against the field's unit."""
    if UNITS_ATTR not in ds.attrs:
        return fl.unit if fl is not None else None  # written before datasets carried units: the format's unit
    unit = _attr(ds.attrs[UNITS_ATTR])
    if not isinstance(unit, str) or len(unit) > 64:
        raise SessionError(f"/ticks/{dname} in {str(p)!r} has a units attribute that is not a short text (damaged)")
    if fl is not None and unit != fl.unit:
        raise SessionError(f"/ticks/{dname} in {str(p)!r} is in {unit!r}, but the format stores it in {fl.unit!r}; "
                           "the file was not written by arsurf (convert it to SI first)")
    return unit


def _verify(s: Session, name: str, required: bool) -> None:
    """Compare the session with its ``checksums``; set ``verified`` or raise SessionError."""
    raw, texts = s._checksums if s._checksums is not None else (None, None)
    s._checksums = None
    if raw is None:
        if required:
            raise SessionError(f"{name} has no checksums although its format_version "
                               f"{s.attrs.get('format_version')!r} has them (damaged)")
        s.verified = False
        s.notes = (*s.notes, "written before sessions carried checksums: its content cannot be verified")
        return
    try:
        sums = json.loads(raw)
    except (ValueError, RecursionError):
        raise SessionError(f"{name}: its checksums attribute is not valid JSON (damaged)") from None
    if not isinstance(sums, dict) or sums.get("algorithm") != "sha256":
        raise SessionError(f"{name}: its checksums attribute is not a sha256 table (damaged)")
    attrs = {k: v for k, v in s.attrs.items() if k != "checksums"}
    have = {"algorithm": "sha256", "attrs": _sha(_canonical(attrs)), "metadata": _sha(_canonical(texts))}
    for dname, a in s.ticks.items():
        have[f"ticks/{dname}"] = _array_digest(a)
    bad = sorted(k for k in set(have) | set(sums) if have.get(k) != sums.get(k))
    if bad:
        parts = ", ".join("root attributes" if k == "attrs" else "/" + k for k in bad)
        raise SessionError(f"{name} is damaged: {parts} {'does' if len(bad) == 1 else 'do'} not match "
                           "the SHA-256 written with the file; it is refused rather than read with altered values")
    s.verified = True
    s.attrs.pop("checksums", None)


def _read_file(p: Path, spec: dict, allow_incomplete: bool, isolate) -> Session:
    """Read an HDF5 file per ``spec`` (seal, schema; checksums not yet compared)."""
    what = spec["what"]
    name = f"{what} {str(p)!r}"
    if isolate is True:
        return _read_isolated(p, spec, allow_incomplete)
    try:
        data = read_sealed(p, what)
    except OSError as exc:
        raise SessionError(f"{name} cannot be read: {exc}") from exc
    sealed = data is not None
    if data is None:
        if isolate == "auto":
            return _read_isolated(p, spec, allow_incomplete)
        data = read_regular(p, what, error=SessionError)
        check_superblock(data[:4096], 0, name, len(data))
    size = len(data)
    try:  # the bytes in memory, nothing outside them followed (arsurf._h5safe)
        f = open_hdf5(data, what, error=SessionError, soft_links=False, max_expansion=GZIP_LIMIT, name=name)
    except SessionError:
        raise
    except Exception as exc:
        raise SessionError(f"{str(p)!r} is not a readable HDF5 {what} file (truncated, corrupt or another "
                           f"format): {exc}") from None
    try:
        with f:
            s = _read_open(f, p, size, spec["fmt"], tuple(spec["versions"]), _fields_from_spec(spec),
                           allow_incomplete, what)
    except SessionError:
        raise
    except (Exception, MemoryError) as exc:  # h5py's errors on damaged files, whatever their class
        raise SessionError(f"{str(p)!r} is damaged (truncated or corrupt HDF5): {type(exc).__name__}: {exc}") from None
    s.notes = (*s.notes, *(() if sealed else ("read without a seal",)))
    return s


_CHILD = """
import json, os, sys
from pathlib import Path
from arsurf.errors import SessionError
from arsurf.replay.session import _isolated_child
try:
    _isolated_child(sys.argv[1], sys.argv[2], sys.argv[3])
except SessionError as exc:
    print(str(exc).replace("\\n", " "), file=sys.stderr)
    sys.exit(3)
"""


def _isolated_child(path: str, spec_text: str, out: str) -> None:
    """The isolated reader's body: read in-process, answer with ticks.npz + info.json in ``out``."""
    spec = json.loads(spec_text)
    p = Path(path)
    if spec.get("session"):  # the metadata check (scipy, numba imports) runs in the parent
        s = _read_file(p, spec, spec["allow_incomplete"], False)
        _verify(s, f"session {str(p)!r}", required=s.attrs.get("format_version", 0) >= _CHECKSUMMED_FROM)
    else:
        s = read_h5(p, fmt=spec["fmt"], versions=tuple(spec["versions"]), fields=_fields_from_spec(spec),
                    allow_incomplete=spec["allow_incomplete"], what=spec["what"], isolate=False)
    np.savez(os.path.join(out, "ticks.npz"), **s.ticks)
    info = {"metadata": s.metadata, "attrs": s.attrs, "n_ticks": s.n_ticks, "verified": s.verified,
            "recovered": s.recovered, "notes": list(s.notes), "names": list(s.ticks), "units": s.units}
    with open(os.path.join(out, "info.json"), "w", encoding="utf-8") as fh:
        json.dump(info, fh, sort_keys=True)


def _units_answer(units, name: str) -> dict:
    if not isinstance(units, dict) or not all(isinstance(k, str) and isinstance(v, str) for k, v in units.items()):
        raise SessionError(f"{name}: the isolated reader's answer has no valid units")
    return units


def _read_isolated(p: Path, spec: dict, allow_incomplete: bool, session: bool = False) -> Session:
    """Read (and fully check) the file in a child process; build the Session from its answer."""
    import tempfile

    size = check_regular(p, spec["what"], error=SessionError)  # a FIFO never reaches the child
    name = f"reading {spec['what']} {str(p)!r}"
    spec = {**spec, "allow_incomplete": bool(allow_incomplete), "session": session}
    limit = (2 << 30) + 3 * _MAX_INFLATION * size
    timeout = 60.0 + size / 20e6
    with tempfile.TemporaryDirectory(prefix="arsurf-isolated-") as out:
        run_isolated(_CHILD, [str(p), json.dumps(spec), out], timeout=timeout, memory_limit=limit, what=name)
        try:
            with open(os.path.join(out, "info.json"), encoding="utf-8") as fh:
                info = json.load(fh)
            with np.load(os.path.join(out, "ticks.npz"), allow_pickle=False) as z:
                ticks = {k: z[k] for k in info["names"]}
        except (OSError, ValueError, KeyError) as exc:
            raise SessionError(f"{name}: the isolated reader gave no usable answer ({exc})") from None
    s = Session(metadata=info["metadata"], ticks=ticks, n_ticks=int(info["n_ticks"]), attrs=info["attrs"], path=p,
                verified=bool(info["verified"]), recovered=bool(info["recovered"]),
                notes=(*info["notes"], "read in an isolated process"), units=_units_answer(info.get("units"), name))
    for fl in _fields_from_spec(spec):  # the answer is checked like the file was
        a = s.ticks.get(fl.name)
        if a is None or a.dtype != np.dtype(fl.dtype) or a.shape != (s.n_ticks, *fl.row_shape):
            raise SessionError(f"{name}: the isolated reader's answer has a bad /ticks/{fl.name}")
    return s


def read_h5(path: str | os.PathLike, *, fmt: str, versions: tuple[int, ...], fields: tuple[TickField, ...],
            allow_incomplete: bool = False, what: str = "session", isolate="auto") -> Session:
    """Read a file written by :func:`write_h5` and check it against ``fields`` (SessionError if bad).

    Seal, schema, then checksums (when the file has them); ``isolate`` as in :func:`load_session`.
    """
    p = _existing(path, what)
    spec = _spec(fmt, versions, fields, what)
    s = _read_file(p, spec, allow_incomplete, isolate)
    if s._checksums is not None:
        _verify(s, f"{what} {str(p)!r}", required=False)
    return s


def _existing(path, what: str) -> Path:
    p = Path(path)
    if not p.exists():
        raise SessionFileNotFound(f"{what} file {str(p)!r} does not exist")
    if p.is_dir():
        raise SessionError(f"{what} path {str(p)!r} is a directory, not a {what} file")
    return p


#: no desk haptic device reaches farther than this from its home position, m (the largest,
#: Haption's Virtuose 6D, spans about 1.1 m); a session may record a smaller ``workspace``
DEVICE_REACH = 1.0
#: no desk haptic device pushes harder than this, N (the strongest give ~35-40 N peak); a session
#: may record its device's ``max_force``
DEVICE_FORCE_LIMIT = 100.0
#: no tip position in a scan frame lies farther than this from its origin, m (AFM scanners travel
#: at most ~0.1 mm); the replay checks the scan's own extent once the scan is read
PROBE_REACH = 1e-2


def _first(bad: np.ndarray) -> int:
    return int(np.flatnonzero(bad)[0])


def check_ticks(s: Session, name: str) -> None:
    """Refuse ticks that cannot be real, naming the tick and the field (:class:`SessionError`).

    - ``t``: finite and strictly increasing;
    - ``probe_position`` (and ``tip_position``, ``contact_point``, ``instrument_position`` where
      given): finite, within :data:`PROBE_REACH` of the scan frame's origin (the replay then checks
      the scan's extent, :func:`arsurf.replay.replay.check_probe_extent`);
    - ``stylus_position`` where given: within the device's reach (its recorded
      ``haptics.workspace`` half-extents plus half again, else :data:`DEVICE_REACH`);
    - ``device_force`` where given: finite, norm within the device's limit (recorded
      ``haptics.max_force`` plus 1 %, else :data:`DEVICE_FORCE_LIMIT`); ``force`` finite where given.

    NaN is the fill of an optional field (not given) and is allowed there; an infinity never is.
    """
    t = s.ticks["t"]
    if t.size:
        bad = ~np.isfinite(t)
        if bad.any():
            k = _first(bad)
            raise SessionError(f"{name}: tick {k}: t = {float(t[k])!r} s is not finite; time must be finite")
        steps = np.diff(t)
        if (steps <= 0).any():
            k = _first(steps <= 0) + 1
            raise SessionError(f"{name}: tick {k}: t = {float(t[k])!r} s is not after tick {k - 1} "
                               f"(t = {float(t[k - 1])!r} s); time must increase strictly")
    haptics = s.metadata.get("haptics") if isinstance(s.metadata.get("haptics"), dict) else {}
    reach, where = DEVICE_REACH, "no desk haptic device reaches farther"
    ws = haptics.get("workspace")
    if isinstance(ws, list) and len(ws) == 3 and all(isinstance(x, (int, float)) and x > 0 for x in ws):
        reach, where = 0.75 * max(ws), "outside the recorded device workspace (half-extents plus half again)"
    limit, what = DEVICE_FORCE_LIMIT, "no desk haptic device pushes harder"
    mf = haptics.get("max_force")
    if isinstance(mf, (int, float)) and not isinstance(mf, bool) and 0 < mf < DEVICE_FORCE_LIMIT:
        limit, what = 1.01 * mf, "above the recorded device's max_force"
    checks = [("probe_position", PROBE_REACH, "m", "outside any scanner's travel", False),
              ("tip_position", PROBE_REACH, "m", "outside any scanner's travel", False),
              ("contact_point", PROBE_REACH, "m", "outside any scanner's travel", False),
              ("instrument_position", PROBE_REACH, "m", "outside any scanner's travel", False),
              ("stylus_position", reach, "m", where, False),
              ("device_force", limit, "N", what, False),
              ("force", math.inf, "N", "", False)]
    for field_name, bound, unit, why, required in checks:
        a = s.ticks.get(field_name)
        if a is None or not a.size:
            continue
        a = a.reshape(a.shape[0], -1)
        given = ~np.isnan(a).any(axis=1)
        if required and not given.all():
            k = _first(~given)
            raise SessionError(f"{name}: tick {k}: {field_name} = {a[k].tolist()} {unit} is not finite; it is "
                               "required at every tick")
        inf = np.isinf(a).any(axis=1)
        if inf.any():
            k = _first(inf)
            raise SessionError(f"{name}: tick {k}: {field_name} = {a[k].tolist()} {unit} is infinite")
        size = np.linalg.norm(np.where(given[:, None], a, 0.0), axis=1)
        far = size > bound
        if far.any():
            k = _first(far)
            raise SessionError(f"{name}: tick {k}: {field_name} = {a[k].tolist()} {unit} (norm {size[k]:.3g} {unit}) "
                               f"is {why} ({bound:g} {unit}); the file is damaged or crafted")


def _check_session(s: Session, path) -> None:
    """The checks a session adds to the schema: metadata that rebuilds a model, tube poses, ticks
    that make sense (:func:`check_ticks`)."""
    try:
        check_metadata(s.metadata)
    except SessionError as exc:
        raise SessionError(f"session {str(path)!r}: {exc}") from exc
    check_ticks(s, f"session {str(path)!r}")
    flags = s.ticks.get(SAFETY_FLAGS.name)
    if flags is not None and (flags.dtype.kind not in "iu" or flags.shape != (s.n_ticks,)):
        raise SessionError(f"session {str(path)!r}: /ticks/safety_flags has shape {flags.shape} and dtype "
                           f"{flags.dtype}, expected integers ({s.n_ticks},)")
    poses = s.ticks.get(TUBE_POSES.name)
    if poses is not None:  # optional: checked against the scene when present
        k = tube_count(s.metadata)
        if k is None or poses.dtype.kind != "f" or poses.shape != (s.n_ticks, k, 3):
            raise SessionError(f"session {str(path)!r}: /ticks/tube_poses has shape {poses.shape} and dtype "
                               f"{poses.dtype}, expected float ({s.n_ticks}, k, 3) with k the number of tubes of "
                               f"the metadata's tube scene ({'none' if k is None else k})")
    pos = s.ticks.get(INSTRUMENT_POSITION.name)
    if pos is not None and (s.metadata.get("instrument") is None or pos.dtype.kind != "f"
                            or pos.shape != (s.n_ticks, 3)):
        raise SessionError(f"session {str(path)!r}: /ticks/instrument_position has shape {pos.shape} and dtype "
                           f"{pos.dtype}, expected float ({s.n_ticks}, 3) and an 'instrument' in the metadata")


# ---------------------------------------------------------------------------------------------
# journals


def _journal_session(jpath: Path, allow_incomplete: bool, shown: Path) -> Session:
    """Read every intact tick of a recording's journal (no libhdf5 involved)."""
    index = _journal.scan_journal(jpath)
    name = f"session {str(shown)!r}"
    meta = index.header.get("metadata")
    try:
        check_metadata(meta)
    except SessionError as exc:
        raise SessionError(f"{name} (journal {str(jpath)!r}): {exc}") from exc
    fields = _session_fields(meta)
    if index.layout.names != tuple(fields) or index.layout.shapes != tuple(s for _, s in fields.values()) \
            or index.layout.dtypes != _layout(fields).dtypes:
        raise SessionError(f"journal {str(jpath)!r} lists fields {index.layout.describe()} which do not match its "
                           "metadata (damaged, or written by another version)")
    end = index.end
    if end is not None and end.get("n_ticks") != index.n_ticks:
        raise SessionError(f"journal {str(jpath)!r} is damaged: its end record counts {end.get('n_ticks')!r} ticks, "
                           f"its records hold {index.n_ticks}")
    complete = end.get("complete") is True if end is not None else False
    if end is None:
        reason = ("the recording was interrupted (the writer never closed: the process was killed or crashed)"
                  + (f"; stopped at {index.stop_reason}, {index.discarded_bytes} bytes dropped"
                     if index.stop_reason else ""))
    else:
        reason = str(end.get("reason") or "")
    summary = (f"{index.n_ticks} ticks recovered from the journal {str(jpath)!r}"
               + (f" ({_dropped(index)} dropped while recording)" if _dropped(index) else ""))
    if not complete and not allow_incomplete:
        raise SessionError(f"{name} is incomplete ({reason}): {summary}; pass allow_incomplete=True "
                           "(arsurf replay --allow-incomplete) to read them, or recover_session() to write them "
                           "to a session file")
    n = index.n_ticks
    lay = index.layout
    arrays = [np.full((n, *s), f.fill, dtype=np.dtype(f.dtype)) for (f, s) in fields.values()]

    def sink(row, parts):
        m = parts[0].shape[0]
        for a, part in zip(arrays, parts):
            a[row:row + m] = part

    _journal.read_rows(index, sink)
    attrs = {"format": FORMAT, "format_version": FORMAT_VERSION,
             "arsurf_version": str(index.header.get("arsurf_version", "")),
             "created": str((end or {}).get("created") or index.header.get("started", "")), "units": "SI",
             "complete": complete, "n_ticks": n, "dropped_ticks": _dropped(index)}
    if not complete:
        attrs["aborted"] = reason
    notes = [summary + ("" if complete else " (the recording is incomplete)")]
    if end is not None and complete:
        notes.append("the recording was closed but its .h5 was never written")
    s = Session(metadata=meta, ticks=dict(zip(lay.names, arrays)), n_ticks=n, attrs=attrs, path=jpath,
                verified=True, recovered=True, notes=tuple(notes),
                units={name: f.unit for name, (f, _) in fields.items()})
    check_ticks(s, name)
    return s


def recover_session(path: str | os.PathLike) -> Path:
    """Write the ticks of an unfinished recording's journal into its session file.

    Parameters
    ----------
    path : path-like
        The session file the recording was writing (``run.h5``) or its journal
        (``run.h5.journal``).

    Returns
    -------
    Path
        The session file, sealed, ``complete`` False (with the reason) unless the recording
        was closed normally and only the final write failed. The journal is deleted.

    Raises
    ------
    SessionError
        No journal, or one without an intact header.
    """
    p = Path(path)
    if p.name.endswith(_journal.JOURNAL_SUFFIX):
        jpath, target = p, p.with_name(p.name[:-len(_journal.JOURNAL_SUFFIX)])
    else:
        jpath, target = journal_path(p), p
    if not jpath.is_file():
        raise SessionFileNotFound(f"there is no journal {str(jpath)!r} to recover")
    s = _journal_session(jpath, True, target)
    index = _journal.scan_journal(jpath)
    _merge_journal(index, target, complete=s.complete, reason=s.attrs.get("aborted", ""),
                   created=s.attrs["created"] or None)
    jpath.unlink()
    _fsync_dir(jpath.parent)
    return target


def load_session(path: str | os.PathLike, *, allow_incomplete: bool = False, isolate="auto") -> Session:
    """Read and check a session file, or the journal of a recording that never closed.

    Parameters
    ----------
    path : path-like
        ``run.h5``; if it does not exist but ``run.h5.journal`` does (the recording was
        killed), the journal is read. A ``.journal`` path is read directly.
    allow_incomplete : bool
        Accept a session whose recording was aborted (``complete`` False), including the
        ticks recovered from a journal.
    isolate : {"auto", True, False}
        Where libhdf5 parses the file: ``"auto"`` in this process for a sealed file (checked
        byte for byte first) and in an isolated child process (time and memory limits) for
        an unsealed one; ``True`` always isolated (untrusted files: a crash or hang of libhdf5
        becomes a SessionError); ``False`` always in-process.

    Returns
    -------
    Session
        ``metadata`` (dict), ``ticks`` (dict name -> array, see :data:`TICK_FIELDS`; plus
        ``tube_poses`` (n, k, 3) when the session recorded a tube scene),
        ``n_ticks``, ``attrs`` (root attributes), ``path``, ``verified`` (checksums matched),
        ``recovered`` (read from a journal), ``notes``.

    Raises
    ------
    SessionError
        Missing file (:class:`SessionFileNotFound`), a seal or checksum that does not match,
        not HDF5 or truncated, another format, an unknown ``format_version``, missing datasets
        or wrong shapes, datasets of different lengths, an incomplete recording, metadata that
        cannot rebuild the model; :class:`~arsurf.errors.IsolatedReadFailure` when the isolated
        reader crashed or hung.
    """
    if isolate not in ("auto", True, False):
        raise SessionError(f"`isolate` must be 'auto', True or False (got {isolate!r})")
    p = Path(path)
    if p.name.endswith(_journal.JOURNAL_SUFFIX) and p.is_file():
        return _journal_session(p, allow_incomplete, p)
    jpath = journal_path(p)
    if not p.exists() and jpath.is_file():
        return _journal_session(jpath, allow_incomplete, p)
    p = _existing(p, "session")
    spec = _spec(FORMAT, SUPPORTED_VERSIONS, TICK_FIELDS, "session")
    if isolate is True or (isolate == "auto" and _unsealed(p)):
        s = _read_isolated(p, spec, allow_incomplete, session=True)
        _check_session(s, path)
    else:
        s = _read_file(p, spec, allow_incomplete, False)
        _check_session(s, path)
        _verify(s, f"session {str(p)!r}", required=s.attrs.get("format_version", 0) >= _CHECKSUMMED_FROM)
    if jpath.is_file():
        s.notes = (*s.notes, f"the journal {str(jpath)!r} of a later, unfinished recording to this path exists "
                             "(load it with allow_incomplete=True, or recover_session)")
    return s


def _unsealed(p: Path) -> bool:
    """True for a regular file starting with the HDF5 signature (no seal); a FIFO is opened
    without blocking and is not one (the reader then refuses it)."""
    try:
        fd = os.open(p, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_BINARY", 0))
    except OSError:
        return False
    try:
        return stat.S_ISREG(os.fstat(fd).st_mode) and os.read(fd, 8) == b"\x89HDF\r\n\x1a\n"
    except OSError:
        return False
    finally:
        os.close(fd)
