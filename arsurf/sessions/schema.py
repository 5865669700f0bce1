r"""Session files: the schema of the HDF5 file a live loop records, and its checksums.

A session is everything needed to re-run the model offline (:func:`arsurf.replay.replay.replay`):
which scan file (with the SHA-256 of its bytes) and how it was turned into a surface, the tip,
contact law, friction and cantilever of the :class:`~arsurf.model.ARModel`, and per tick the
probe pose, the measured signals and what the loop did. :mod:`arsurf.sessions.writer` records
it, :mod:`arsurf.sessions.reader` reads and checks it; this module is what both agree on: the
tables below (:data:`TICK_FIELDS`), the per-tick fields of a given metadata and the SHA-256
digests of the ``checksums`` attribute.

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

The file is *sealed* (:mod:`arsurf.sessions.sealed`): its first 512 bytes (the HDF5 user block)
hold its length and a SHA-256 of all its bytes.

Group ``/metadata``: one attribute per key, its value a JSON text (:func:`arsurf.assembly.session_metadata`
builds it; :class:`arsurf.config.SessionConfig` is its typed form, read and written in one place):

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
``static_friction``         optional: the static coefficient mu_s of the stick-slip proxy
                            (absent: mu)
``friction_law``            optional: ``"adhesive"`` (``mu (P + |P_c|)``, what sessions record
                            by default), ``"area"`` (tau pi a^2) or ``"compressive"`` (mu P
                            for P > 0 only; absent: this law, the one sessions recorded before
                            the key existed ran with), :mod:`arsurf.contact.friction`
``shear_strength``          Pa, the interfacial shear strength tau of the ``"area"`` law
``zone_energy``             optional: true, the model's contact was the energy of the whole tip
                            (:mod:`arsurf.contact.zone_energy`; absent: the contacts at the
                            minima of the distance)
``zone_closed_form``        optional, with ``zone_energy``: true, that energy was taken in closed
                            form where its checks trusted it (:mod:`arsurf.contact.zone_quadric`);
                            false or absent (sessions recorded before the key), the lattice's sum
                            everywhere
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
the table's unit for files written before it existed (:attr:`Session.units <arsurf.sessions.reader.Session.units>`).

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
                                                   :mod:`arsurf.sessions.instrument_session`): the
                                                   tip position the instrument measured, m (scan
                                                   frame, tip-sphere centre)
========================  ========  ======  =====  ===========================================

``safety_flags``, ``tube_poses`` and ``instrument_position`` are the optional datasets: the
writer always adds the first, the second when the metadata has a ``tubes`` scene and the third
when it has an ``instrument``; readers accept their absence (files written before they existed,
sessions without nano-objects or an instrument), so ``format_version`` does not change. When
present, ``safety_flags`` must be integers, one per tick, and the shapes of the others are
checked (k rows of 3 per tick for the tubes, 3 per tick for the instrument).
"""
from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from arsurf.assembly import tube_count
from arsurf.errors import require
from arsurf.sessions import journal as _journal

__all__ = [
    "FORMAT",
    "FORMAT_VERSION",
    "SUPPORTED_VERSIONS",
    "MD_STATUS_NOT_GIVEN",
    "TICK_FIELDS",
    "TickField",
    "contact_fields",
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


def _h5py():
    return require("h5py", "core", "session files")


def contact_fields(tick) -> dict:
    """The contact fields of :meth:`~arsurf.sessions.writer.SessionWriter.append` from a
    :class:`~arsurf.model.ModelTick`.

    Examples
    --------
    >>> # writer.append(t=t, probe_position=c, probe_velocity=v, force=f, **contact_fields(tick))
    """
    return {"contact_point": tick.point, "contact_normal": tick.normal, "depth": tick.depth,
            "contact_radius": tick.contact_radius, "load": tick.load, "in_contact": int(tick.in_contact),
            "md_status": tick.md_status, "decoupling_flags": tick.decoupling_flags}


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
