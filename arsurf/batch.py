r"""Batch runs: one pipeline over many scans or sessions, on local processes or a Dask cluster.

:func:`run_batch` (and ``arsurf batch PIPELINE INPUT... --out DIR``) applies one of three
pipelines to every file of a folder, a glob or a list of files:

===========  =====================================================================================
pipeline     what each item does
===========  =====================================================================================
``process``  load, inpaint, level, smooth (:func:`arsurf.scan.prepare.prepare_scan`), fit a bicubic
             B-spline (:func:`arsurf.spline.fit.fit_surface`), save it (``<item>.surface.npz``,
             :func:`arsurf.spline.storage.save_surface`) and export it if asked (mesh: STL/PLY/GLB by
             :func:`arsurf.export.export_surface`; height map: .gwy/.gsf/.npz/.npy, as ``arsurf export``)
``replay``   replay a recorded session (:func:`arsurf.replay.replay.replay`) into ``<item>/``
``sweep``    a contact sweep over a grid of friction coefficient x tip radius x effective modulus on
             each scan: one item per scan and grid point (below)
===========  =====================================================================================

Execution: local worker processes by default (:class:`concurrent.futures.ProcessPoolExecutor`,
``workers``; 0 runs the items in this process), or the workers of a Dask cluster when a scheduler
address is given (``dask.distributed``, the optional extra ``arsurf[dask]``; the workers must
have arsurf installed and see ``out_dir`` and the input files on a shared file system). Whichever
runs them, the items give the same results: the sweep and the fit are deterministic.

Errors of one item never stop the batch: the item gets a row with ``status`` = ``error`` and a
one-line reason (``CorruptScan: ...``). A worker process that dies (a crash, the OOM killer) breaks
the local pool: the items it held are rerun one at a time in a fresh pool, so the one that kills
its worker is found and reported, and the others complete.

Files written to ``out_dir``:

=================  ===============================================================================
``results.csv``    one row per finished item, appended and flushed (``fsync``) as each finishes; the
                   columns carry their unit (``rms_roughness_m``, ``fit_time_s``, ``peak_load_N``;
                   counts and ratios have none). Floats are written with ``repr`` (exact round trip),
                   ``nan`` where a value does not exist, empty cells in the rows of failed items
``batch.json``     the pipeline and its options (SI, each named with its unit: ``sigma_m``,
                   ``tip_radius_m``; :mod:`arsurf.units`), written at the start; a resumed batch must
                   have the same
``summary.json``   counts (ok, failed, skipped), the failures with their reasons, ``elapsed_s``,
                   ``items_per_s``, and min / median / max of every numeric column over the items
                   that succeeded (under the column's name, so in its unit); rewritten at the end
                   (``"complete": false`` when interrupted)
per item           ``process``: ``<item>.surface.npz`` (+ exports), ``replay``: ``<item>/``
=================  ===============================================================================

``<item>`` is the input's path relative to the common folder of all inputs, with ``/`` written
``__``. Each row lists the files its item wrote with their size and SHA-256 (``output_files``,
``name|size_bytes|sha256;...``). With ``resume``, an item is skipped only when its latest row says
``ok``, parses, and every file it lists is there with that size and SHA-256; the others (failed,
never finished, a row that does not parse, an output deleted or changed) run again. Each item has
a time limit (``item_timeout``, :data:`ITEM_TIMEOUT`). ``replay`` without a ``scan`` option reads
each session through the checked, isolated reader first and uses the scan it recorded only when
that lies under the batch's inputs: a session cannot make the batch open or hash another file. A row is written only after an item's files are complete,
and a torn last line (the batch killed while writing it) is cut off before appending, so the table
stays valid whatever moment the batch was stopped.

Sweep (one item per scan x friction x tip radius x modulus; the scan prepared and fitted as the
``preset`` says, once per worker): on the fitted surface at ``at`` (default the middle of the
scan), with the preset's work of adhesion, cantilever and deformation, the tip centre is driven in
three straight legs of ``steps`` ticks each through the :class:`~arsurf.model.ARModel`:

1. **press**: from 2 nm above contact down to the indentation ``depth`` (on the rest surface);
2. **slide**: ``slide`` metres along +x at that centre height (the depth follows the topography);
3. **retract**: straight up to 10 nm above the start of contact.

The row gives the largest depth and load and the contact radius at the largest load
(Maugis-Dugdale, :mod:`arsurf.contact.maugis_dugdale`), the pull-off force (the most tensile load
while retracting), and the friction during the slide: the mean tangential force
:math:`|F - P n|` and the mean ratio :math:`|F_t| / P` over the ticks where the friction proxy
slipped (:mod:`arsurf.contact.friction`; on a flat surface it equals the kinetic coefficient).
The motion is scripted, without a hand, device or haptic loop, so the answers depend only on the
contact physics being swept (:mod:`arsurf.feel_scenarios` scores the feel through the whole loop).

Examples
--------
>>> # run_batch("process", ["scans/"], "out", options={"sigma": 1e-9, "export": [".stl"]}, workers=4)
>>> # run_batch("sweep", ["scan.gsf"], "out", options={"friction": [0.1, 0.3], "tip_radius": [10e-9, 20e-9],
>>> #           "effective_modulus": [1e9, 1e10]}, scheduler="tcp://10.0.0.5:8786")
>>> sorted(PIPELINES)
['process', 'replay', 'sweep']
>>> PIPELINES["sweep"].columns[4:7]
('friction', 'tip_radius_m', 'effective_modulus_Pa')
"""
from __future__ import annotations

import contextlib
import csv
import functools
import glob
import hashlib
import itertools
import json
import math
import logging
import multiprocessing
import os
import re
import signal
import threading
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from arsurf._files import check_target, write_text
from arsurf._logging import progress as progress_bar
from arsurf.errors import ArsurfError, BatchError, SessionError, require
from arsurf.units import summary_json, with_unit

log = logging.getLogger(__name__)

__all__ = ["PIPELINES", "BatchResult", "Item", "Pipeline", "collect_inputs", "make_items", "read_results",
           "run_batch"]

TABLE = "results.csv"
SUMMARY = "summary.json"
SETTINGS = "batch.json"
BATCH_FORMAT = "arsurf-batch"
#: 2: batch.json's options carry their unit in their names (``sigma_m``), summary.json ``items_per_s``;
#: 3: every row lists its output files with size and SHA-256 (``output_files``), re-checked on resume
BATCH_FORMAT_VERSION = 3
#: default time limit of one item, s (``run_batch(item_timeout=...)``, ``--item-timeout``)
ITEM_TIMEOUT = 3600.0
#: the SI unit of each option in batch.json (:mod:`arsurf.units`); the others are dimensionless or text
_OPTION_UNITS = {"sigma": "m", "dx": "m", "dy": "m", "tip_radius": "m", "effective_modulus": "Pa", "depth": "m",
                 "slide": "m", "at": "m"}
#: most items one batch accepts (a typo in a sweep grid must not allocate millions of rows)
MAX_ITEMS = 1_000_000
#: the columns every table starts with
BASE_COLUMNS = ("item", "status", "error")
#: longest error reason kept in the table (characters)
MAX_REASON = 400


@dataclass(frozen=True)
class Item:
    """One unit of work: ``key`` (unique in the table), ``path`` (the input file, absolute) and
    ``params`` (the sweep's grid point as ``((name, value), ...)``, SI; empty otherwise)."""

    key: str
    path: str
    params: tuple = ()
    root: str = ""  #: the folder every input of the batch is under (what a session may name)


@dataclass(frozen=True)
class Pipeline:
    """A batch pipeline: its ``name``, table ``columns`` (units in the names), the input files a
    folder contributes (``suffixes``; None: the scan extensions :func:`arsurf.scan.io.load_scan`
    knows), the option check (``check(options) -> options``, SI, JSON-ready) and the work of one
    item (``task(item, options, out_dir) -> {column: value}``)."""

    name: str
    columns: tuple[str, ...]
    check: Callable[[Mapping], dict]
    task: Callable[[Item, Mapping, Path], dict]
    suffixes: tuple[str, ...] | None = None
    description: str = ""


@dataclass(frozen=True)
class BatchResult:
    """What :func:`run_batch` did (times in s).

    ``total`` items in the batch, ``ran`` in this call, ``skipped`` (done before: ``resume``),
    ``ok`` and ``failed`` over the whole table (this call and the earlier ones), ``errors``:
    ``((item, reason), ...)`` of the failed ones, ``elapsed`` wall time of this call and
    ``items_per_second`` (items run by this call / elapsed).
    """

    out_dir: Path
    table: Path
    summary: Path
    total: int
    ran: int
    skipped: int
    ok: int
    failed: int
    errors: tuple[tuple[str, str], ...]
    elapsed: float
    items_per_second: float


# ---------------------------------------------------------------------------------------------
# inputs


def _scan_suffixes() -> tuple[str, ...]:
    from arsurf.scan.io import _ext_map

    return tuple(sorted(_ext_map()))


def collect_inputs(inputs: Sequence[str | os.PathLike], suffixes: Sequence[str] | None = None, *,
                   exclude: str | os.PathLike | None = None) -> tuple[list[Path], Path]:
    """The input files of a batch, sorted, and the folder they are named relative to.

    Each input is a file (taken as it is), a folder (its files whose extension is in
    ``suffixes``, case-insensitive, not recursive) or a glob pattern (``*``, ``?``, ``[...]``;
    ``**`` recurses; every regular file it matches). Files inside ``exclude`` (the batch's output
    folder) are left out.

    Returns
    -------
    files : list of Path
        Absolute (symbolic links are not resolved), without duplicates.
    root : Path
        The deepest folder holding all of them (item keys are relative to it).

    Raises
    ------
    BatchError
        An input does not exist, a folder holds no such file, a pattern matches nothing.
    """
    if isinstance(inputs, (str, os.PathLike)):
        inputs = [inputs]
    if not inputs:
        raise BatchError("no input given: name scan files, folders or glob patterns")
    wanted = {s.lower() for s in (suffixes if suffixes is not None else _scan_suffixes())}
    skips = set() if exclude is None else {Path(os.path.abspath(exclude)), Path(exclude).resolve()}
    found: dict[Path, None] = {}
    for entry in inputs:
        text = os.fspath(entry)
        if glob.has_magic(text):
            matches = [Path(m) for m in sorted(glob.glob(text, recursive=True)) if Path(m).is_file()]
            if not matches:
                raise BatchError(f"no file matches the pattern {text!r}")
        elif os.path.isdir(text):
            matches = sorted(p for p in Path(text).iterdir() if p.is_file() and p.suffix.lower() in wanted)
            if not matches:
                raise BatchError(f"folder {text!r} holds no input file (extensions {', '.join(sorted(wanted))}); "
                                 "name the files or a glob pattern to take others")
        elif os.path.isfile(text):
            matches = [Path(text)]
        else:
            raise BatchError(f"input {text!r} does not exist (a file, a folder or a glob pattern)")
        for m in matches:
            path = Path(os.path.abspath(m))  # symbolic links kept: a linked copy is an item of its own
            if any(s == p or s in p.parents for s in skips for p in (path, path.resolve())):
                continue
            found.setdefault(path, None)
    files = sorted(found)
    if not files:
        raise BatchError(f"every input is inside the output folder {os.fspath(exclude)!r}; choose another output "
                         "folder")
    root = Path(os.path.commonpath([str(p.parent) for p in files]))
    return files, root


def _key(path: Path, root: Path) -> str:
    return path.relative_to(root).as_posix()


def _safe(key: str) -> str:
    """A file name for an item key: ``/`` -> ``__``; characters a file system refuses -> ``_``."""
    name = key.replace("/", "__")
    return "".join("_" if c in '<>:"\\|?*' or ord(c) < 32 else c for c in name)


def make_items(pipeline: str | Pipeline, files: Sequence[Path], root: Path, options: Mapping) -> list[Item]:
    """The items of a batch: one per file, and for ``sweep`` one per file and grid point.

    The sweep's grid is the Cartesian product of ``options["friction"]``, ``["tip_radius"]`` and
    ``["effective_modulus"]`` (SI); its key is ``<file>;friction=...;tip_radius_m=...;
    effective_modulus_Pa=...`` with the values as Python writes them (exact).
    """
    p = _pipeline(pipeline)
    items = [Item(_key(f, root), str(f), (), str(root)) for f in files]
    if p.name != "sweep":
        return items
    axes = [(name, unit, options[name]) for name, unit in _SWEEP_AXES]
    n = len(items) * math.prod(len(values) for _, _, values in axes)
    if n > MAX_ITEMS:
        raise BatchError(f"the sweep has {n} items ({len(items)} scans x "
                         f"{' x '.join(str(len(v)) for _, _, v in axes)}), more than {MAX_ITEMS}; use a coarser grid")
    out = []
    for item in items:
        for point in itertools.product(*(values for _, _, values in axes)):
            key = ";".join([item.key] + [f"{name}{unit}={v!r}" for (name, unit, _), v in zip(axes, point)])
            out.append(Item(key, item.path, tuple((name, v) for (name, _, _), v in zip(axes, point)), item.root))
    return out


# ---------------------------------------------------------------------------------------------
# option checks (SI, JSON-ready)


def _number(options: Mapping, name: str, default, *, minimum: float = 0.0, strict: bool = False,
            unit: str = "", what: str = "") -> float:
    value = options.get(name, default)
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise BatchError(f"option {name!r} must be a number{' in ' + unit if unit else ''} (got {value!r}); "
                         f"{what}") from None
    if not math.isfinite(x) or x < minimum or (strict and x == minimum):
        rule = f"> {minimum:g}" if strict else f">= {minimum:g}"
        raise BatchError(f"option {name!r} must be finite and {rule}{' ' + unit if unit else ''} (got {value!r}); "
                         f"{what}")
    return x


def _int_pair(options: Mapping, name: str, minimum: int, what: str):
    value = options.get(name)
    if value is None:
        return None
    try:
        pair = [int(v) for v in value]
        ok = len(pair) == 2 and all(float(v) == p for v, p in zip(value, pair))
    except (TypeError, ValueError):
        ok = False
    if not ok or min(pair) < minimum:
        raise BatchError(f"option {name!r} must be two integers >= {minimum} (got {value!r}); {what}")
    return pair


def _unknown(options: Mapping, known: Sequence[str], pipeline: str) -> None:
    extra = sorted(set(options) - set(known))
    if extra:
        raise BatchError(f"unknown option(s) {extra} for the {pipeline!r} pipeline; it takes {sorted(known)}")


_MESH_EXPORTS = (".stl", ".ply", ".glb")
_MAP_EXPORTS = (".gwy", ".gsf", ".npz", ".npy")
_PROCESS_OPTIONS = ("channel", "level", "sigma", "inpaint", "control_shape", "smoothing", "export", "resolution",
                    "solid", "dx", "dy", "z_unit")


def _check_process(options: Mapping) -> dict:
    from arsurf.scan.level import METHODS

    _unknown(options, _PROCESS_OPTIONS, "process")
    level = options.get("level", "plane")
    if level is None:
        level = "none"
    if level not in (*METHODS, "none"):
        raise BatchError(f"option 'level' must be one of {(*METHODS, 'none')} (got {level!r})")
    exports = options.get("export") or ()
    if isinstance(exports, str):
        exports = [exports]
    norm = []
    for ext in exports:
        e = str(ext).lower()
        e = e if e.startswith(".") else "." + e
        if e not in _MESH_EXPORTS + _MAP_EXPORTS:
            raise BatchError(f"export format {ext!r} is not one of {', '.join(_MESH_EXPORTS + _MAP_EXPORTS)}")
        if e not in norm:
            norm.append(e)
    if any(e in _MESH_EXPORTS for e in norm):
        require("trimesh", "mesh", "arsurf batch process --export " + "/".join(e for e in norm if e in _MESH_EXPORTS))
    out = {
        "channel": None if options.get("channel") is None else str(options["channel"]),
        "level": level,
        "sigma": _number(options, "sigma", 0.0, unit="m", what="it is the Gaussian smoothing width in metres"),
        "inpaint": bool(options.get("inpaint", True)),
        "control_shape": _int_pair(options, "control_shape", 4, "they are the control points of an approximating fit"),
        "smoothing": _number(options, "smoothing", 0.0, what="it is the P-spline penalty weight"),
        "export": norm,
        "resolution": _int_pair(options, "resolution", 2, "they are the samples along u and v of an export"),
        "solid": bool(options.get("solid", False)),
        "z_unit": None if options.get("z_unit") is None else str(options["z_unit"]),
    }
    for name in ("dx", "dy"):
        out[name] = (None if options.get(name) is None else
                     _number(options, name, None, strict=True, unit="m", what="it is the pixel spacing in metres"))
    return out


def _check_replay(options: Mapping) -> dict:
    _unknown(options, ("scan",), "replay")
    scan = options.get("scan")
    if scan is not None and not os.path.isfile(scan):
        raise BatchError(f"scan file {os.fspath(scan)!r} does not exist (option 'scan': the scan every session was "
                         "recorded on; leave it out to use the path each session recorded)")
    return {"scan": None if scan is None else str(Path(scan).resolve())}


#: the sweep's axes: option name, unit in the key and in the column name
_SWEEP_AXES = (("friction", ""), ("tip_radius", "_m"), ("effective_modulus", "_Pa"))
_SWEEP_OPTIONS = ("friction", "tip_radius", "effective_modulus", "preset", "depth", "slide", "steps", "at")
_SWEEP_DEFAULT_STEPS = 40
#: most grid values on one axis
_MAX_AXIS = 10_000


def _axis(options: Mapping, name: str, default: float, *, strict: bool, unit: str, what: str) -> list[float]:
    values = options.get(name)
    if values is None:
        values = [default]
    elif isinstance(values, (int, float)):
        values = [values]
    try:
        values = list(values)
    except TypeError:
        raise BatchError(f"option {name!r} must be a list of numbers{' in ' + unit if unit else ''} "
                         f"(got {values!r})") from None
    if not values or len(values) > _MAX_AXIS:
        raise BatchError(f"option {name!r} needs 1 to {_MAX_AXIS} values (got {len(values)})")
    out = [_number({name: v}, name, None, strict=strict, unit=unit, what=what) for v in values]
    if len(set(out)) != len(out):
        raise BatchError(f"option {name!r} repeats a value ({values!r}); give each grid value once")
    return out


def _check_sweep(options: Mapping) -> dict:
    from arsurf.assembly import PRESETS

    _unknown(options, _SWEEP_OPTIONS, "sweep")
    name = options.get("preset", "demo")
    if name not in PRESETS:
        raise BatchError(f"option 'preset' must be one of {sorted(PRESETS)} (got {name!r})")
    p = PRESETS[name]
    out = {
        "preset": name,
        "friction": _axis(options, "friction", p.friction, strict=False, unit="",
                          what="it is the kinetic friction coefficient"),
        "tip_radius": _axis(options, "tip_radius", p.tip_radius, strict=True, unit="m",
                            what="it is the tip sphere radius in metres"),
        "effective_modulus": _axis(options, "effective_modulus", p.effective_modulus, strict=True, unit="Pa",
                                   what="it is the contact modulus E* in pascals"),
        "depth": _number(options, "depth", 2e-9, strict=True, unit="m",
                         what="it is the indentation of the press in metres"),
        "slide": _number(options, "slide", 20e-9, unit="m", what="it is the slide length along x in metres"),
    }
    steps = options.get("steps", _SWEEP_DEFAULT_STEPS)
    if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) or not 2 <= steps <= 100_000:
        raise BatchError(f"option 'steps' must be an integer in [2, 100000] (got {steps!r}); it is the ticks of "
                         "each leg (press, slide, retract)")
    out["steps"] = int(steps)
    at = options.get("at")
    if at is not None:
        try:
            at = [float(v) for v in at]
        except (TypeError, ValueError):
            at = None
        if at is None or len(at) != 2 or not all(map(math.isfinite, at)):
            raise BatchError(f"option 'at' must be (x, y) in metres, finite (got {options.get('at')!r})")
    out["at"] = at
    return out


# ---------------------------------------------------------------------------------------------
# the work of one item (runs in a worker: module-level functions, picklable by reference)


def _residual_and_roughness(scan, surface) -> tuple[float, float, float]:
    xx, yy = np.meshgrid(scan.x, scan.y)
    resid = surface.evaluate(xx, yy)[..., 2] - scan.heights
    z = scan.heights
    return (float(np.sqrt(np.mean(resid ** 2))), float(np.abs(resid).max()),
            float(np.sqrt(np.mean((z - z.mean()) ** 2))))


def _process(item: Item, o: Mapping, out_dir: Path) -> dict:
    from arsurf.scan.prepare import prepare_scan
    from arsurf.spline.fit import fit_surface
    from arsurf.spline.storage import save_surface

    scan = prepare_scan(item.path, o["channel"], o["level"], o["sigma"], o["inpaint"], dx=o["dx"], dy=o["dy"],
                        z_unit=o["z_unit"])
    t0 = time.perf_counter()
    cs = o["control_shape"]
    surface = fit_surface(scan, control_shape=tuple(cs) if cs else None, smoothing=o["smoothing"])
    fit_time = time.perf_counter() - t0
    rms_resid, max_resid, rq = _residual_and_roughness(scan, surface)
    stem = _safe(item.key)
    outputs = [f"{stem}.surface.npz"]
    save_surface(surface, out_dir / outputs[0], metadata={"scan": item.path, "history": scan.history})
    res = tuple(o["resolution"]) if o["resolution"] else None
    for ext in o["export"]:
        name = f"{stem}{ext}"
        if ext in _MESH_EXPORTS:
            from arsurf.export import export_surface

            export_surface(surface, out_dir / name, res, solid=o["solid"])
        else:
            from arsurf.scan.io import save_scan
            from arsurf.spline.sampling import surface_to_scan

            sampled = surface_to_scan(surface, res, source=item.path)
            save_scan(sampled, out_dir / name)  # through arsurf._files.atomic_write, as every writer
        outputs.append(name)
    ny, nx = scan.shape
    filled = sum(int(s.get("nan_filled", 0)) for s in scan.history if s.get("step") == "inpaint")
    return {"format": scan.metadata.get("format"), "nx_px": nx, "ny_px": ny, "dx_m": scan.dx, "dy_m": scan.dy,
            "z_range_m": float(np.ptp(scan.heights)), "rms_roughness_m": rq, "inpainted_pixels": filled,
            "control_nu": surface.shape[0], "control_nv": surface.shape[1], "rms_residual_m": rms_resid,
            "max_residual_m": max_resid, "fit_time_s": fit_time, "outputs": ";".join(outputs)}


def _recorded_scan(session_path: str, root: str) -> str:
    """The scan a session recorded, read through the checked, isolated session reader; it must lie
    under ``root`` (the folder of the batch's inputs): a session cannot make the batch open or
    hash a file elsewhere. A relative path is taken from the session's folder."""
    from arsurf.sessions.reader import load_session

    s = load_session(session_path, isolate=True, allow_incomplete=True)  # every check, libhdf5 in a child
    path = (s.metadata.get("scan") or {}).get("path")
    if not isinstance(path, str) or not path:
        raise SessionError(f"{session_path!r}: the session records no scan path ({path!r}); give the scan with --scan")
    full = Path(path) if os.path.isabs(path) else Path(session_path).parent / path
    resolved, base = full.resolve(), Path(root).resolve()
    if not root or (resolved != base and base not in resolved.parents):
        raise SessionError(f"{session_path!r} names the scan {path!r}, outside the batch's inputs ({str(base)!r}); "
                           "it is not opened: give the scan with --scan")
    return str(resolved)


def _replay(item: Item, o: Mapping, out_dir: Path) -> dict:
    from arsurf.replay.replay import replay

    scan = o["scan"] or _recorded_scan(item.path, item.root)
    name = _safe(item.key)
    r = replay(item.path, scan, out_dir / name, progress=False, overwrite=True)
    return {"scan": scan, "n_ticks": r.n_ticks, "peak_force_N": r.peak_force,
            "peak_measured_force_N": r.peak_measured_force, "max_depth_m": r.max_depth,
            "max_contact_radius_m": r.max_contact_radius, "depth_difference_m": r.depth_difference,
            "load_difference_N": r.load_difference, "contact_mismatches": r.contact_mismatches,
            "collision_failures": r.collision_failures, "replay_time_s": r.elapsed, "outputs": name}


@functools.lru_cache(maxsize=4)
def _fitted(path: str, stamp: tuple, level: str, sigma: float):
    """The scan prepared and fitted once per worker (``stamp``: size and mtime, so an edited file is refitted).
    Never handed out: callers take a copy (the model dents its surface)."""
    from arsurf.scan.prepare import prepare_scan
    from arsurf.spline.fit import fit_surface

    return fit_surface(prepare_scan(path, None, level, sigma, True))


def _sweep(item: Item, o: Mapping, out_dir: Path) -> dict:
    from arsurf.assembly import PRESETS, make_model
    from arsurf.model import M_IN_CONTACT, M_LOAD, M_NX, M_RADIUS, M_SIM_FX, M_SLIPPING, M_DEPTH

    p = PRESETS[o["preset"]]
    st = os.stat(item.path)
    surface = _fitted(item.path, (st.st_size, st.st_mtime_ns), p.level, p.sigma).copy()
    g = dict(item.params)
    mu, radius, modulus = g["friction"], g["tip_radius"], g["effective_modulus"]
    model = make_model(surface, tip_radius=radius, effective_modulus=modulus, work_of_adhesion=p.work_of_adhesion,
                       cantilever=p.cantilever, friction=mu)
    (u0, u1), (v0, v1) = surface.domain
    x, y = (0.5 * (u0 + u1), 0.5 * (v0 + v1)) if o["at"] is None else o["at"]
    if not (u0 <= x <= u1 and v0 <= y <= v1):
        raise BatchError(f"sweep point at=({x!r}, {y!r}) m is outside the scan ({u0!r}..{u1!r}, {v0!r}..{v1!r} m)")
    z_touch = float(surface.evaluate(x, y)[2]) + radius  # centre height of first contact (no adhesion)
    n = o["steps"]
    ramp = np.linspace(0.0, 1.0, n)
    legs = [np.column_stack([np.full(n, x), np.full(n, y), z_touch + 2e-9 - (2e-9 + o["depth"]) * ramp]),
            np.column_stack([x + o["slide"] * ramp, np.full(n, y), np.full(n, z_touch - o["depth"])]),
            np.column_stack([np.full(n, x + o["slide"]), np.full(n, y), z_touch - o["depth"] + (o["depth"] + 10e-9) * ramp])]
    rows = []
    for leg in legs:
        out = np.empty((n, model.out.size))
        for k in range(n):
            model.step(leg[k])
            out[k] = model.out
        rows.append(out)
    press_slide = np.vstack(rows[:2])
    k_peak = int(np.argmax(press_slide[:, M_LOAD]))
    slide, retract = rows[1], rows[2]
    normal = slide[:, M_NX:M_NX + 3]
    tangential = np.linalg.norm(slide[:, M_SIM_FX:M_SIM_FX + 3] - slide[:, M_LOAD:M_LOAD + 1] * normal, axis=1)
    touching = slide[:, M_IN_CONTACT] > 0.5
    slipping = touching & (slide[:, M_SLIPPING] > 0.5) & (slide[:, M_LOAD] > 0.0)
    ratio = float(np.mean(tangential[slipping] / slide[slipping, M_LOAD])) if slipping.any() else math.nan
    model.reset()
    return {"scan": item.key.split(";", 1)[0], "friction": mu, "tip_radius_m": radius,
            "effective_modulus_Pa": modulus, "work_of_adhesion_J_per_m2": p.work_of_adhesion,
            "max_depth_m": float(np.max(press_slide[:, M_DEPTH])), "peak_load_N": float(press_slide[k_peak, M_LOAD]),
            "contact_radius_m": float(press_slide[k_peak, M_RADIUS]),
            "pull_off_force_N": float(max(0.0, -np.min(retract[:, M_LOAD]))),
            "mean_friction_force_N": float(np.mean(tangential[touching])) if touching.any() else 0.0,
            "friction_ratio": ratio, "slip_fraction": float(np.mean(slipping))}


PIPELINES: Mapping[str, Pipeline] = {
    "process": Pipeline(
        "process",
        (*BASE_COLUMNS, "format", "nx_px", "ny_px", "dx_m", "dy_m", "z_range_m", "rms_roughness_m", "inpainted_pixels",
         "control_nu", "control_nv", "rms_residual_m", "max_residual_m", "fit_time_s", "item_time_s", "outputs", "output_files"),
        _check_process, _process, None, "level, smooth, fit and export scans"),
    "replay": Pipeline(
        "replay",
        (*BASE_COLUMNS, "scan", "n_ticks", "peak_force_N", "peak_measured_force_N", "max_depth_m",
         "max_contact_radius_m", "depth_difference_m", "load_difference_N", "contact_mismatches",
         "collision_failures", "replay_time_s", "item_time_s", "outputs", "output_files"),
        _check_replay, _replay, (".h5",), "replay recorded sessions"),
    "sweep": Pipeline(
        "sweep",
        (*BASE_COLUMNS, "scan", "friction", "tip_radius_m", "effective_modulus_Pa", "work_of_adhesion_J_per_m2",
         "max_depth_m", "peak_load_N", "contact_radius_m", "pull_off_force_N", "mean_friction_force_N",
         "friction_ratio", "slip_fraction", "item_time_s", "output_files"),
        _check_sweep, _sweep, None, "press-slide-retract over a friction x tip radius x modulus grid"),
}


def _pipeline(name: str | Pipeline) -> Pipeline:
    if isinstance(name, Pipeline):
        return name
    if name not in PIPELINES:
        raise BatchError(f"unknown pipeline {name!r}; choose one of {', '.join(PIPELINES)}")
    return PIPELINES[name]


def _reason(exc: BaseException) -> str:
    """``Type: first line of the message``, at most :data:`MAX_REASON` characters."""
    text = str(exc).strip().splitlines()
    line = f"{type(exc).__name__}: {text[0]}" if text else type(exc).__name__
    return line if len(line) <= MAX_REASON else line[:MAX_REASON - 3] + "..."


class ItemTimeout(Exception):
    """An item ran past the batch's per-item time limit."""


@contextlib.contextmanager
def _time_limit(seconds: float | None, key: str):
    """Raise :class:`ItemTimeout` in the item after ``seconds`` (SIGALRM, in a process's main thread:
    the local workers and ``workers=0``). A worker process whose item does not give control back
    (stuck in a C library) is ended by a watchdog ``seconds`` later: the pool then reports the item
    as a crashed worker. Dask workers run items in threads: no limit there (the cluster's own)."""
    if not seconds or threading.current_thread() is not threading.main_thread() or not hasattr(signal, "SIGALRM"):
        yield
        return

    def expired(signum, frame):
        raise ItemTimeout(f"the item ran longer than its time limit ({seconds:g} s); raise it with --item-timeout")

    watchdog = None
    if multiprocessing.parent_process() is not None:  # a worker process: it may end itself
        watchdog = threading.Timer(2 * seconds + 5.0, os._exit, args=(70,))
        watchdog.daemon = True
        watchdog.start()
    old = signal.signal(signal.SIGALRM, expired)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
        if watchdog is not None:
            watchdog.cancel()


def _sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _output_files(out_dir: Path, outputs: str) -> str:
    """``rel|size_bytes|sha256`` of every file an item wrote (``outputs``: names in ``out_dir``, a
    folder standing for the files in it), ``;``-separated, sorted."""
    files = []
    for name in filter(None, (outputs or "").split(";")):
        p = out_dir / name
        if p.is_dir() and not p.is_symlink():
            files += [f for f in p.rglob("*") if f.is_file() and not f.is_symlink()]
        elif p.is_file():
            files.append(p)
    return ";".join(f"{f.relative_to(out_dir).as_posix()}|{f.stat().st_size}|{_sha256_file(f)}" for f in sorted(files))


_SHA = re.compile(r"^[0-9a-f]{64}$")


def _row_stands(row: Mapping | None, columns: Sequence[str], out_dir: Path) -> bool:
    """Whether a table row may be kept on resume: ``ok``, every column present, its time a finite
    number, and every output file it lists there, of its size and SHA-256. Anything else
    (a row that does not parse, a deleted or changed output) is run again."""
    if not row or row.get("status") != "ok" or any(c not in row for c in columns):
        return False
    try:
        if not 0.0 <= float(row["item_time_s"]) < math.inf:
            return False
        listed = [e.split("|")[0] for e in filter(None, row["output_files"].split(";"))]
        for name in filter(None, row.get("outputs", "").split(";")):  # every output the row names is hashed
            if not any(rel == name or rel.startswith(name + "/") for rel in listed):
                return False
        for entry in filter(None, row["output_files"].split(";")):
            rel, size, digest = entry.split("|")
            p = out_dir / rel
            if (not rel or rel.startswith("/") or ".." in rel.split("/") or not _SHA.match(digest)
                    or p.is_symlink() or not p.is_file() or p.stat().st_size != int(size)
                    or _sha256_file(p) != digest):
                return False
    except (ValueError, KeyError, OSError):
        return False
    return True


def run_item(pipeline: str, item: Item, options: Mapping, out_dir: str, time_limit: float | None = None) -> dict:
    """Run one item and return its table row; any exception becomes an ``error`` row (one line).

    The row lists every file the item wrote with its size and SHA-256 (``output_files``), which a
    resumed batch re-checks; ``time_limit`` (s) bounds the item (:func:`_time_limit`).
    This is what the workers run (local processes or Dask): a module-level function, so it is
    pickled by reference.
    """
    t0 = time.perf_counter()
    try:
        with _time_limit(time_limit, item.key):
            values = PIPELINES[pipeline].task(item, options, Path(out_dir))
        files = _output_files(Path(out_dir), values.get("outputs", ""))
    except Exception as exc:  # noqa: BLE001 - one bad item must not stop the batch; the reason is kept
        return {"item": item.key, "status": "error", "error": _reason(exc)}
    return {"item": item.key, "status": "ok", "error": "", **values, "item_time_s": time.perf_counter() - t0,
            "output_files": files}


# ---------------------------------------------------------------------------------------------
# the results table


def _cell(value) -> str:
    if value is None:
        return ""
    if isinstance(value, (bool, np.bool_)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        return repr(float(value))
    return str(value).replace("\r", " ").replace("\n", " ")


class _Table:
    """``results.csv``: the header once, then one row per item, flushed and fsynced as it comes."""

    def __init__(self, path: Path, columns: tuple[str, ...]):
        self.path = path
        self.columns = columns
        check_target(path, "results table", error=BatchError)  # a planted link is refused, never appended to
        fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0), 0o666)
        new = os.fstat(fd).st_size == 0
        self.fh = os.fdopen(fd, "a", encoding="utf-8", newline="")
        self.writer = csv.writer(self.fh, lineterminator="\n")
        if new:
            self._write(columns)

    def _write(self, cells) -> None:
        self.writer.writerow(cells)
        self.fh.flush()
        os.fsync(self.fh.fileno())

    def append(self, row: Mapping) -> None:
        self._write([_cell(row.get(c)) for c in self.columns])

    def close(self) -> None:
        self.fh.close()


def _repair(path: Path) -> None:
    """Cut a torn last line (the batch killed while writing it) so appending keeps the table valid."""
    if not path.exists():
        return
    data = path.read_bytes()
    if data and not data.endswith(b"\n"):
        with open(path, "r+b") as fh:
            fh.truncate(data.rfind(b"\n") + 1)


def read_results(path: str | os.PathLike, columns: Sequence[str] | None = None) -> dict[str, dict[str, str]]:
    """The rows of a results table, the latest per item (a resumed item's last attempt), as strings.

    Parameters
    ----------
    path : path-like
        ``results.csv`` (or the batch's output folder).
    columns : sequence of str, optional
        The header the table must have (BatchError otherwise).

    Returns
    -------
    dict
        item -> {column: cell}. A torn last line is ignored.
    """
    path = Path(path)
    if path.is_dir():
        path = path / TABLE
    if not path.exists():
        return {}
    text = path.read_text(encoding="utf-8")
    if text and not text.endswith("\n"):
        text = text[:text.rfind("\n") + 1]
    lines = list(csv.reader(text.splitlines()))
    if not lines:
        return {}
    header = tuple(lines[0])
    if columns is not None and header != tuple(columns):
        raise BatchError(f"{str(path)!r} has the columns {list(header)}, not those of this pipeline "
                         f"{list(columns)}; choose another output folder")
    return {row[0]: dict(zip(header, row)) for row in lines[1:] if len(row) == len(header)}


# ---------------------------------------------------------------------------------------------
# progress


class _Progress:
    """Items done as a tqdm bar on stderr (:func:`arsurf._logging.progress`: on a terminal, unless
    ``-q``), failures in its postfix; the resume note is logged (INFO)."""

    def __init__(self, total: int, skipped: int, enabled: bool):
        self.failed = 0
        if enabled and skipped:
            log.info("batch: %d of %d items already done (resume)", skipped, total)
        self.bar = progress_bar(total=total, initial=skipped, desc="batch", unit="item", enabled=enabled)

    def update(self, ok: bool) -> None:
        self.bar.update(1)
        if not ok:
            self.failed += 1
            self.bar.set_postfix(failed=self.failed, refresh=False)

    def close(self) -> None:
        self.bar.close()


# ---------------------------------------------------------------------------------------------
# execution


def _execute_local(func: Callable, calls: Sequence[tuple], workers: int, on_result: Callable[[int, Any], None],
                   on_crash: Callable[[int, str], None]) -> None:
    """Run ``func(*calls[i])`` for every i on ``workers`` processes, calling ``on_result(i, value)``
    as each finishes (in this process). A worker that dies breaks the pool: the calls it held run
    again one at a time in a fresh pool, and one that breaks it alone is given to ``on_crash``."""
    import multiprocessing
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
    from concurrent.futures.process import BrokenProcessPool

    if workers == 0:
        for i, args in enumerate(calls):
            on_result(i, func(*args))
        return
    context = multiprocessing.get_context("spawn")  # no fork of a process that holds threads (Dask, BLAS)
    pending = deque(range(len(calls)))
    suspects: deque[int] = deque()
    window = 2 * workers  # calls handed to the pool at once: the suspects if it breaks
    pool = None
    try:
        while pending or suspects:
            if pool is None:
                pool = ProcessPoolExecutor(max_workers=workers, mp_context=context)
            if suspects:  # after a break: one call at a time, so a call that breaks the pool alone is known
                i = suspects.popleft()
                try:
                    value = pool.submit(func, *calls[i]).result()
                except BrokenProcessPool:
                    on_crash(i, "the worker process died while running this item (a crash or the out-of-memory "
                                "killer)")
                    pool.shutdown(wait=True, cancel_futures=True)
                    pool = None
                    continue
                on_result(i, value)
                continue
            inflight: dict = {}
            broken = False
            while (pending or inflight) and not broken:
                while pending and len(inflight) < window:
                    i = pending.popleft()
                    try:
                        inflight[pool.submit(func, *calls[i])] = i
                    except BrokenProcessPool:
                        pending.appendleft(i)
                        broken = True
                        break
                if not inflight:
                    break
                done, _ = wait(list(inflight), return_when=FIRST_COMPLETED)
                for fut in done:
                    i = inflight.pop(fut)
                    try:
                        value = fut.result()
                    except BrokenProcessPool:
                        broken = True
                        suspects.append(i)
                        continue
                    on_result(i, value)
            if broken:  # the calls the broken pool held: not run, or not known to have run
                suspects.extend(sorted(inflight.values()))
                pool.shutdown(wait=True, cancel_futures=True)
                pool = None
    finally:
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)


def _connect(scheduler, connect_timeout: float):
    """``(client, own)``: a ``distributed.Client`` for an address (``own``: close it after), or the client given."""
    distributed = require("distributed", "dask", "arsurf batch on a Dask cluster (--scheduler)")
    if isinstance(scheduler, distributed.Client):
        return scheduler, False
    try:
        return distributed.Client(scheduler, timeout=connect_timeout), True
    except (OSError, TimeoutError, ValueError, TypeError) as exc:
        raise BatchError(f"cannot reach the Dask scheduler at {scheduler!r} within {connect_timeout:g} s "
                         f"({_reason(exc)}); start one with `dask scheduler` or check the address") from None


def _execute_dask(func: Callable, calls: Sequence[tuple], client, on_result: Callable[[int, Any], None],
                  on_crash: Callable[[int, str], None]) -> None:
    """Run the calls on the Dask cluster of ``client``. A task that fails on the cluster (a worker
    killed three times running it: ``KilledWorker``) goes to ``on_crash``."""
    import distributed

    futures = [client.submit(func, *args, pure=False) for args in calls]
    index = {f.key: i for i, f in enumerate(futures)}
    try:
        for fut in distributed.as_completed(futures):
            i = index[fut.key]
            try:
                value = fut.result()
            except Exception as exc:  # noqa: BLE001 - the cluster lost the task; the others go on
                on_crash(i, f"the Dask cluster could not run this item ({_reason(exc)})")
            else:
                on_result(i, value)
            fut.release()
    finally:
        client.cancel([f for f in futures if not f.done()])


def _settings(pipeline: Pipeline, options: dict, version: int = BATCH_FORMAT_VERSION) -> dict:
    """batch.json: from version 2 each option named with its SI unit (``sigma_m``); version 1 (an older
    arsurf's batch, for resuming it) named them as the API does."""
    if version >= 2:
        options = {with_unit(k, _OPTION_UNITS.get(k, "")): v for k, v in options.items()}
    return {"format": BATCH_FORMAT, "version": version, "pipeline": pipeline.name,
            "options": options, "columns": list(pipeline.columns)}


def _check_out_dir(out: Path, pipeline: Pipeline, options: dict, resume: bool) -> None:
    settings = _settings(pipeline, options)
    table = out / TABLE
    if out.exists() and not out.is_dir():
        raise BatchError(f"output path {str(out)!r} is a file, not a folder")
    if table.exists() and not resume:
        raise BatchError(f"{str(table)!r} exists: pass --resume (resume=True) to continue that batch, or choose "
                         "another output folder")
    path = out / SETTINGS
    if resume and path.exists():
        try:
            old = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise BatchError(f"{str(path)!r} is not readable JSON ({exc}); it holds the settings of the batch to "
                             "resume") from None
        if old.get("version") == 2:
            raise BatchError(f"the batch in {str(out)!r} was written by an older arsurf, whose rows do not record "
                             "their output files' SHA-256; it cannot be verified, so not resumed: choose another "
                             "output folder")
        was = old.get("version") if old.get("version") in (1, BATCH_FORMAT_VERSION) else BATCH_FORMAT_VERSION
        if old != _settings(pipeline, options, was):
            mine = _settings(pipeline, options, was)["options"]
            api = dict(zip(mine, options))  # the file's option names -> the API's (as the user gave them)
            diff = sorted(api.get(k, k) for k in set(old.get("options", {})) | set(mine)
                          if old.get("options", {}).get(k) != mine.get(k))
            what = f"options {diff}" if old.get("pipeline") == pipeline.name else f"pipeline {old.get('pipeline')!r}"
            raise BatchError(f"cannot resume the batch in {str(out)!r} with other settings ({what} differ); "
                             "rerun it with the same ones, or choose another output folder")
    out.mkdir(parents=True, exist_ok=True)
    write_text(path, json.dumps(settings, indent=2, sort_keys=True) + "\n", what="batch settings", error=BatchError)


def _summary(pipeline: Pipeline, items: Sequence[Item], rows: Mapping[str, Mapping], ran: int, skipped: int,
             elapsed: float, complete: bool) -> dict:
    mine = [rows[it.key] for it in items if it.key in rows]
    ok = [r for r in mine if r.get("status") == "ok"]
    failed = [(r["item"], r.get("error", "")) for r in mine if r.get("status") != "ok"]
    stats = {}
    for col in pipeline.columns[len(BASE_COLUMNS):]:
        try:
            values = np.array([float(r[col]) for r in ok if r.get(col, "") != ""], dtype=float)
        except ValueError:
            continue  # a text column
        values = values[np.isfinite(values)]
        if values.size:
            stats[col] = {"min": float(values.min()), "median": float(np.median(values)), "max": float(values.max()),
                          "count": int(values.size)}
    return {"format": BATCH_FORMAT, "version": BATCH_FORMAT_VERSION, "pipeline": pipeline.name,
            "complete": complete, "items": len(items), "ok": len(ok), "failed": len(failed),
            "not_run": len(items) - len(mine), "ran_this_time": ran, "skipped_as_done": skipped,
            "elapsed_s": elapsed, "items_per_s": ran / elapsed if elapsed > 0 else None,
            "errors": [{"item": k, "reason": v} for k, v in failed], "statistics": stats}


def run_batch(pipeline: str, inputs: Sequence[str | os.PathLike], out_dir: str | os.PathLike, *,
              options: Mapping | None = None, workers: int | None = None, scheduler=None, resume: bool = False,
              progress: bool = True, connect_timeout: float = 10.0,
              item_timeout: float | None = ITEM_TIMEOUT) -> BatchResult:
    """Run a pipeline over many files; write ``results.csv``, ``batch.json``, ``summary.json`` and the item outputs.

    Parameters
    ----------
    pipeline : {"process", "replay", "sweep"}
        See the module docstring.
    inputs : sequence of path-like or str
        Files, folders and glob patterns (:func:`collect_inputs`).
    out_dir : path-like
        Output folder (created). It must not hold a results table unless ``resume``.
    options : mapping, optional
        SI options of the pipeline. ``process``: ``channel``, ``level`` (default ``"plane"``),
        ``sigma`` (m, 0), ``inpaint`` (True), ``control_shape`` ((nu, nv) or None: interpolate),
        ``smoothing`` (0), ``export`` (extensions: ``.stl .ply .glb .gwy .gsf .npz .npy``),
        ``resolution`` ((nu, nv) export samples), ``solid``, ``dx``/``dy`` (m) and ``z_unit`` for
        bare matrices. ``replay``: ``scan`` (default: each session's recorded scan). ``sweep``:
        ``friction``, ``tip_radius`` (m), ``effective_modulus`` (Pa) (lists: the grid; default the
        preset's value), ``preset`` (``"demo"``), ``depth`` (m, 2e-9), ``slide`` (m, 20e-9),
        ``steps`` (40 per leg), ``at`` ((x, y) m; default the middle).
    workers : int, optional
        Local worker processes (default: the CPU count; 0: run in this process).
    scheduler : str or distributed.Client, optional
        A Dask scheduler address (``tcp://host:8786``) or client: run on that cluster instead.
    resume : bool
        Skip the items whose latest row in an existing table has ``status`` ``ok``.
    progress : bool
        A counter on stderr.
    connect_timeout : float, s
        How long to wait for the Dask scheduler.
    item_timeout : float or None, s
        Time limit of one item (:data:`ITEM_TIMEOUT` by default; None: none): an item past it is an
        ``error`` row and the batch goes on (local workers; Dask workers keep the cluster's limits).

    Returns
    -------
    BatchResult

    Raises
    ------
    BatchError
        No input, a bad option, an existing table without ``resume``, a table or settings of another
        batch with ``resume``, both ``workers`` and ``scheduler``, an unreachable scheduler.
    MissingDependency
        ``scheduler`` without ``dask.distributed`` installed (``pip install 'arsurf[dask]'``).
    """
    t0 = time.perf_counter()
    p = _pipeline(pipeline)
    if scheduler is not None and workers is not None:
        raise BatchError("give the local worker count or a Dask scheduler, not both (--workers or --scheduler)")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, (int, np.integer))
                                or not 0 <= workers <= 4096):
        raise BatchError(f"workers must be an integer in [0, 4096] (got {workers!r}); 0 runs in this process")
    if isinstance(scheduler, str) and not scheduler.strip():
        raise BatchError("the Dask scheduler address is empty; give tcp://HOST:PORT")
    if not (isinstance(connect_timeout, (int, float)) and math.isfinite(connect_timeout) and connect_timeout > 0):
        raise BatchError(f"connect_timeout must be a positive number of seconds (got {connect_timeout!r})")
    if item_timeout is not None and not (isinstance(item_timeout, (int, float)) and not isinstance(item_timeout, bool)
                                         and math.isfinite(item_timeout) and item_timeout > 0):
        raise BatchError(f"item_timeout must be a positive number of seconds or None (got {item_timeout!r})")
    if scheduler is not None:
        require("distributed", "dask", "arsurf batch on a Dask cluster (--scheduler)")
    opts = json.loads(json.dumps(p.check(dict(options or {}))))  # JSON-normal: tuples -> lists
    out = Path(out_dir)
    files, root = collect_inputs(inputs, p.suffixes, exclude=out)
    items = make_items(p, files, root, opts)
    if len({it.key for it in items}) != len(items):
        raise BatchError("two inputs give the same item name; rename one of them")
    client, own = _connect(scheduler, float(connect_timeout)) if scheduler is not None else (None, False)
    try:
        return _run(p, items, opts, out, workers, client, resume, progress, t0, item_timeout)
    finally:
        if own:
            client.close()


def _run(p: Pipeline, items: list[Item], opts: dict, out: Path, workers, client, resume: bool, progress: bool,
         t0: float, item_timeout: float | None = ITEM_TIMEOUT) -> BatchResult:
    """The part of :func:`run_batch` after every check: the table, the execution, the summary."""
    _check_out_dir(out, p, opts, resume)
    table_path = check_target(out / TABLE, "results table", error=BatchError)  # not a planted link
    _repair(table_path)
    rows = read_results(table_path, p.columns) if resume else {}
    todo = [it for it in items if not _row_stands(rows.get(it.key), p.columns, out)]
    skipped = len(items) - len(todo)
    table = _Table(table_path, p.columns)
    bar = _Progress(len(items), skipped, progress)
    ran = 0

    def record(i: int, row: Mapping) -> None:
        nonlocal ran
        table.append(row)
        rows[row["item"]] = {c: _cell(row.get(c)) for c in p.columns}
        ran += 1
        bar.update(row["status"] == "ok")

    def crashed(i: int, reason: str) -> None:
        record(i, {"item": todo[i].key, "status": "error", "error": reason})

    calls = [(p.name, it, opts, str(out.resolve()), item_timeout) for it in todo]
    complete = False
    try:
        if not calls:
            pass
        elif client is not None:
            _execute_dask(run_item, calls, client, record, crashed)
        else:
            n = (os.cpu_count() or 1) if workers is None else int(workers)
            _execute_local(run_item, calls, min(n, len(calls)), record, crashed)
        complete = True
    finally:
        table.close()
        bar.close()
        elapsed = time.perf_counter() - t0
        summary = _summary(p, items, rows, ran, skipped, elapsed, complete)
        write_text(out / SUMMARY, summary_json(summary), what="batch summary", error=BatchError)
    return BatchResult(out_dir=out, table=table_path, summary=out / SUMMARY, total=len(items), ran=ran,
                       skipped=skipped, ok=summary["ok"], failed=summary["failed"],
                       errors=tuple((e["item"], e["reason"]) for e in summary["errors"]), elapsed=elapsed,
                       items_per_second=summary["items_per_s"] or 0.0)
