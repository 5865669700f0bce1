"""The configuration of a session as typed records: scan, contact, cantilever, haptics, material, device.

A session's ``/metadata`` (:mod:`arsurf.sessions.schema`) is JSON; this module is the one place
where that JSON becomes typed, frozen records and back:

* :meth:`SessionConfig.from_metadata` checks the JSON once, where it enters (a session file, a
  journal, :func:`arsurf.assembly.session_metadata` for the CLI and the presets), with one-line
  :class:`~arsurf.errors.SessionError` messages naming the key, the rule and the value;
* :meth:`SessionConfig.to_metadata` writes it back (the layout the readers of format version 2
  and later know: ``tip_radius``, ``friction``, ``deform`` at the top, the contact law under
  ``contact``, the processing under ``scan.processing``...);
* the builders (:func:`arsurf.assembly.build_model`, :func:`~arsurf.assembly.build_loop`) take
  the records, not the dict.

Units are SI (m, Pa, J/m^2, N, Hz, rad), as in the JSON. A value that was not recorded is
:data:`UNSET` (not written back, so a builder's default applies); ``None`` is a recorded null
(e.g. ``haptics.filter_cutoff = None``: the filter off).

Adding a setting is one line: a field ``name: type = UNSET`` on its record (the JSON key is the
field's name; an optional key needs no other change), plus, if it has a rule, its check in the
record's ``from_metadata``. Keys no record names are kept as they are (``SessionConfig.extra``:
e.g. ``preset``, ``instrument``; ``extra`` of the haptics, material and device records), so a
newer writer's additions survive a round trip and an older reader still loads the file.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, Mapping

from arsurf.errors import SessionError

__all__ = ["UNSET", "ScanConfig", "ContactConfig", "CantileverConfig", "HapticsConfig", "MaterialConfig",
           "DeviceConfig", "SessionConfig"]


class _Unset:
    """The value of a setting the metadata does not record (falsy, one instance)."""

    _instance = None

    def __new__(cls):
        if cls._instance is None:
            cls._instance = super().__new__(cls)
        return cls._instance

    def __repr__(self) -> str:
        return "UNSET"

    def __bool__(self) -> bool:
        return False

    def __reduce__(self):
        return (_Unset, ())


#: a setting the metadata does not record
UNSET: Any = _Unset()


def _need(d: Mapping, key: str, where: str):
    if not isinstance(d, Mapping) or key not in d:
        raise SessionError(f"session metadata lacks {where}.{key}; record it with arsurf.session_metadata")
    return d[key]


def _is_hex64(d) -> bool:
    return isinstance(d, str) and len(d) == 64 and all(c in "0123456789abcdef" for c in d)


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _from(cls, d: Mapping, *, where: str):
    """A record of ``cls`` from the JSON object ``d``: its fields' keys (absent: UNSET); the keys no
    field names go to the record's ``extra`` (kept as recorded)."""
    if not isinstance(d, Mapping):
        raise SessionError(f"metadata {where} must be an object (got {d!r})")
    names = {f.name for f in dataclasses.fields(cls)} - {"extra"}
    return cls(**{k: v for k, v in d.items() if k in names},
               extra=MappingProxyType({k: v for k, v in d.items() if k not in names}))


def _json(record) -> dict:
    """The JSON object of a record: its recorded fields (UNSET left out) and its ``extra`` keys."""
    out = {f.name: getattr(record, f.name) for f in dataclasses.fields(record)
           if f.name != "extra" and getattr(record, f.name) is not UNSET}
    out.update(getattr(record, "extra", None) or {})
    return out


@dataclass(frozen=True)
class ScanConfig:
    """The scan file and how it was prepared and fitted (``scan`` of the metadata).

    ``path``, ``sha256`` (hex of the file bytes), ``channel`` (None: the topography), and the
    arguments of :func:`arsurf.scan.prepare.prepare_scan` and :func:`arsurf.fit_surface`:
    ``level`` (method), ``sigma`` (m), ``inpaint``, ``control_shape`` ((nu, nv) or None),
    ``smoothing`` (P-spline weight).
    """

    path: str
    sha256: str
    channel: str | None = None
    level: str = "plane"
    sigma: float = 0.0
    inpaint: bool = True
    control_shape: tuple[int, int] | None = None
    smoothing: float = 0.0

    @classmethod
    def from_metadata(cls, scan: Mapping) -> "ScanConfig":
        path = _need(scan, "path", "scan")
        if not isinstance(path, str) or not path:
            raise SessionError(f"metadata scan.path must be a non-empty string (got {path!r})")
        digest = _need(scan, "sha256", "scan")
        if not _is_hex64(digest):
            raise SessionError(f"metadata scan.sha256 must be 64 lowercase hex digits (got {digest!r}); "
                               "compute it with arsurf.scan_sha256(path)")
        channel = scan.get("channel")
        if channel is not None and not isinstance(channel, str):
            raise SessionError(f"metadata scan.channel must be a string or null (got {channel!r})")
        proc = _need(scan, "processing", "scan")
        lv = _need(proc, "level", "scan.processing")
        if not isinstance(lv, str):
            raise SessionError(f"metadata scan.processing.level must be a method name (got {lv!r})")
        sg = _need(proc, "sigma", "scan.processing")
        if not _is_number(sg) or not sg >= 0.0:
            raise SessionError(f"metadata scan.processing.sigma must be >= 0 metres (got {sg!r})")
        ip = _need(proc, "inpaint", "scan.processing")
        if not isinstance(ip, bool):
            raise SessionError(f"metadata scan.processing.inpaint must be true or false (got {ip!r})")
        cs = proc.get("control_shape")
        if cs is not None and not (isinstance(cs, (list, tuple)) and len(cs) == 2
                                   and all(isinstance(c, int) and not isinstance(c, bool) and c >= 4 for c in cs)):
            raise SessionError(f"metadata scan.processing.control_shape must be null or two integers >= 4 "
                               f"(got {cs!r})")
        sm = proc.get("smoothing", 0.0)
        if not _is_number(sm) or not sm >= 0.0:
            raise SessionError(f"metadata scan.processing.smoothing must be >= 0 (got {sm!r})")
        return cls(path, digest, channel, lv, sg, ip, None if cs is None else tuple(cs), sm)

    def to_metadata(self) -> dict:
        return {"path": self.path, "sha256": self.sha256, "channel": self.channel,
                "processing": {"level": self.level, "sigma": self.sigma, "inpaint": self.inpaint,
                               "control_shape": None if self.control_shape is None else list(self.control_shape),
                               "smoothing": self.smoothing}}


@dataclass(frozen=True)
class ContactConfig:
    """The tip and its contact law: ``tip_radius`` (m), Maugis-Dugdale ``effective_modulus`` (Pa),
    ``work_of_adhesion`` (J/m^2), ``dugdale_stress`` (Pa; None: from w), the friction
    coefficients (``static_friction`` UNSET: the kinetic one), ``deform`` (the model dents), the
    friction law (``friction_law``: ``"adhesive"``, ``"area"`` or ``"compressive"``,
    :mod:`arsurf.contact.friction`; UNSET, a session recorded before the law was recorded: the
    compressive law it ran with), the area law's ``shear_strength`` (Pa), ``zone_energy`` (the
    model's contact the energy of the whole tip, :class:`~arsurf.model.ARModel`; UNSET: False) and
    ``zone_closed_form`` (with it, its closed form where trusted; UNSET, a session recorded before
    the key existed: False, the lattice's sum it ran with)."""

    tip_radius: float
    effective_modulus: float
    work_of_adhesion: float
    dugdale_stress: float | None = None
    friction: float = 0.2
    static_friction: float | None = UNSET
    deform: bool = True
    friction_law: str = UNSET
    shear_strength: float | None = UNSET
    zone_energy: bool = UNSET
    zone_closed_form: bool = UNSET

    @classmethod
    def from_metadata(cls, meta: Mapping) -> "ContactConfig":
        """From the metadata's top level (``tip_radius``, ``friction``, ``static_friction``,
        ``deform``, ``friction_law``, ``shear_strength``) and its ``contact`` object (the law)."""
        c = meta["contact"]
        for k in ("effective_modulus", "work_of_adhesion"):
            _need(c, k, "contact")
        return cls(meta["tip_radius"], c["effective_modulus"], c["work_of_adhesion"], c.get("dugdale_stress"),
                   meta["friction"], meta.get("static_friction", UNSET), meta.get("deform", True),
                   meta.get("friction_law", UNSET), meta.get("shear_strength", UNSET), meta.get("zone_energy", UNSET),
                   meta.get("zone_closed_form", UNSET))

    def law(self) -> dict:
        """The ``contact`` object of the metadata."""
        return {"effective_modulus": self.effective_modulus, "work_of_adhesion": self.work_of_adhesion,
                "dugdale_stress": self.dugdale_stress}

    def to_metadata(self) -> dict:
        """The top-level keys this record writes (``contact`` among them)."""
        out = {"tip_radius": self.tip_radius, "contact": self.law(), "friction": self.friction,
               "deform": self.deform}
        for key in ("static_friction", "friction_law", "shear_strength", "zone_energy", "zone_closed_form"):
            if getattr(self, key) is not UNSET:
                out[key] = getattr(self, key)
        return out


@dataclass(frozen=True)
class CantileverConfig:
    """The :class:`~arsurf.force.cantilever.Cantilever` constructor arguments (SI; UNSET: its default)."""

    length: float = UNSET
    width: float = UNSET
    thickness: float = UNSET
    tip_height: float = UNSET
    youngs_modulus: float = UNSET
    poisson_ratio: float = UNSET
    normal_stiffness: float | None = UNSET
    torsional_stiffness: float | None = UNSET
    beta: float | None = UNSET

    @classmethod
    def from_metadata(cls, lever: Mapping) -> "CantileverConfig":
        if not isinstance(lever, Mapping):
            raise SessionError(f"metadata cantilever must be an object of constructor arguments (got {lever!r})")
        names = [f.name for f in dataclasses.fields(cls)]
        unknown = sorted(set(lever) - set(names))
        if unknown:
            raise SessionError(f"metadata cantilever has unknown arguments {unknown}; allowed: {names}")
        return cls(**lever)

    def arguments(self, *, drop_none: bool = False) -> dict:
        """The constructor's keyword arguments (``drop_none``: without the recorded nulls)."""
        return {k: v for k, v in _json(self).items() if not (drop_none and v is None)}

    to_metadata = arguments


@dataclass(frozen=True)
class HapticsConfig:
    """The haptic loop's settings (``haptics`` of the metadata; UNSET: the demo's value).

    ``coupling`` ("direct" | "force_position"), ``scale`` (probe m per stylus m), ``force_gain``
    (hand N per probe N), ``rate`` (Hz), ``source``, ``blend``, ``filter_cutoff`` (Hz; None:
    off), ``signal_noise`` (rad), ``seed``, ``ramp_time`` (s), ``coupling_stiffness`` (N/m at the
    handle), ``virtual_coupling`` (False: the direct loop runs without one; UNSET or True: with
    ``coupling_stiffness``, else one chosen from the device and the rate), ``passivity``,
    ``max_rate`` (N/s), ``jump_blend`` (s over which a jump of the coupled tip reaches the hand,
    :mod:`arsurf.contact.jump_blend`; 0: in one tick; UNSET in a recorded session: recorded before the
    blend existed, replayed in one tick), and the force-position coupling's ``K_fp`` (N/m),
    ``B_fp`` (N s/m), ``G_n``.
    """

    coupling: str = UNSET
    scale: float = UNSET
    force_gain: float = UNSET
    rate: float = UNSET
    source: str = UNSET
    blend: float = UNSET
    filter_cutoff: float | None = UNSET
    signal_noise: float = UNSET
    seed: int = UNSET
    ramp_time: float = UNSET
    coupling_stiffness: float | None = UNSET
    virtual_coupling: bool = UNSET
    passivity: bool = UNSET
    max_rate: float = UNSET
    jump_blend: float = UNSET
    K_fp: float = UNSET
    B_fp: float = UNSET
    G_n: float = UNSET
    #: settings this record does not name (kept; :func:`arsurf.assembly.build_loop` refuses them)
    extra: Mapping[str, Any] = field(default_factory=dict)

    @classmethod
    def from_metadata(cls, haptics: Mapping | None) -> "HapticsConfig":
        haptics = haptics or {}
        if not isinstance(haptics, Mapping):
            raise SessionError(f"metadata haptics must be an object (got {haptics!r})")
        return _from(cls, haptics, where="haptics")

    def get(self, name: str, default=None):
        """The recorded value of ``name``, or ``default`` when it is not recorded."""
        value = getattr(self, name)
        return default if value is UNSET else value

    def to_metadata(self) -> dict:
        return _json(self)


@dataclass(frozen=True)
class MaterialConfig:
    """The material map the model looks E* and w up in (``material`` of the metadata,
    :meth:`arsurf.contact.material_map.MaterialMap.to_metadata`): ``channels`` (role -> channel),
    ``units`` (role -> unit), ``conversion`` (:class:`~arsurf.contact.material_conversion.MaterialConversion`
    JSON, SI), ``offset`` ((x0, y0) m), ``processing`` (``sigma`` m, ``smoothing``,
    ``control_shape``), ``sha256`` (the map's hash), ``path`` (None: the scan file) and its
    ``file_sha256``."""

    channels: Mapping[str, str]
    conversion: Mapping[str, Any]
    sha256: str
    units: Mapping[str, str] | None = UNSET
    offset: tuple[float, float] = UNSET
    processing: Mapping[str, Any] | None = UNSET
    path: str | None = UNSET
    file_sha256: str | None = UNSET
    extra: Mapping[str, Any] = field(default_factory=dict)

    @classmethod
    def from_metadata(cls, spec: Mapping, roles) -> "MaterialConfig":
        """Checked against the channel ``roles`` a map knows (the conversion is checked by its class)."""
        if not isinstance(spec, Mapping):
            raise SessionError(f"metadata material must be an object (got {spec!r})")
        chans = _need(spec, "channels", "material")
        if not (isinstance(chans, Mapping) and all(isinstance(k, str) and isinstance(v, str) for k, v in chans.items())
                and set(chans) <= set(roles) and {"modulus", "adhesion"} <= set(chans)):
            raise SessionError(f"metadata material.channels must map roles {sorted(roles)} (modulus and "
                               f"adhesion at least) to channel names (got {chans!r})")
        units = spec.get("units") or {}
        if not (isinstance(units, Mapping) and all(isinstance(v, str) for v in units.values())
                and set(units) <= set(roles)):
            raise SessionError(f"metadata material.units must map roles to unit names (got {units!r})")
        conversion = _need(spec, "conversion", "material")
        off = spec.get("offset", [0.0, 0.0])
        if not (isinstance(off, (list, tuple)) and len(off) == 2
                and all(_is_number(v) and math.isfinite(v) for v in off)):
            raise SessionError(f"metadata material.offset must be two finite numbers in metres (got {off!r})")
        proc = spec.get("processing") or {}
        for key in ("sigma", "smoothing"):
            v = proc.get(key, 0.0)
            if not _is_number(v) or not v >= 0.0:
                raise SessionError(f"metadata material.processing.{key} must be >= 0 (got {v!r})")
        for key in ("sha256", "file_sha256"):
            d = spec.get(key)
            if d is not None and not _is_hex64(d):
                raise SessionError(f"metadata material.{key} must be 64 lowercase hex digits (got {d!r})")
        if spec.get("sha256") is None:
            raise SessionError("metadata material lacks sha256 (the hash of the map); record it with "
                               "arsurf.session_metadata(material=...)")
        path = spec.get("path")
        if path is not None and not (isinstance(path, str) and path and spec.get("file_sha256")):
            raise SessionError(f"metadata material.path must be null (the scan file) or a path with its file_sha256 "
                               f"(got {path!r})")
        return _from(cls, spec, where="material")

    def to_metadata(self) -> dict:
        return _json(self)


@dataclass(frozen=True)
class DeviceConfig:
    """The haptic device a session ran on (``device`` of the metadata): its backend ``interface``,
    ``name``, ``max_force`` (N; absent when the device has no finite limit) and ``workspace`` ((3,)
    m: the extents of the box centred on the home position, :class:`~arsurf.haptics.device.DeviceInfo`).
    The session reader bounds the recorded stylus positions and device forces by these
    (:func:`arsurf.sessions.reader.check_ticks`)."""

    interface: str = UNSET
    name: str = UNSET
    max_force: float = UNSET
    workspace: list = UNSET
    extra: Mapping[str, Any] = field(default_factory=dict)

    @classmethod
    def from_metadata(cls, device: Mapping) -> "DeviceConfig":
        return _from(cls, device, where="device")

    @classmethod
    def of(cls, info, interface: str, **extra) -> "DeviceConfig":
        """The record of a device whose limits are ``info`` (a :class:`~arsurf.haptics.device.DeviceInfo`).

        >>> from arsurf.haptics.device import TOUCH_X
        >>> DeviceConfig.of(TOUCH_X, "virtual").to_metadata()["workspace"]
        [0.12, 0.16, 0.12]
        """
        mf = float(info.max_force)
        return cls(interface=interface, name=info.name, **({"max_force": mf} if math.isfinite(mf) else {}),
                   workspace=[float(w) for w in info.workspace], extra=dict(extra))

    def to_metadata(self) -> dict:
        return _json(self)


#: the metadata keys every session records
REQUIRED = ("scan", "tip_radius", "contact", "friction", "cantilever")


@dataclass(frozen=True)
class SessionConfig:
    """A session's whole configuration: one record per part, and the keys no record names.

    ``tubes`` (the tube scene's JSON, :meth:`arsurf.manipulation.scene.TubeScene.to_metadata`),
    ``calibration`` (free object), ``loop_rate`` (Hz or None) and ``extra`` (any other key, e.g.
    ``preset``, ``instrument``) are kept as recorded.
    """

    scan: ScanConfig
    contact: ContactConfig
    cantilever: CantileverConfig
    haptics: HapticsConfig = field(default_factory=HapticsConfig)
    material: MaterialConfig | None = None
    device: DeviceConfig | None = None
    tubes: Mapping | None = None
    calibration: Mapping = field(default_factory=dict)
    loop_rate: float | None = None
    extra: Mapping[str, Any] = field(default_factory=dict)

    @classmethod
    def from_metadata(cls, meta: Mapping, *, material_roles=()) -> "SessionConfig":
        """The records of session metadata (JSON), checked; :class:`SessionError` names the first
        key that breaks a rule. ``material_roles``: the channel roles a material map knows."""
        if not isinstance(meta, Mapping):
            raise SessionError(f"session metadata must be a dict (got {type(meta).__name__})")
        missing = [k for k in REQUIRED if k not in meta]
        if missing:
            raise SessionError(f"session metadata lacks {missing}; build it with arsurf.session_metadata")
        scan = ScanConfig.from_metadata(meta["scan"])
        lever = CantileverConfig.from_metadata(meta["cantilever"])
        contact = ContactConfig.from_metadata(meta)
        haptics = HapticsConfig.from_metadata(meta.get("haptics"))
        spec = meta.get("material")
        material = None if spec is None else MaterialConfig.from_metadata(spec, material_roles)
        device = None if meta.get("device") is None else DeviceConfig.from_metadata(meta["device"])
        named = {"scan", "tip_radius", "contact", "friction", "static_friction", "deform", "friction_law",
                 "shear_strength", "zone_energy", "zone_closed_form", "cantilever", "haptics", "material", "device",
                 "tubes", "calibration", "loop_rate"}
        return cls(scan, contact, lever, haptics, material, device, meta.get("tubes"),
                   MappingProxyType(dict(meta.get("calibration") or {})), meta.get("loop_rate"),
                   MappingProxyType({k: v for k, v in meta.items() if k not in named}))

    def to_metadata(self) -> dict:
        """The session's ``/metadata`` JSON (the one place the records are written)."""
        meta = {"scan": self.scan.to_metadata(), **self.contact.to_metadata(),
                "cantilever": self.cantilever.to_metadata(), "calibration": dict(self.calibration),
                "haptics": self.haptics.to_metadata(), "loop_rate": self.loop_rate, **self.extra}
        for key, value in (("material", self.material), ("device", self.device)):
            if value is not None:
                meta[key] = value.to_metadata()
        if self.tubes is not None:
            meta["tubes"] = self.tubes
        return meta
