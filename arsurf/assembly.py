r"""Model assembly: the one place where a scan, a tip, a contact law, a cantilever and a haptic
loop are put together.

Every caller that needs an AR model goes through here - the demo, the interactive viewer, the
live bridge loop and offline replay - so a recorded session rebuilds exactly the model that ran:

* :func:`session_metadata` (or :func:`preset_metadata` from a named :class:`Preset`) writes down
  everything the model needs (scan and its processing, tip, contact law, friction, cantilever,
  haptic settings, optional tube scene) as checked JSON - the ``/metadata`` group of a session;
* :func:`build_model` turns that metadata into the processed scan, the fitted surface and the
  :class:`~arsurf.model.ARModel` (and the tube scene); :func:`make_model` does the last step for
  a surface that is already fitted; :func:`build_loop` adds the
  :class:`~arsurf.haptics.loop.HapticLoop` from the recorded haptic settings.

The steps of :func:`build_model` are those of the pipeline (docs/design.rst, "The pipeline"): load → level → smooth
(Gaussian, :math:`\sigma` in metres) → fit (bicubic B-spline) → ARModel (tip sphere of radius R,
Maugis-Dugdale contact with :math:`E^*, w, \sigma_0`, friction coefficient, cantilever).

Examples
--------
>>> sorted(PRESETS)
['demo', 'mwcnt-push', 'spline-ar', 'thesis-haptics', 'tipless-rolling', 'viewer']
>>> p = preset("tipless-rolling")
>>> round(p.cantilever["length"] * 1e6), p.haptics["coupling"]
(220, 'force_position')
>>> preset("seed003") is p          # the name it had before (PRESET_ALIASES), still accepted
True
"""
from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any, Mapping

import numpy as np

from arsurf._files import sha256_file
from arsurf.config import UNSET, CantileverConfig, ContactConfig, HapticsConfig, SessionConfig, _is_number
from arsurf.contact.jump_blend import BLEND_TIME
from arsurf.data import bundled_scan
from arsurf.errors import ArsurfError, ScanFileNotFound, SessionError

__all__ = [
    "BRIDGE_HAPTICS",
    "BUNDLED_SCAN",
    "LEVER",
    "ModelSetup",
    "PRESETS",
    "Preset",
    "build_loop",
    "build_model",
    "check_metadata",
    "loop_metadata",
    "make_model",
    "passivity_reserve",
    "preset_metadata",
    "scan_sha256",
    "session_metadata",
]

#: the synthetic nanotubes scan the demo and the viewer open by default (package data, :mod:`arsurf.data`)
BUNDLED_SCAN = bundled_scan("nanotubes")

#: a common rectangular silicon contact lever (450 x 50 x 2.5 um, 15 um tip; k ~ 0.2 N/m)
LEVER = MappingProxyType(dict(length=450e-6, width=50e-6, thickness=2.5e-6, tip_height=15e-6,
                              youngs_modulus=169e9, poisson_ratio=0.27))

#: the friction laws a session may record (:data:`arsurf.contact.friction.LAW_NAMES`), the one new
#: sessions record and the one of sessions recorded before the law was (friction only for P > 0)
FRICTION_LAWS = ("adhesive", "area", "compressive")
DEFAULT_FRICTION_LAW = "adhesive"
LEGACY_FRICTION_LAW = "compressive"
_CANTILEVER_ARGS = ("length", "width", "thickness", "tip_height", "youngs_modulus", "poisson_ratio",
                    "normal_stiffness", "torsional_stiffness", "beta")
_HAPTIC_KEYS = ("coupling", "scale", "force_gain", "rate", "source", "blend", "filter_cutoff", "signal_noise",
                "seed", "ramp_time", "coupling_stiffness", "virtual_coupling", "passivity", "max_rate", "jump_blend")


@dataclass(frozen=True)
class Preset:
    """A named set of model and haptic settings (SI units), with where each value comes from.

    Attributes
    ----------
    name, description : str
    tip_radius : float, m
    effective_modulus : float, Pa
        Contact modulus :math:`E^*` of tip and sample.
    work_of_adhesion : float, J/m^2
    cantilever : mapping
        :class:`~arsurf.force.cantilever.Cantilever` constructor arguments.
    friction : float
        Coefficient of the simulated friction.
    level : str
        :func:`arsurf.level` method.
    sigma : float, m
        Gaussian smoothing width before the fit.
    haptics : mapping
        ``coupling`` ("direct" | "force_position"), ``scale`` (probe m per stylus m),
        ``force_gain`` (hand N per probe N), ``rate`` (Hz), ``source``, ``filter_cutoff`` (Hz),
        ``signal_noise`` (rad), ``coupling_stiffness`` (N/m at the handle: the direct coupling's
        virtual coupling, :func:`arsurf.haptics.gains.coupling_stiffness`; absent: the loop
        chooses it from the device and the rate, :meth:`~arsurf.haptics.loop.HapticLoop.direct`),
        ``virtual_coupling`` (False: none, explicitly), ``passivity`` (the passivity controller
        on; absent: on), and for the force-position coupling ``K_fp``, ``B_fp``, ``G_n``.
    sources : str
        Where the values come from; values a source does not give are the demo's, and said so.
    """

    name: str
    description: str
    tip_radius: float
    effective_modulus: float
    work_of_adhesion: float
    cantilever: Mapping[str, float]
    friction: float
    level: str
    sigma: float
    haptics: Mapping[str, Any] = field(default_factory=dict)
    sources: str = ""


def _contact(tip: str, sample: str) -> tuple[float, float]:
    """E* (Pa) and w (J/m^2) of two :data:`arsurf.contact.materials.MATERIALS` presets."""
    from arsurf.contact.materials import effective_modulus, work_of_adhesion

    return effective_modulus(tip, sample), work_of_adhesion(tip, sample)


# no coupling_stiffness: the loop chooses the virtual coupling from the device it runs on and the rate
# (arsurf.haptics.gains.coupling_stiffness; 2 b / T = 66.7 N/m for the demo's VirtualDevice at 1 kHz)
_DEMO_HAPTICS = MappingProxyType({"coupling": "direct", "scale": 1e-5, "force_gain": 1e5, "rate": 1000.0,
                                  "source": "blended", "filter_cutoff": 50.0, "signal_noise": 2e-7,
                                  "virtual_coupling": True, "passivity": True, "jump_blend": BLEND_TIME})


def _presets() -> dict[str, Preset]:
    e_si_ps, w_si_ps = _contact("Si", "polystyrene")
    e_si_pc, w_si_pc = _contact("Si", "polycarbonate")
    demo = Preset(
        "demo", "the demo: a 20 nm silicon tip on a soft adhesive polymer-like film (lambda ~ 0.5, dents visibly)",
        tip_radius=20e-9, effective_modulus=10e9, work_of_adhesion=0.1, cantilever=LEVER, friction=0.2,
        level="plane", sigma=2e-9, haptics=_DEMO_HAPTICS,
        sources="chosen for the demo; scale 1 mm -> 10 nm, K_f = 1e5 (1e6 chatters: docs/design.rst, Design notes)")
    return {
        "demo": demo,
        "viewer": dataclasses.replace(
            demo, name="viewer", description="the interactive viewer: Si tip on polystyrene (arsurf.MATERIALS)",
            effective_modulus=e_si_ps, work_of_adhesion=w_si_ps, sigma=0.0,
            sources="E* and w from the Si and polystyrene presets of arsurf.contact.materials; the rest is the demo's"),
        "mwcnt-push": dataclasses.replace(
            demo, name="mwcnt-push", description="MWCNT pushing on polycarbonate with a calibrated lever ([MWCNT])",
            effective_modulus=e_si_pc, work_of_adhesion=w_si_pc,
            cantilever=MappingProxyType(dict(LEVER, normal_stiffness=38.6, torsional_stiffness=8.56e-7)),
            sources="[MWCNT] Sec. 2.3: k = 38.6 N/m, k_ct = 8.56e-7 N m/rad; Sec. 4.2: the tubes lie on "
                    "polycarbonate (E* and w of the Si and polycarbonate presets of arsurf.contact.materials, "
                    "the tip's material assumed); tip radius and lever geometry are not given there: the demo's"),
        "thesis-haptics": dataclasses.replace(
            demo, name="thesis-haptics", description="force-feedback haptic interface ([Alabdulmuhsin] thesis)",
            cantilever=MappingProxyType(dict(LEVER, normal_stiffness=0.3)), sigma=0.0,
            haptics=MappingProxyType(dict(_DEMO_HAPTICS, force_gain=15e6, source="measured", filter_cutoff=None)),
            sources="[Alabdulmuhsin] Tables 4.2-4.6: k = 0.3 N/m, K_f = 15e6; scale, tip and sample: the demo's"),
        "spline-ar": dataclasses.replace(
            demo, name="spline-ar", description="the spline AR interface ([SplineAR]): smoothing, B-spline, MD, dent, "
                                              "decoupling with the contact normal",
            haptics=MappingProxyType(dict(_DEMO_HAPTICS, source="measured")),
            sources="[SplineAR] gives the method, not the numbers: the demo's values with measured signals"),
        "tipless-rolling": dataclasses.replace(
            demo, name="tipless-rolling", description="2D rolling telemanipulation with a tipless beam ([Bolopion])",
            tip_radius=25e-6, sigma=0.0,
            cantilever=MappingProxyType(dict(length=220e-6, width=27e-6, thickness=2.9e-6, tip_height=0.0,
                                             youngs_modulus=150e9, poisson_ratio=0.17)),
            haptics=MappingProxyType({"coupling": "force_position", "scale": 1.0 / 50e3, "force_gain": 25e6,
                                      "rate": 1000.0, "source": "measured", "filter_cutoff": None,
                                      "signal_noise": 0.0, "K_fp": 100.0, "B_fp": 0.1, "G_n": 825.0}),
            sources="[Bolopion] Table I (beam 220 x 27 x 2.9 um, E = 150 GPa, nu = 0.17), 25 um spheres, Fig. 5 gains "
                    "(A_f = 25e6, A_d = 50e3, K_fp = 100 N/m, B_fp = 0.1 N s/m, G_n = 825); contact law: the demo's"),
    }


#: the named presets (read-only); :func:`preset_metadata` turns one into session metadata
PRESETS: Mapping[str, Preset] = MappingProxyType(_presets())
#: the names the source presets had before they were named for what they are (sessions and scripts
#: that say ``seed000``..``seed003`` keep working): old name -> preset name
PRESET_ALIASES: Mapping[str, str] = MappingProxyType({
    "seed000": "mwcnt-push", "seed001": "thesis-haptics", "seed002": "spline-ar", "seed003": "tipless-rolling"})

#: the haptic settings of the bridge loop (``metadata["haptics"]`` of its sessions; ``scale``
#: is the command line's ``--scale``): the direct coupling, the simulated force (MD load +
#: friction, no synthesised signals), a 200 Hz low-pass, the passivity controller, the tip's jumps
#: blended over :data:`~arsurf.contact.jump_blend.BLEND_TIME`, and the
#: virtual coupling the loop chooses from the device and the rate (recorded with the session:
#: :func:`loop_metadata`)
BRIDGE_HAPTICS = MappingProxyType({"coupling": "direct", "scale": 1e-5, "force_gain": 1e5, "rate": 1000.0,
                                   "source": "simulated", "filter_cutoff": 200.0, "signal_noise": 0.0,
                                   "passivity": True, "jump_blend": BLEND_TIME})


def preset(name: str | Preset) -> Preset:
    """The :class:`Preset` called ``name``, or by its old name in :data:`PRESET_ALIASES` (a Preset
    is returned as is)."""
    if isinstance(name, Preset):
        return name
    try:
        return PRESETS[PRESET_ALIASES.get(name, name)]
    except (KeyError, TypeError):
        raise SessionError(f"unknown preset {name!r}; presets are {sorted(PRESETS)}") from None


# ---------------------------------------------------------------------------------------------
# metadata


def scan_sha256(path: str | os.PathLike) -> str:
    """SHA-256 (hex) of a file's bytes, read in 1 MiB blocks.

    Raises
    ------
    ScanFileNotFound
        The file does not exist.

    Examples
    --------
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
    return sha256_file(p)


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
                     loop_rate: float | None = None, material=None, friction_law: str = DEFAULT_FRICTION_LAW,
                     shear_strength: float | None = None, zone_energy: bool = False, zone_closed_form: bool = True,
                     **extra) -> dict:
    """The metadata dict of a session, checked and JSON-ready.

    Parameters
    ----------
    scan : path-like or dict
        The scan file (its SHA-256 is computed here, and the processing is taken from
        ``channel``, ``level``, ``sigma``, ``inpaint``, ``control_shape``, ``smoothing``: the
        arguments of :func:`arsurf.scan.prepare.prepare_scan` and :func:`arsurf.fit_surface`), or a
        complete ``scan`` dict as in the schema (:mod:`arsurf.sessions.schema`).
    tip_radius : float, metres
    contact : MaugisDugdale or dict
        The contact law (or ``{"effective_modulus", "work_of_adhesion", "dugdale_stress"}``).
    cantilever : Cantilever or dict
        The cantilever (or its constructor arguments).
    friction : float
        Coefficient of the model's simulated friction.
    friction_law : str
        The friction's normal (:mod:`arsurf.contact.friction`): ``"adhesive"`` (default, ``mu (P + |P_c|)``),
        ``"area"`` (tau pi a^2, with ``shear_strength`` in Pa) or ``"compressive"`` (mu max(P, 0)).
    deform : bool
        Whether the model dents the surface.
    zone_energy : bool
        The model's contact the energy of the whole tip (:class:`~arsurf.model.ARModel`; recorded
        only when True).
    zone_closed_form : bool
        With ``zone_energy``, its closed form where trusted (:class:`~arsurf.model.ARModel`'s;
        default True; recorded with ``zone_energy``, true or false).
    calibration, haptics : dict, optional
        Free JSON objects (:func:`build_loop` reads ``haptics``).
    loop_rate : float, Hz, optional
    material : MaterialMap or dict, optional
        The material map of the model (:mod:`arsurf.contact.material_map`): its channels,
        conversion, processing and hash are recorded (``material``), with the channel file's path
        and SHA-256 when it is not the scan file; :func:`build_model` rebuilds it and checks the hash.
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
            "deform": deform, "friction_law": friction_law, "cantilever": lever_meta,
            "calibration": dict(calibration or {}),
            "haptics": dict(haptics or {}), "loop_rate": loop_rate, **extra}
    if shear_strength is not None:
        meta["shear_strength"] = shear_strength
    if zone_energy is not False:
        meta["zone_energy"] = zone_energy
        meta["zone_closed_form"] = zone_closed_form
    if material is not None:
        meta["material"] = _material_meta(material, scan_meta["path"])
    return check_metadata(_jsonable(meta, "metadata")).to_metadata()


def preset_metadata(scan: str | os.PathLike, preset_name: str | Preset = "demo", **overrides) -> dict:
    """Session metadata of a model built on ``scan`` with the settings of a :class:`Preset`.

    ``overrides`` replace any :func:`session_metadata` argument (``tip_radius``, ``friction``,
    ``sigma``, ``haptics``, ``tubes``...); the preset's name is recorded under ``preset``.

    Examples
    --------
    >>> meta = preset_metadata(BUNDLED_SCAN, "demo", friction=0.3)
    >>> meta["preset"], meta["friction"], meta["contact"]["effective_modulus"]
    ('demo', 0.3, 10000000000.0)
    """
    p = preset(preset_name)
    args = dict(scan=scan, tip_radius=p.tip_radius, friction=p.friction, level=p.level, sigma=p.sigma,
                contact={"effective_modulus": p.effective_modulus, "work_of_adhesion": p.work_of_adhesion,
                         "dugdale_stress": None},
                cantilever=dict(p.cantilever), haptics=dict(p.haptics),
                loop_rate=p.haptics.get("rate"), preset=p.name)
    args.update(overrides)
    return session_metadata(**args)


def check_metadata(meta: Mapping | SessionConfig) -> SessionConfig:
    """The typed configuration of session metadata (:class:`~arsurf.config.SessionConfig`), checked
    once: the records' rules, then the contact law, cantilever, tube scene and material conversion
    they describe are built (their own checks apply). Raises :class:`SessionError` unless ``meta``
    describes a model that can be rebuilt."""
    from arsurf.contact.material_map import CHANNEL_NAMES

    config = meta if isinstance(meta, SessionConfig) else SessionConfig.from_metadata(
        meta, material_roles=CHANNEL_NAMES)
    _model_parts(config)
    _tube_scene(config)
    _check_material(config.material)
    return config


def _material_meta(material, scan_path: str) -> dict:
    """The ``material`` record of a MaterialMap (or a dict as recorded): channels, units,
    conversion, offset, processing, hash, and the channel file when it is not the scan's."""
    if isinstance(material, Mapping):
        return dict(material)
    spec = material.to_metadata()
    src = material.source
    if src and os.path.abspath(src) != os.path.abspath(scan_path):
        spec["path"], spec["file_sha256"] = src, scan_sha256(src)
    else:
        spec["path"] = None
    return spec


def _check_material(material) -> None:
    """Raise :class:`SessionError` unless the recorded conversion of a material map (a
    :class:`~arsurf.config.MaterialConfig`, or None) is valid."""
    if material is None:
        return
    from arsurf.contact.material_conversion import MaterialConversion

    try:
        MaterialConversion.from_metadata(material.conversion)
    except ArsurfError as exc:
        raise SessionError(f"metadata material.conversion is not valid: {exc}") from exc


def _material_map(config: SessionConfig, scan, scan_path):
    """The MaterialMap a session recorded, rebuilt on the prepared ``scan``'s grid and checked
    against its hash (None without ``material``)."""
    if config.material is None:
        return None
    spec = config.material.to_metadata()
    from arsurf.contact.material_conversion import MaterialConversion
    from arsurf.contact.material_map import CHANNEL_NAMES, material_map_from_file

    path = spec.get("path") or scan_path
    if spec.get("path") is not None:
        actual = scan_sha256(path)
        if actual != spec["file_sha256"]:
            raise SessionError(f"the material channels file {path!r} has SHA-256 {actual}, the session recorded "
                               f"{spec['file_sha256']}; pass the file the session was recorded with")
    proc = spec.get("processing") or {}
    cs = proc.get("control_shape")
    try:
        m = material_map_from_file(
            path, MaterialConversion.from_metadata(spec["conversion"]), height=scan,
            channels={role: spec["channels"].get(role) for role in CHANNEL_NAMES}, units=spec.get("units") or None,
            offset=tuple(spec.get("offset", (0.0, 0.0))), sigma=float(proc.get("sigma", 0.0)),
            smoothing=float(proc.get("smoothing", 0.0)), control_shape=None if cs is None else tuple(cs))
    except ArsurfError as exc:
        raise SessionError(f"the session's material map cannot be rebuilt from {str(path)!r}: {exc}") from exc
    if m.sha256 != spec["sha256"]:
        raise SessionError(f"the material map rebuilt from {str(path)!r} has hash {m.sha256}, the session recorded "
                           f"{spec['sha256']}: the channels or their processing differ from the recording")
    return m


def _tube_scene(config: SessionConfig):
    """The :class:`~arsurf.manipulation.scene.TubeScene` of the configuration (None without ``tubes``)."""
    spec = config.tubes
    if spec is None:
        return None
    from arsurf.manipulation.scene import TubeScene

    try:
        return TubeScene.from_metadata(spec)
    except (ArsurfError, TypeError, ValueError) as exc:
        raise SessionError(f"metadata tubes does not describe a tube scene: {exc}") from exc


def tube_count(meta: Mapping) -> int | None:
    """Number of tubes of the metadata's scene (None without ``tubes``); metadata checked."""
    spec = meta.get("tubes")
    return None if spec is None else len(spec["tubes"])


def _model_parts(config: SessionConfig | Mapping):
    """:func:`_parts` of a configuration's records (or of a metadata dict's model keys:
    ``tip_radius``, ``contact``, ``friction``, ``static_friction``, ``deform``, ``cantilever``,
    ``haptics``)."""
    if isinstance(config, Mapping):
        return _parts(ContactConfig.from_metadata(config), CantileverConfig.from_metadata(config["cantilever"]),
                      HapticsConfig.from_metadata(config.get("haptics")))
    return _parts(config.contact, config.cantilever, config.haptics)


def _parts(contact: ContactConfig, cantilever: CantileverConfig, haptics: HapticsConfig):
    """(tip_radius, MaugisDugdale, Cantilever, model keyword arguments, deform) of the records.

    The keyword arguments are the friction coefficients (``friction`` = mu_k, ``static_friction``
    mu_s, default mu_k), the friction law and its shear strength (a session without
    ``friction_law`` was recorded with :data:`LEGACY_FRICTION_LAW`), the coupling stiffness at the probe's scale, k_vc / (K_f s) from
    ``haptics.coupling_stiffness`` (hand side) of a direct coupling (inf without one), and the
    measured angles' rms noise, ``haptics.signal_noise`` (the loop synthesises signals with it; 0:
    noise-free), None without one (the model's default for signals of unknown noise)."""
    from arsurf.contact.maugis_dugdale import MaugisDugdale
    from arsurf.force.cantilever import Cantilever

    c, h = contact, haptics
    try:
        tip_radius = float(c.tip_radius)
        md = MaugisDugdale(tip_radius, c.effective_modulus, c.work_of_adhesion, c.dugdale_stress)
        lever = Cantilever(**cantilever.arguments())
        friction = float(c.friction)
        static = c.static_friction
        static = friction if static is None or static is UNSET else float(static)
        law = LEGACY_FRICTION_LAW if c.friction_law is UNSET else c.friction_law
        shear = None if c.shear_strength is UNSET or c.shear_strength is None else float(c.shear_strength)
        k_vc = h.get("coupling_stiffness") if h.get("coupling", "direct") == "direct" else None
        if h.get("virtual_coupling", True) is False and k_vc is not None:
            raise SessionError(f"metadata haptics.virtual_coupling is false but haptics.coupling_stiffness is "
                               f"{k_vc!r} N/m; record one or the other")
        k_probe = math.inf if k_vc is None else float(k_vc) / (
            float(h.get("force_gain", _DEMO_HAPTICS["force_gain"])) * float(h.get("scale", _DEMO_HAPTICS["scale"])))
        noise = h.get("signal_noise")
        noise = None if noise is None else float(noise)
        zone = False if c.zone_energy is UNSET else c.zone_energy
        closed = False if c.zone_closed_form is UNSET else c.zone_closed_form  # recorded before it was: the sum
    except (ArsurfError, TypeError, ValueError) as exc:
        raise SessionError(f"the session metadata does not describe a valid model: {exc}") from exc
    if not (math.isfinite(friction) and friction >= 0.0):
        raise SessionError(f"metadata friction must be >= 0 (got {friction!r})")
    if not (math.isfinite(static) and static >= friction):
        raise SessionError(f"metadata static_friction must be >= friction (got {static!r})")
    if law not in FRICTION_LAWS:
        raise SessionError(f"metadata friction_law must be one of {sorted(FRICTION_LAWS)} (got {law!r})")
    if (law == "area") != (shear is not None) or (shear is not None and not (math.isfinite(shear) and shear > 0.0)):
        raise SessionError(f"metadata shear_strength must be > 0 Pa with the area friction law and absent otherwise "
                           f"(got {shear!r} with {law!r})")
    if not k_probe > 0.0:
        raise SessionError(f"metadata haptics.coupling_stiffness must be > 0 N/m (got {k_vc!r})")
    if noise is not None and not (math.isfinite(noise) and noise >= 0.0):
        raise SessionError(f"metadata haptics.signal_noise must be >= 0 rad (got {noise!r})")
    if not isinstance(zone, bool):
        raise SessionError(f"metadata zone_energy must be true or false (got {zone!r})")
    if not isinstance(closed, bool):
        raise SessionError(f"metadata zone_closed_form must be true or false (got {closed!r})")
    return tip_radius, md, lever, dict(friction=friction, static_friction=static, coupling_stiffness=k_probe,
                                       signal_noise=noise, friction_law=law, shear_strength=shear,
                                       zone_energy=zone, zone_closed_form=closed), bool(c.deform)


# ---------------------------------------------------------------------------------------------
# building


@dataclass(frozen=True)
class ModelSetup:
    """What :func:`build_model` made: the processed scan (the substrate when there is a tube scene),
    the fitted (live) surface, the model, the tube scene (None without ``tubes`` metadata), the
    metadata it was built from and its typed form (:class:`~arsurf.config.SessionConfig`)."""

    scan: Any
    surface: Any
    model: Any
    scene: Any = None
    metadata: Mapping | None = None
    config: SessionConfig | None = None


def make_model(surface, *, tip_radius: float, effective_modulus: float, work_of_adhesion: float,
               dugdale_stress: float | None = None, cantilever: Mapping | None = None, friction: float = 0.2,
               deform: bool = True, static_friction: float | None = None, coupling_stiffness: float = math.inf,
               material=None, signal_noise: float | None = None, friction_law: str = DEFAULT_FRICTION_LAW,
               shear_strength: float | None = None, zone_energy: bool = False, zone_closed_form: bool = True):
    """The :class:`~arsurf.model.ARModel` on a fitted ``surface`` (the last step of :func:`build_model`).

    Parameters
    ----------
    surface : BSplineSurface
        The live surface (the model dents it in place when ``deform``).
    tip_radius : float, m
    effective_modulus : float, Pa
    work_of_adhesion : float, J/m^2
    dugdale_stress : float, Pa, optional
        Maugis-Dugdale cohesive stress (default: from w and the equilibrium spacing).
    cantilever : mapping, optional
        :class:`~arsurf.force.cantilever.Cantilever` arguments (default :data:`LEVER`).
    friction, static_friction : float
        Kinetic and static friction coefficients (static default: the kinetic one).
    friction_law : str
        ``"adhesive"`` (default), ``"area"`` or ``"compressive"`` (:mod:`arsurf.contact.friction`).
    shear_strength : float, Pa, optional
        The area law's interfacial shear strength.
    deform : bool
    coupling_stiffness : float, N/m
        The virtual coupling at the probe's scale (:mod:`arsurf.contact.proxy`; inf: none).
    material : MaterialMap, optional
        Per-location E* and w; the contact law given is then the reference (its
        :meth:`~arsurf.contact.material_map.MaterialMap.contact_law`).
    signal_noise : float, rad rms, optional
        Noise of the measured angles (:class:`~arsurf.model.ARModel`; default: unknown).
    zone_energy : bool
        The contact as the energy of the whole tip (:class:`~arsurf.model.ARModel`'s; default False).
    zone_closed_form : bool
        With ``zone_energy``, its closed form where trusted (:class:`~arsurf.model.ARModel`'s; default True).
    """
    contact = ContactConfig(tip_radius, effective_modulus, work_of_adhesion, dugdale_stress, friction,
                            static_friction, deform, friction_law, UNSET if shear_strength is None else shear_strength)
    haptics = HapticsConfig() if signal_noise is None else HapticsConfig(signal_noise=signal_noise)
    from arsurf.model import ARModel

    radius, md, lever, kwargs, dent = _parts(
        contact, CantileverConfig.from_metadata(dict(LEVER if cantilever is None else cantilever)), haptics)
    return ARModel(surface, radius, md, lever, deform=dent, material=material,
                   **dict(kwargs, coupling_stiffness=coupling_stiffness, zone_energy=zone_energy,
                          zone_closed_form=zone_closed_form))


def build_model(metadata: Mapping | SessionConfig, scan_path: str | os.PathLike | None = None) -> ModelSetup:
    """Build the model a session describes: prepare the scan as recorded, fit it, make the ARModel.

    The steps are exactly those of the recording (:func:`arsurf.scan.prepare.prepare_scan` with the
    recorded channel, levelling, smoothing and inpainting, then :func:`arsurf.fit_surface`
    with the recorded control shape and smoothing; a recorded material map is rebuilt from its
    channels and conversion and must have the recorded hash). A live loop that builds its model
    with this function is guaranteed to be replayed bit for bit.

    Parameters
    ----------
    metadata : dict or SessionConfig
        Session metadata (:func:`session_metadata`, :func:`preset_metadata`), or its typed form.
    scan_path : path-like, optional
        The scan file; default the recorded ``scan.path``. Its hash is not checked here
        (:func:`arsurf.replay.replay.replay` does).

    Returns
    -------
    ModelSetup
    """
    config = check_metadata(metadata)
    if isinstance(metadata, SessionConfig):
        metadata = config.to_metadata()
    from arsurf.model import ARModel
    from arsurf.scan.prepare import prepare_scan
    from arsurf.spline.fit import fit_surface

    sc = config.scan
    path = sc.path if scan_path is None else scan_path
    scan = prepare_scan(path, sc.channel, sc.level, float(sc.sigma), bool(sc.inpaint))
    scene = _tube_scene(config)
    if scene is not None:  # the tubes are scene objects: the spline holds only the substrate
        scan = scene.substrate(scan)
    surface = fit_surface(scan, control_shape=sc.control_shape, smoothing=float(sc.smoothing))
    tip_radius, md, lever, kwargs, deform = _model_parts(config)
    material = _material_map(config, scan, path)
    try:
        model = ARModel(surface, tip_radius, md, lever, deform=deform, material=material, **kwargs)
    except ArsurfError as exc:
        if material is None:
            raise
        raise SessionError(f"the session's material map does not fit its contact law: {exc}") from exc
    blend = _recorded_jump_blend(config.haptics)
    if blend is not None:  # the loop's blend of the tip's jumps, which the recorded forces have
        model.set_jump_blend(*blend)
    return ModelSetup(scan, surface, model, scene, metadata, config)


def _number_or(value, name: str) -> float:
    """``value`` as a finite float, else a SessionError naming the metadata key ``name``."""
    if not (_is_number(value) and math.isfinite(value)):
        raise SessionError(f"metadata {name} must be a finite number (got {value!r})")
    return float(value)


def _recorded_jump_blend(haptics: HapticsConfig):
    """``(blend time s, tick period s)`` of a recorded ``haptics.jump_blend`` and ``rate``
    (:meth:`~arsurf.model.ARModel.set_jump_blend`), None when none is recorded: a session recorded
    before the blend existed rendered its jumps in one tick, and is replayed that way."""
    blend = haptics.get("jump_blend")
    if blend is None:
        return None
    blend = _number_or(blend, "haptics.jump_blend")
    rate = _number_or(haptics.get("rate", _DEMO_HAPTICS["rate"]), "haptics.rate")
    if not (blend >= 0.0 and rate > 0.0):
        raise SessionError(f"metadata haptics.jump_blend must be >= 0 s and haptics.rate > 0 Hz (got {blend!r} s, "
                           f"{rate!r} Hz)")
    return blend, 1.0 / rate


def build_loop(model, haptics: Mapping | HapticsConfig, device_info, probe_origin, *, scene=None, seed: int = 0, **safety_kwargs):
    """The :class:`~arsurf.haptics.loop.HapticLoop` of recorded haptic settings (``metadata["haptics"]``).

    Only the direct coupling is assembled here (``haptics["coupling"]`` absent or ``"direct"``):
    ``scale`` probe m per stylus m, ``force_gain`` hand N per probe N, ``rate`` Hz, ``source``,
    ``blend``, ``filter_cutoff`` Hz (None: off), ``signal_noise`` rad; missing keys take the demo's
    values. ``safety_kwargs`` go to the safety layer (e.g. ``ramp_time``).

    The loop has the virtual coupling and the passivity controller unless the settings turn them
    off (``virtual_coupling``: False, ``passivity``: False): the model's, built from a recorded
    ``coupling_stiffness``, or else one chosen from ``device_info`` and the rate
    (:meth:`~arsurf.haptics.loop.HapticLoop.direct`; record it with :func:`loop_metadata`).

    Examples
    --------
    >>> import numpy as np
    >>> from arsurf.spline.surface import BSplineSurface
    >>> from arsurf.haptics.virtual_device import VirtualDevice
    >>> s = BSplineSurface.from_heights(np.zeros((8, 8)), (0.0, 100e-9), (0.0, 100e-9))
    >>> m = make_model(s, tip_radius=20e-9, effective_modulus=10e9, work_of_adhesion=0.1)
    >>> loop = build_loop(m, PRESETS["demo"].haptics, VirtualDevice().info, (50e-9, 50e-9, 30e-9))
    >>> loop.dt
    0.001
    """
    from arsurf.haptics.loop import HapticLoop, LoopConfig

    if isinstance(haptics, HapticsConfig):
        haptics = haptics.to_metadata()
    h = {**_DEMO_HAPTICS, **dict(haptics or {})}
    unknown = sorted(set(h) - set(_HAPTIC_KEYS) - {"K_fp", "B_fp", "G_n"})
    if unknown:
        raise SessionError(f"unknown haptic settings {unknown}; known: {list(_HAPTIC_KEYS)}")
    if h["coupling"] != "direct":
        raise SessionError(f"build_loop assembles the direct coupling (got coupling={h['coupling']!r}); build a "
                           "force-position loop with arsurf.haptics.coupling.ForcePositionCoupling and HapticLoop")
    config = LoopConfig(rate=float(h["rate"]), source=h["source"], blend=float(h.get("blend", 0.5)),
                        filter_cutoff=h["filter_cutoff"], signal_noise=float(h["signal_noise"]),
                        seed=int(h.get("seed", seed)), passivity=bool(h.get("passivity", True)),
                        jump_blend=_number_or(h["jump_blend"], "haptics.jump_blend"))
    if "max_rate" in h and "max_rate" not in safety_kwargs:
        safety_kwargs["max_rate"] = float(h["max_rate"])
    vc = h.get("virtual_coupling", True)
    if not isinstance(vc, bool):
        raise SessionError(f"haptics.virtual_coupling must be true or false (got {vc!r})")
    return HapticLoop.direct(model, device_info, probe_origin, scale=float(h["scale"]),
                             force_gain=float(h["force_gain"]), config=config, scene=scene, virtual_coupling=vc,
                             **safety_kwargs)


def loop_metadata(metadata: Mapping, loop) -> dict:
    """``metadata`` with the haptic protections ``loop`` runs with, as a session records them:
    ``haptics.virtual_coupling`` (bool), ``haptics.coupling_stiffness`` (N/m at the handle, the
    one the loop chose from the device when none was recorded; absent without a coupling),
    ``haptics.passivity`` (bool) and ``haptics.jump_blend`` (s). :func:`build_model` on the
    result rebuilds the model the loop ticks, bit for bit (the replay's guarantee).

    Examples
    --------
    >>> import numpy as np
    >>> from arsurf.spline.surface import BSplineSurface
    >>> from arsurf.haptics.virtual_device import VirtualDevice
    >>> s = BSplineSurface.from_heights(np.zeros((8, 8)), (0.0, 100e-9), (0.0, 100e-9))
    >>> m = make_model(s, tip_radius=20e-9, effective_modulus=10e9, work_of_adhesion=0.1)
    >>> loop = build_loop(m, BRIDGE_HAPTICS, VirtualDevice().info, (50e-9, 50e-9, 30e-9))
    >>> h = loop_metadata({"haptics": dict(BRIDGE_HAPTICS)}, loop)["haptics"]
    >>> h["virtual_coupling"], round(h["coupling_stiffness"], 2), h["passivity"], h["jump_blend"]
    (True, 66.67, True, 0.015)
    """
    h = dict(metadata.get("haptics") or {})
    k_vc = loop.virtual_coupling
    h["virtual_coupling"] = k_vc is not None
    if k_vc is None:
        h.pop("coupling_stiffness", None)
    elif h.get("coupling_stiffness") is None:
        h["coupling_stiffness"] = float(k_vc)
    h["passivity"] = bool(loop.config.passivity)
    h["jump_blend"] = float(loop.config.jump_blend)
    return dict(metadata, haptics=h)


def passivity_reserve(model, haptics: Mapping | HapticsConfig) -> float:
    """The passive energy store E0 (J, at the hand) that :func:`build_loop`'s loop gives its
    passivity controller for recorded haptic settings: the model's adhesion well
    (:meth:`~arsurf.model.ARModel.adhesion_energy`) times the direct coupling's energy gain
    (:meth:`~arsurf.haptics.coupling.DirectCoupling.energy_gain`). A replay scores the recorded
    feel with it (:func:`arsurf.haptics.feel.score_session`) as the demo and the live loop do.
    0 for a coupling other than the direct one (nothing is allowed)."""
    from arsurf.haptics.coupling import DirectCoupling
    from arsurf.haptics.scaling import ForceScaling, PositionScaling

    if isinstance(haptics, HapticsConfig):
        haptics = haptics.to_metadata()
    h = {**_DEMO_HAPTICS, **dict(haptics or {})}
    if h["coupling"] != "direct":
        return 0.0
    coupling = DirectCoupling(PositionScaling(float(h["scale"])), ForceScaling(float(h["force_gain"])))
    return float(model.adhesion_energy() * coupling.energy_gain())
