"""The three batch pipelines (``process``, ``replay``, ``sweep``): for each, its table columns, its
option check (SI, JSON-ready, :mod:`arsurf.batch.options`) and the work of one item, run in a
worker (module-level functions, pickled by reference); :func:`run_item` turns any failure into an
``error`` row. The sweep's physics is :func:`arsurf.manipulation.press_slide.press_slide_retract`.
"""
from __future__ import annotations

import contextlib
import functools
import itertools
import math
import multiprocessing
import os
import re
import signal
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Mapping, Sequence

import numpy as np

from arsurf._files import sha256_file
from arsurf.batch.inputs import Item, item_file_name, item_key
from arsurf.batch.options import axis, int_pair, number, refuse_unknown
from arsurf.batch.table import BASE_COLUMNS, one_line_reason
from arsurf.errors import BatchError, ItemTimeout, SessionError, require

__all__ = ["PIPELINES", "Pipeline", "get_pipeline", "make_items", "run_item"]

#: most items one batch accepts (a typo in a sweep grid must not allocate millions of rows)
MAX_ITEMS = 1_000_000


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



def make_items(pipeline: str | Pipeline, files: Sequence[Path], root: Path, options: Mapping) -> list[Item]:
    """The items of a batch: one per file, and for ``sweep`` one per file and grid point.

    The sweep's grid is the Cartesian product of ``options["friction"]``, ``["tip_radius"]`` and
    ``["effective_modulus"]`` (SI); its key is ``<file>;friction=...;tip_radius_m=...;
    effective_modulus_Pa=...`` with the values as Python writes them (exact).
    """
    p = get_pipeline(pipeline)
    items = [Item(item_key(f, root), str(f), (), str(root)) for f in files]
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


_MESH_EXPORTS = (".stl", ".ply", ".glb")
_MAP_EXPORTS = (".gwy", ".gsf", ".npz", ".npy")
_PROCESS_OPTIONS = ("channel", "level", "sigma", "inpaint", "control_shape", "smoothing", "export", "resolution",
                    "solid", "dx", "dy", "z_unit")


def _check_process(options: Mapping) -> dict:
    from arsurf.scan.level import METHODS

    refuse_unknown(options, _PROCESS_OPTIONS, "process")
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
        "sigma": number(options, "sigma", 0.0, unit="m", what="it is the Gaussian smoothing width in metres"),
        "inpaint": bool(options.get("inpaint", True)),
        "control_shape": int_pair(options, "control_shape", 4, "they are the control points of an approximating fit"),
        "smoothing": number(options, "smoothing", 0.0, what="it is the P-spline penalty weight"),
        "export": norm,
        "resolution": int_pair(options, "resolution", 2, "they are the samples along u and v of an export"),
        "solid": bool(options.get("solid", False)),
        "z_unit": None if options.get("z_unit") is None else str(options["z_unit"]),
    }
    for name in ("dx", "dy"):
        out[name] = (None if options.get(name) is None else
                     number(options, name, None, strict=True, unit="m", what="it is the pixel spacing in metres"))
    return out


def _check_replay(options: Mapping) -> dict:
    refuse_unknown(options, ("scan",), "replay")
    scan = options.get("scan")
    if scan is not None and not os.path.isfile(scan):
        raise BatchError(f"scan file {os.fspath(scan)!r} does not exist (option 'scan': the scan every session was "
                         "recorded on; leave it out to use the path each session recorded)")
    return {"scan": None if scan is None else str(Path(scan).resolve())}



#: the sweep's axes: option name, unit in the key and in the column name
_SWEEP_AXES = (("friction", ""), ("tip_radius", "_m"), ("effective_modulus", "_Pa"))
_SWEEP_OPTIONS = ("friction", "tip_radius", "effective_modulus", "preset", "depth", "slide", "steps", "at")
_SWEEP_DEFAULT_STEPS = 40


def _check_sweep(options: Mapping) -> dict:
    from arsurf.assembly import PRESET_ALIASES, PRESETS

    refuse_unknown(options, _SWEEP_OPTIONS, "sweep")
    name = options.get("preset", "demo")
    name = PRESET_ALIASES.get(name, name) if isinstance(name, str) else name
    if name not in PRESETS:
        raise BatchError(f"option 'preset' must be one of {sorted(PRESETS)} (got {name!r})")
    p = PRESETS[name]
    out = {
        "preset": name,
        "friction": axis(options, "friction", p.friction, strict=False, unit="",
                          what="it is the kinetic friction coefficient"),
        "tip_radius": axis(options, "tip_radius", p.tip_radius, strict=True, unit="m",
                            what="it is the tip sphere radius in metres"),
        "effective_modulus": axis(options, "effective_modulus", p.effective_modulus, strict=True, unit="Pa",
                                   what="it is the contact modulus E* in pascals"),
        "depth": number(options, "depth", 2e-9, strict=True, unit="m",
                         what="it is the indentation of the press in metres"),
        "slide": number(options, "slide", 20e-9, unit="m", what="it is the slide length along x in metres"),
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
    stem = item_file_name(item.key)
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
    name = item_file_name(item.key)
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
    from arsurf.assembly import make_model, preset
    from arsurf.manipulation.press_slide import press_slide_retract

    p = preset(o["preset"])
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
    physics = press_slide_retract(model, x, y, tip_radius=radius, depth=o["depth"], slide=o["slide"], steps=o["steps"])
    return {"scan": item.key.split(";", 1)[0], "friction": mu, "tip_radius_m": radius,
            "effective_modulus_Pa": modulus, "work_of_adhesion_J_per_m2": p.work_of_adhesion, **physics}


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


def get_pipeline(name: str | Pipeline) -> Pipeline:
    """The pipeline named ``name`` (a Pipeline is returned as it is); BatchError for an unknown name."""
    if isinstance(name, Pipeline):
        return name
    if name not in PIPELINES:
        raise BatchError(f"unknown pipeline {name!r}; choose one of {', '.join(PIPELINES)}")
    return PIPELINES[name]


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
    return ";".join(f"{f.relative_to(out_dir).as_posix()}|{f.stat().st_size}|{sha256_file(f)}" for f in sorted(files))


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
                    or sha256_file(p) != digest):
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
        return {"item": item.key, "status": "error", "error": one_line_reason(exc)}
    return {"item": item.key, "status": "ok", "error": "", **values, "item_time_s": time.perf_counter() - t0,
            "output_files": files}
