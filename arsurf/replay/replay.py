r"""Offline replay: re-run the model over a recorded session and write what it computes.

:func:`replay` (and ``arsurf replay SESSION --scan SCAN --out DIR``) loads a session
(:mod:`arsurf.sessions`), checks that the scan file is the one it was recorded on (SHA-256
of the bytes), rebuilds the surface and the :class:`~arsurf.model.ARModel` exactly as recorded
(:func:`~arsurf.assembly.build_model`), runs the model over every recorded tick - tip
centre, tip velocity and, where both are finite, the measured (bending, torsion) signals - and
writes into ``DIR``:

=====================  =======================================================================
file                   content
=====================  =======================================================================
``replay.h5``          per tick: recomputed contact (point, normal, uv, distance, depth, radius,
                       load, status) and forces (simulated, measured) with the recorded force,
                       format ``arsurf-replay`` version 1 (schema below, style of the session)
``forces.csv``         ``t_s``, recorded / simulated / measured force xyz (``F_recorded_x_N``...),
                       ``depth_m``, ``contact_radius_m``, ``load_N``, ``in_contact``: SI units
                       named in the header (:mod:`arsurf.units`), floats written with ``repr``
                       (shortest exact round trip), ``nan`` where absent
``summary.json``       tick count, duration, peaks, agreement with the recorded contact (SI, the
                       unit in each key: ``duration_s``, ``peak_force_N``, ``max_depth_m``)
``forces.png``         force components in nN vs time, contact shaded ([MWCNT] Fig. 10)
``coupled_motion.png`` probe z / device F_z / probe y / device F_y vs time ([Alabdulmuhsin] Fig. 4.21)
``path.png``           the probe path over the processed height map (nm, colour bar)
``frames/``            ``frame_NNNNN.png``, only with ``frames > 0`` and :mod:`arsurf_viewer`
=====================  =======================================================================

The same session and scan give byte-identical files (no timestamps anywhere: the session's
``created`` is not copied, HDF5 datasets carry no times, PNGs no text chunks). Everything is
written into a hidden sibling folder that is renamed to ``DIR`` only at the end, so an
interrupted replay leaves ``DIR`` absent (or, with ``overwrite``, as it was).

``replay.h5`` per-tick datasets (``/ticks``; root attributes ``format="arsurf-replay"``,
``format_version=1``, ``arsurf_version``, ``units="SI"``, ``complete``, ``n_ticks``,
``session_sha256``, ``scan_sha256``; ``/metadata`` is the session's; every dataset carries its
SI unit in a ``units`` attribute, :mod:`arsurf.units`):

=====================  ========  =====  =====================================================
dataset                shape     dtype  meaning
=====================  ========  =====  =====================================================
``t``                  (n,)      f8     recorded time, s
``probe_position``     (n, 3)    f8     recorded tip centre, m
``probe_velocity``     (n, 3)    f8     recorded tip velocity, m/s
``signals``            (n, 2)    f8     recorded (bending, torsion), rad (NaN: none)
``recorded_force``     (n, 3)    f8     the force the live loop used, N
``simulated_force``    (n, 3)    f8     replayed model force P n + friction, N
``measured_force``     (n, 3)    f8     replayed decoupling of the signals, N (NaN: none)
``contact_point``      (n, 3)    f8     closest point on the rest surface, m
``contact_normal``     (n, 3)    f8     unit normal there
``uv``                 (n, 2)    f8     surface parameters of the closest point, m
``distance``           (n,)      f8     signed distance of the tip centre, m
``depth``              (n,)      f8     indentation depth R - distance, m
``contact_radius``     (n,)      f8     Maugis-Dugdale contact radius, m
``load``               (n,)      f8     Maugis-Dugdale load, N (> 0 compressive)
``condition``          (n,)      f8     condition number of the decoupling (NaN: none)
``in_contact``         (n,)      i4     1 when touching
``md_status``          (n,)      i4     0 contact, 1 cohesive, 2 separated, < 0 error
``decoupling_flags``   (n,)      i4     DecouplingFlag bits
``collide_status``     (n,)      i4     collision status (< 0: failed, contact fields NaN)
``moved``              (n,)      i4     control points under the dent (its index box)
``tube_poses``         (n,k,3)   f8     only with a tube scene: the poses the replayed scene
                                        computed (x, y m, angle rad) after each tick
=====================  ========  =====  =====================================================

Tube scene: when the session's metadata has ``tubes`` (:mod:`arsurf.manipulation.scene`), the
surface is the substrate (as recorded) and the scene is re-run over the recorded probe
positions - tick k pushes with the tip moving from ``probe_position[k-1]`` to
``probe_position[k]`` (no move at tick 0), exactly what :class:`~arsurf.haptics.loop.HapticLoop`
did live - so the poses come back bit for bit; the summary gives the largest difference from
the recorded ``tube_poses`` (``tubes/position_difference_m`` and ``tubes/angle_difference_rad``,
0 for a faithful replay; :attr:`ReplayResult.tube_pose_difference` is the larger), each tube's
displacement and rotation, and the frames draw the tubes where they are.

Examples
--------
>>> # result = replay("run.h5", "scans/nanotubes.npz", "run-replay", frames=20)
>>> # result.files -> ('coupled_motion.png', 'forces.csv', 'forces.png', 'frames/frame_00000.png', ...)
"""
from __future__ import annotations

import importlib
import logging
import math
import os
import json
import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from arsurf import status
from arsurf._files import read_regular, write_text
from arsurf._logging import progress as progress_bar
from arsurf.errors import ArsurfError, MissingDependency, SessionError, rendering_failed, require
from arsurf.assembly import build_model, scan_sha256
from arsurf.units import summary_json, with_unit
from arsurf.sessions.reader import Session, load_session, read_h5
from arsurf.sessions.schema import MD_STATUS_NOT_GIVEN, TUBE_POSES, TickField
from arsurf.sessions.writer import write_h5

log = logging.getLogger(__name__)

__all__ = ["replay", "ReplayResult", "load_replay", "REPLAY_FIELDS", "REPLAY_FORMAT", "register", "cmd_replay"]

REPLAY_FORMAT = "arsurf-replay"
REPLAY_FORMAT_VERSION = 1
_NAN = math.nan
#: the per-tick datasets of replay.h5, in file order
REPLAY_FIELDS: tuple[TickField, ...] = (
    TickField("t", 0, "f8", _NAN, "recorded time, s", "s"),
    TickField("probe_position", 3, "f8", _NAN, "recorded tip centre, m", "m"),
    TickField("probe_velocity", 3, "f8", _NAN, "recorded tip velocity, m/s", "m/s"),
    TickField("signals", 2, "f8", _NAN, "recorded (bending, torsion), rad", "rad"),
    TickField("recorded_force", 3, "f8", _NAN, "force the live loop used, N", "N"),
    TickField("simulated_force", 3, "f8", _NAN, "replayed model force, N", "N"),
    TickField("measured_force", 3, "f8", _NAN, "replayed decoupled force, N", "N"),
    TickField("contact_point", 3, "f8", _NAN, "closest point on the rest surface, m", "m"),
    TickField("contact_normal", 3, "f8", _NAN, "unit contact normal"),
    TickField("uv", 2, "f8", _NAN, "surface parameters of the closest point, m", "m"),
    TickField("distance", 0, "f8", _NAN, "signed distance of the tip centre, m", "m"),
    TickField("depth", 0, "f8", _NAN, "indentation depth, m", "m"),
    TickField("contact_radius", 0, "f8", _NAN, "contact radius, m", "m"),
    TickField("load", 0, "f8", _NAN, "Maugis-Dugdale load, N", "N"),
    TickField("condition", 0, "f8", _NAN, "decoupling condition number"),
    TickField("in_contact", 0, "i4", 0, "1 when touching"),
    TickField("md_status", 0, "i4", 0, "MD status"),
    TickField("decoupling_flags", 0, "i4", 0, "DecouplingFlag bits"),
    TickField("collide_status", 0, "i4", 0, "collision status"),
    TickField("moved", 0, "i4", 0, "control points under the dent (its index box)"),
)
#: forces.csv columns, each with its SI unit (:mod:`arsurf.units`)
_CSV_COLUMNS = ("t_s", "F_recorded_x_N", "F_recorded_y_N", "F_recorded_z_N", "F_simulated_x_N", "F_simulated_y_N",
                "F_simulated_z_N", "F_measured_x_N", "F_measured_y_N", "F_measured_z_N", "depth_m",
                "contact_radius_m", "load_N", "in_contact")


@dataclass(frozen=True)
class ReplayResult:
    """What :func:`replay` wrote and found (SI units).

    ``files``: paths relative to ``out_dir``, sorted; ``frames``: PNG frames written;
    ``notes``: why something was skipped; ``peak_force``: largest |simulated force| (N);
    ``peak_measured_force`` (N, NaN without signals); ``max_depth``, ``max_contact_radius`` (m);
    ``depth_difference``, ``load_difference``: largest |replayed - recorded| where the session
    recorded them (NaN: never); ``contact_mismatches``: ticks whose recorded contact state
    (md_status) differs from the replay; ``collision_failures``: ticks the collision could not
    answer; ``elapsed``: wall time (s, not written to any file); ``tube_poses`` (n, k, 3) the
    replayed poses (None without a tube scene); ``tube_pose_difference`` largest |replayed -
    recorded| pose component (NaN: nothing to compare).
    """

    out_dir: Path
    n_ticks: int
    files: tuple[str, ...]
    frames: int
    notes: tuple[str, ...]
    peak_force: float
    peak_measured_force: float
    max_depth: float
    max_contact_radius: float
    depth_difference: float
    load_difference: float
    contact_mismatches: int
    collision_failures: int
    elapsed: float
    tube_poses: np.ndarray | None = None
    tube_pose_difference: float = _NAN

    def _repr_html_(self) -> str:
        """Peaks, agreement with the recording, files and a force thumbnail (IPython)."""
        from arsurf.sessions.display import replay_html

        return replay_html(self, self._ticks())

    def _repr_png_(self) -> bytes | None:
        """The replayed and recorded |force| against time, from ``replay.h5`` (IPython)."""
        from arsurf.sessions.display import replay_png

        return replay_png(self, self._ticks())

    def _ticks(self) -> dict | None:
        """The per-tick arrays of ``out_dir/replay.h5`` (checked), None when it is gone or damaged."""
        path = Path(self.out_dir) / "replay.h5"
        if not path.is_file():
            return None
        try:
            return load_replay(path).ticks
        except ArsurfError:
            return None


#: the list of files arsurf wrote in an output folder (relative path, size, SHA-256): what
#: ``overwrite`` may delete there, and nothing else
MANIFEST = "arsurf-manifest.json"


#: how far beyond the scan a recorded probe may be, in scan extents (the larger side) on each side
PROBE_MARGIN = 2.0


def check_probe_extent(positions: np.ndarray, surface, name: str) -> None:
    """Refuse a probe position outside the scan's extent plus :data:`PROBE_MARGIN` extents (x, y
    within the surface's domain, z within its heights, each widened by the margin), naming the
    tick: a session recorded on this scan never put the tip there.

    Examples
    --------
    >>> from arsurf.spline.surface import BSplineSurface
    >>> s = BSplineSurface.from_heights(np.zeros((4, 4)), (0, 1e-6), (0, 1e-6))
    >>> check_probe_extent(np.array([[5e-7, 5e-7, 1e-7]]), s, "session")
    >>> check_probe_extent(np.array([[5e-7, 5e-7, 1e-7], [1.0, 0, 0]]), s, "session")
    Traceback (most recent call last):
    ...
    arsurf.errors.SessionError: session: tick 1: probe_position = [1.0, 0.0, 0.0] m is outside the scan ...
    """
    (u0, u1), (v0, v1) = surface.domain
    z = np.asarray(surface.control_points)[..., 2]
    margin = PROBE_MARGIN * max(u1 - u0, v1 - v0)
    lo = np.array([u0, v0, float(z.min())]) - margin
    hi = np.array([u1, v1, float(z.max())]) + margin
    bad = ((positions < lo) | (positions > hi)).any(axis=1)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        raise SessionError(f"{name}: tick {k}: probe_position = {positions[k].tolist()} m is outside the scan "
                           f"(x {lo[0]:.3g}..{hi[0]:.3g}, y {lo[1]:.3g}..{hi[1]:.3g}, z {lo[2]:.3g}..{hi[2]:.3g} m: "
                           f"its extent plus {PROBE_MARGIN:g} extents); the session was not recorded on this scan "
                           "or is damaged")


def _finite_rows(name: str, a: np.ndarray, session_path) -> None:
    bad = ~np.isfinite(a).reshape(a.shape[0], -1).all(axis=1)
    if bad.any():
        k = int(np.argmax(bad))
        raise SessionError(f"session {str(session_path)!r}: {name} is not finite at {int(bad.sum())} tick(s), "
                           f"first at tick {k} ({a[k].tolist()}); the replay needs it at every tick")


def _csv(path: Path, columns: list[np.ndarray]) -> None:
    """One row per tick, floats as repr (exact), integers as integers; '\\n' line ends."""
    table = np.column_stack(columns[:-1])
    ints = columns[-1]
    with open(path, "w", encoding="ascii", newline="\n") as fh:
        fh.write(",".join(_CSV_COLUMNS) + "\n")
        for row, flag in zip(table.tolist(), ints.tolist()):
            fh.write(",".join(map(repr, row)))
            fh.write(f",{flag}\n")


def _max_abs(a: np.ndarray) -> float:
    a = np.abs(a[np.isfinite(a)])
    return float(a.max()) if a.size else _NAN


#: the SI unit of each statistic (ReplayResult field) in summary.json's keys (:mod:`arsurf.units`)
_STAT_UNITS = {"peak_force": "N", "peak_measured_force": "N", "max_depth": "m", "max_contact_radius": "m",
               "depth_difference": "m", "load_difference": "N", "contact_mismatches": "", "collision_failures": ""}


def _json_number(x: float):
    return None if not math.isfinite(x) else x


def _rmtree(path: Path) -> None:
    if path.exists():
        shutil.rmtree(path, ignore_errors=False)


def recorded_scan(session, session_path: str | os.PathLike) -> Path:
    """The scan file a session names (``metadata["scan"]["path"]``): an absolute path as it is, a
    relative one from the current folder (where ``arsurf`` was run when it recorded), else from the
    session's folder. Only a regular file is taken (the caller checks its SHA-256 against the session's).

    Raises
    ------
    SessionError
        The session names no scan, or no regular file is found there (the message says where it looked).
    """
    named = (session.metadata.get("scan") or {}).get("path")
    if not isinstance(named, str) or not named:
        raise SessionError(f"session {str(session_path)!r} records no scan path; pass the scan with --scan")
    path = Path(named)
    places = [path] if path.is_absolute() else [Path.cwd() / path, Path(session_path).resolve().parent / path]
    for candidate in places:
        if candidate.is_file():
            return candidate
    raise SessionError(f"session {str(session_path)!r} was recorded on {named!r}, which is not a file here (looked "
                       f"at {', '.join(repr(str(p)) for p in places)}); pass the scan with --scan")


def replay(session_path: str | os.PathLike, scan_path: str | os.PathLike | None, out_dir: str | os.PathLike, *,
           frames: int = 0, progress: bool = True, overwrite: bool = False,
           frame_size: tuple[int, int] = (800, 600), allow_incomplete: bool = False,
           isolate="auto", figure_format: str = "png", dpi: int | None = None) -> ReplayResult:
    """Re-run the model over a recorded session and write forces, contacts, plots and frames.

    Parameters
    ----------
    session_path : path-like
        A session file (:class:`~arsurf.sessions.writer.SessionWriter`).
    scan_path : path-like or None
        The scan file the session was recorded on (its SHA-256 must match the session's); None:
        the one the session names (:func:`recorded_scan`), hash-checked the same way.
    out_dir : path-like
        Output folder; must not exist unless ``overwrite`` (its files are replaced only at the
        end). It gets :data:`MANIFEST`, the list of the files written (size, SHA-256).
    frames : int
        Number of offscreen PNG frames, evenly spread over the ticks (0: none). Needs the
        viewer (:mod:`arsurf_viewer`, pyvista) and an OpenGL context: without the viewer
        :class:`~arsurf.errors.MissingDependency` is raised before any work, and a rendering
        failure raises :class:`~arsurf.errors.RenderingUnavailable` saying what to install
        (no output folder is left behind: frames asked for are never silently dropped).
    progress : bool
        Show a progress bar (tqdm on stderr, when it is a terminal and the ``arsurf`` logger
        passes INFO). Notes (what was skipped) are logged as warnings to ``arsurf.replay``.
    overwrite : bool
        Write into an existing ``out_dir``: only the files arsurf wrote there (listed in its
        :data:`MANIFEST`) are replaced or deleted, every other file is kept (one whose name an
        output needs stops the replay before anything is changed).
    frame_size : (width, height) int, pixels
    allow_incomplete : bool
        Replay a session whose recording did not end normally (killed: the ticks recovered
        from its journal; stopped by a signal or an error): a note says so and how many ticks
        it holds, and ``summary.json`` gets ``session_incomplete`` (the reason).
    isolate : {"auto", True, False}
        How the session file is parsed (:func:`~arsurf.sessions.reader.load_session`);
        ``arsurf replay`` uses True: libhdf5 runs in a child process.
    figure_format : {"png", "pdf", "svg"}
        File format of the figures (:mod:`arsurf.replay.plots`): ``forces``, ``coupled_motion``,
        ``path``, plus ``tubes`` (a tube scene) and ``dent`` (a deformed surface).
    dpi : int, optional
        Resolution of PNG figures (default :data:`arsurf.replay.plots.DEFAULT_DPI`).

    Returns
    -------
    ReplayResult

    Raises
    ------
    SessionError
        Unreadable session (see :func:`~arsurf.sessions.reader.load_session`), scan hash
        mismatch (both hashes named), non-finite probe position/velocity, no ticks,
        ``out_dir`` exists without ``overwrite``.
    ScanError
        The scan file is missing or unreadable.
    """
    t_start = time.perf_counter()
    require("matplotlib.style", "viewer", "replay plots")  # before any work, not after it
    from arsurf.replay import plots

    dpi = plots.check_figure_options(figure_format, dpi)  # FigureError now, not after the run
    out = Path(out_dir)
    frames = int(frames)
    if frames < 0:
        raise SessionError(f"`frames` must be >= 0 (got {frames}); 0 writes no frames")
    if frames > 0:
        _viewer()  # a missing viewer is said now, not after the model is built
    if out.exists() and not overwrite:
        raise SessionError(f"output folder {str(out)!r} exists; choose another folder or pass overwrite=True "
                           "(--overwrite) to replace it")
    if out.exists() and not out.is_dir():
        raise SessionError(f"output path {str(out)!r} is a file, not a folder")
    session = load_session(session_path, allow_incomplete=allow_incomplete, isolate=isolate)
    notes: list[str] = []
    if not session.complete:
        notes.append(f"session {str(session_path)!r} is incomplete ({session.attrs.get('aborted', 'not closed')}): "
                     f"replaying the {session.n_ticks} ticks it holds"
                     + (f" (recovered from {str(session.path)!r})" if session.recovered else ""))
    if session.attrs.get("dropped_ticks"):
        notes.append(f"the recorder dropped {session.attrs['dropped_ticks']} ticks (the disk fell behind); "
                     "the replay runs over those it kept")
    if not session.verified:
        notes.append("the session carries no checksums (format_version 1): its content cannot be verified")
    expected = session.metadata["scan"]["sha256"]
    if scan_path is None:
        scan_path = recorded_scan(session, session_path)
    actual = scan_sha256(scan_path)
    if actual != expected:
        raise SessionError(
            f"scan {str(scan_path)!r} has SHA-256 {actual}, but session {str(session_path)!r} was recorded on "
            f"{session.metadata['scan']['path']!r} with SHA-256 {expected}; pass the scan file the session was "
            "recorded on")
    n = session.n_ticks
    if n == 0:
        raise SessionError(f"session {str(session_path)!r} has no ticks; there is nothing to replay")
    ticks = session.ticks
    for name in ("t", "probe_position", "probe_velocity"):
        _finite_rows(name, ticks[name], session_path)
    session_hash = scan_sha256(session.path)  # the file read (a journal, for a recovered recording)
    setup = build_model(session.metadata, scan_path)
    check_probe_extent(ticks["probe_position"], setup.surface, f"session {str(session_path)!r}")

    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.replay-", dir=out.parent))  # private (0700), exclusive
    try:
        rec = _run(session, setup, tmp, frames, frame_size, progress, notes)
        stats = _write_outputs(tmp, session, setup, rec, session_hash, actual, figure_format, dpi)
        files = tuple(sorted(p.relative_to(tmp).as_posix() for p in tmp.rglob("*") if p.is_file()))
        _install(tmp, out, overwrite, files)
    except BaseException:
        _rmtree(tmp)
        raise
    for note in notes:
        log.warning("replay: %s", note)
    return ReplayResult(out_dir=out, n_ticks=n, files=files, frames=rec["frames"], notes=tuple(notes),
                        elapsed=time.perf_counter() - t_start, tube_poses=rec["tube_poses"], **stats)


#: the public name (``arsurf.replay_session``): ``arsurf.replay`` is the subpackage
replay_session = replay

def _manifest(root: Path, files) -> str:
    """The manifest of the files arsurf wrote in ``root``: relative path, size and SHA-256 each."""
    import hashlib

    entries = [{"path": f, "size_bytes": (root / f).stat().st_size,
                "sha256": hashlib.sha256((root / f).read_bytes()).hexdigest()} for f in sorted(files)]
    return json.dumps({"format": "arsurf-manifest", "written_by": "arsurf replay", "files": entries},
                      indent=1, sort_keys=True) + "\n"


def _ours(out: Path) -> list[str]:
    """The files the manifest of ``out`` says arsurf wrote there (relative, inside ``out``); [] without one."""
    m = out / MANIFEST
    if not m.is_file() or m.is_symlink():
        return []
    try:
        entries = json.loads(read_regular(m, "manifest", error=SessionError, limit=1 << 24))["files"]
        names = [e["path"] for e in entries]
    except (ValueError, TypeError, KeyError, OSError):
        return []  # not a manifest we can trust: nothing there is taken as ours
    good = []
    for n in names:
        if isinstance(n, str) and n and not n.startswith("/") and ".." not in n.split("/") and n != MANIFEST:
            good.append(n)
    return good


def _inside(out: Path, rel: str) -> bool:
    """True when no folder between ``out`` and ``out/rel`` is a symbolic link (nothing leads outside)."""
    p = out
    for part in rel.split("/")[:-1]:
        p = p / part
        if p.is_symlink() or (p.exists() and not p.is_dir()):
            return False
    return True


def _install(tmp: Path, out: Path, overwrite: bool, files) -> None:
    """Move the finished temporary folder's files to ``out``, with a manifest of them.

    A new ``out`` is the temporary folder renamed. An existing one (``overwrite``) keeps every
    file arsurf did not write there: only the files its manifest lists are deleted, and a file
    of the new output whose name a foreign file holds stops the install before anything changed.
    """
    mode = 0o777 & ~_umask()
    manifest = _manifest(tmp, files)
    if not out.exists() and not out.is_symlink():
        (tmp / MANIFEST).write_text(manifest, encoding="utf-8")
        os.chmod(tmp, mode)
        os.rename(tmp, out)
        return
    if not overwrite:
        raise SessionError(f"output folder {str(out)!r} appeared during the replay; nothing was written to it")
    if out.is_symlink() or not out.is_dir():
        raise SessionError(f"output path {str(out)!r} is not a folder (a link or a file); nothing was written to it")
    ours = set(_ours(out))
    for rel in files:
        dest = out / rel
        if not _inside(out, rel) or ((dest.exists() or dest.is_symlink()) and rel not in ours):
            raise SessionError(f"output folder {str(out)!r} holds {rel!r}, which arsurf did not write there (it is "
                               "not in its manifest); it is kept: move it away or choose another folder")
    for rel in sorted(ours):
        dest = out / rel
        if _inside(out, rel) and (dest.is_symlink() or dest.is_file()):
            dest.unlink()
    for rel in sorted(ours, reverse=True):  # folders arsurf made that are now empty (frames/)
        parent = (out / rel).parent
        while parent != out and _inside(out, str(parent.relative_to(out)) + "/x"):
            try:
                parent.rmdir()
            except OSError:
                break
            parent = parent.parent
    for rel in files:
        dest = out / rel
        dest.parent.mkdir(parents=True, exist_ok=True)
        os.replace(tmp / rel, dest)
    write_text(out / MANIFEST, manifest, what="replay manifest", error=SessionError)
    _rmtree(tmp)


def _umask() -> int:
    m = os.umask(0o022)
    os.umask(m)
    return m


def _viewer():
    """The viewer package, or :class:`~arsurf.errors.MissingDependency` naming the extra."""
    try:
        viewer = importlib.import_module("arsurf_viewer")
        viewer.SceneState, viewer.render_frames  # noqa: B018 (a stand-in without them is no viewer)
    except (ImportError, AttributeError) as exc:
        raise MissingDependency(f"replay frames need the viewer (arsurf_viewer cannot be imported: {exc}); "
                                "install it with pip install 'arsurf[viewer]', or ask for no frames") from exc
    return viewer


def _run(session: Session, setup, tmp: Path, frames: int, frame_size, progress: bool, notes: list) -> dict:
    """Run the model over every tick; render frames on the way when asked and possible."""
    from arsurf.model import M_COLLIDE_STATUS, M_DEPTH, M_SIZE, M_TIP

    n = session.n_ticks
    ticks = session.ticks
    pos = ticks["probe_position"]
    sig = ticks["signals"]
    have = np.isfinite(sig).all(axis=1)
    model = setup.model
    model.reset()
    outs = np.empty((n, M_SIZE))
    net = model.surface.control_points  # a read-only view of the live net
    deepest = {"depth": 0.0, "tick": -1, "net": np.empty_like(net)}  # the dent figure's snapshot
    frame_ticks = np.unique(np.linspace(0, n - 1, frames).round().astype(np.int64)) if frames > 0 else np.empty(0, int)
    viewer = None
    if frame_ticks.size:
        viewer = _viewer()
        state_cls, render = viewer.SceneState, viewer.render_frames
    is_frame = np.zeros(n, bool)
    is_frame[frame_ticks] = True
    bar = progress_bar(total=n, desc="replay", unit="tick", enabled=progress)
    failure: dict = {}
    lam = setup.model.contact.maugis_parameter
    radius = setup.model.tip_radius
    scene = setup.scene
    poses = None
    if scene is not None:
        scene.reset()
        poses = np.empty((n, len(scene), 3))
        prev = np.full(3, np.nan)  # tick 0: no previous probe position, as in the live loop
        here = np.empty(3)

    def states():
        tick = model.tick
        try:
            step = 256
            for k0 in range(0, n, step):
                for k in range(k0, min(k0 + step, n)):
                    outs[k] = tick(pos[k], (sig[k, 0], sig[k, 1]) if have[k] else None)
                    if outs[k, M_DEPTH] > deepest["depth"] and outs[k, M_COLLIDE_STATUS] >= 0:
                        deepest["depth"], deepest["tick"] = outs[k, M_DEPTH], k
                        np.copyto(deepest["net"], model.surface.control_points)  # (the dent moved onto the net)
                    if scene is not None:
                        here[:] = outs[k, M_TIP:M_TIP + 3]  # the tip behind the coupling pushes
                        scene.tick(prev, here, radius)
                        poses[k] = scene.poses
                        prev[:] = here
                    if is_frame[k]:
                        yield _scene_state(state_cls, model.surface, outs[k], outs[k, M_TIP:M_TIP + 3], radius, lam, ticks["t"][k],
                                           have[k], scene)
                bar.update(min(k0 + step, n) - k0)
        except BaseException as exc:
            failure["exc"] = exc
            raise

    gen = states()
    n_frames = 0
    try:
        if frame_ticks.size:
            frames_dir = tmp / "frames"
            try:
                n_frames = len(render(gen, frames_dir, movie=None, window_size=tuple(frame_size)).paths)
            except Exception as exc:
                if failure.get("exc") is exc:  # the model failed, not the renderer
                    raise
                raise rendering_failed("replay frames", exc) from exc
        for _ in gen:  # the whole run when no frames are asked for
            pass
    finally:
        bar.close()
    failed = outs[:, M_COLLIDE_STATUS] < 0
    return {"outs": outs, "have_signals": have, "failed": failed, "frames": n_frames, "tube_poses": poses,
            "deepest": deepest}


def _scene_state(state_cls, surface, o: np.ndarray, center, radius, lam, t, have_signals, scene=None):
    from arsurf.model import (M_COLLIDE_STATUS, M_DEPTH, M_MEAS_FX, M_MEAS_FZ, M_NX, M_NZ, M_PX, M_PZ, M_RADIUS,
                              M_SIM_FX, M_SIM_FZ)

    ok = o[M_COLLIDE_STATUS] >= 0
    normal = o[M_NX:M_NZ + 1]
    force = o[M_MEAS_FX:M_MEAS_FZ + 1] if have_signals else o[M_SIM_FX:M_SIM_FZ + 1]
    return state_cls(surface, tip_center=center, tip_radius=radius,
                     contact_point=o[M_PX:M_PZ + 1].copy() if ok else None,
                     contact_normal=normal.copy() if ok and np.any(normal) else None,
                     depth=float(o[M_DEPTH]) if ok else 0.0, contact_radius=float(o[M_RADIUS]),
                     force=force.copy() if np.isfinite(force).all() else np.zeros(3),
                     maugis_lambda=lam, device_status="replay", time=float(t),
                     tubes=scene.viewer_tubes() if scene is not None else ())


def _write_outputs(tmp: Path, session: Session, setup, rec: dict, session_hash: str, scan_hash: str,
                   figure_format: str = "png", dpi: int | None = None) -> dict:
    """replay.h5, forces.csv, summary.json and the plots into ``tmp``; return the statistics."""
    from arsurf import __version__
    from arsurf.model import (M_COLLIDE_STATUS, M_CONDITION, M_DECOUPLE_STATUS, M_DEPTH, M_DISTANCE, M_IN_CONTACT,
                              M_LOAD, M_MD_STATUS, M_MEAS_FX, M_MEAS_FZ, M_MOVED, M_NX, M_NZ, M_PX, M_PZ, M_RADIUS,
                              M_SIM_FX, M_SIM_FZ, M_U, M_V)
    o = rec["outs"]
    have = rec["have_signals"]
    failed = rec["failed"]
    ticks = session.ticks
    n = session.n_ticks

    def geo(a):
        a = a.copy()
        a[failed] = np.nan
        return a

    measured = o[:, M_MEAS_FX:M_MEAS_FZ + 1].copy()
    measured[~have] = np.nan
    condition = o[:, M_CONDITION].copy()
    condition[~have] = np.nan
    data = {
        "t": ticks["t"], "probe_position": ticks["probe_position"], "probe_velocity": ticks["probe_velocity"],
        "signals": ticks["signals"], "recorded_force": ticks["force"],
        "simulated_force": o[:, M_SIM_FX:M_SIM_FZ + 1].copy(), "measured_force": measured,
        "contact_point": geo(o[:, M_PX:M_PZ + 1]), "contact_normal": geo(o[:, M_NX:M_NZ + 1]),
        "uv": geo(o[:, M_U:M_V + 1]), "distance": geo(o[:, M_DISTANCE]), "depth": geo(o[:, M_DEPTH]),
        "contact_radius": o[:, M_RADIUS].copy(), "load": o[:, M_LOAD].copy(), "condition": condition,
        "in_contact": o[:, M_IN_CONTACT].astype(np.int32), "md_status": o[:, M_MD_STATUS].astype(np.int32),
        "decoupling_flags": o[:, M_DECOUPLE_STATUS].astype(np.int32),
        "collide_status": o[:, M_COLLIDE_STATUS].astype(np.int32), "moved": o[:, M_MOVED].astype(np.int32),
    }
    data = {f.name: np.ascontiguousarray(data[f.name], dtype=np.dtype(f.dtype)) for f in REPLAY_FIELDS}
    poses = rec["tube_poses"]
    if poses is not None:
        data["tube_poses"] = poses
    attrs = {"format": REPLAY_FORMAT, "format_version": np.int64(REPLAY_FORMAT_VERSION),
             "arsurf_version": __version__, "units": "SI", "complete": np.bool_(True), "n_ticks": np.int64(n),
             "session_sha256": session_hash, "scan_sha256": scan_hash,
             "session_format_version": np.int64(session.attrs["format_version"])}
    units = {f.name: f.unit for f in (*REPLAY_FIELDS, TUBE_POSES)}
    write_h5(tmp / "replay.h5", attrs, session.metadata, data, units)

    _csv(tmp / "forces.csv", [data["t"], data["recorded_force"], data["simulated_force"], data["measured_force"],
                              data["depth"], data["contact_radius"], data["load"], data["in_contact"]])

    recorded_given = ticks["md_status"] != MD_STATUS_NOT_GIVEN
    recorded_contact = ticks["md_status"] == status.CONTACT
    stats = {
        "peak_force": _max_abs(np.linalg.norm(data["simulated_force"], axis=1)),
        "peak_measured_force": _max_abs(np.linalg.norm(measured, axis=1)),
        "max_depth": _max_abs(np.maximum(data["depth"], 0.0)),
        "max_contact_radius": _max_abs(data["contact_radius"]),
        "depth_difference": _max_abs(data["depth"] - ticks["depth"]),
        "load_difference": _max_abs(data["load"] - ticks["load"]),
        "contact_mismatches": int(np.count_nonzero(recorded_given & (recorded_contact != (data["in_contact"] == 1)))),
        "collision_failures": int(np.count_nonzero(failed)),
    }
    tubes_summary = None
    if poses is not None:
        recorded = ticks.get("tube_poses")
        stats["tube_pose_difference"] = (_max_abs(poses - recorded) if recorded is not None and
                                         recorded.shape == poses.shape else _NAN)
        scene = setup.scene  # its poses are the last tick's
        start = np.array([t.pose for t in scene.initial]).reshape(1, len(scene), 3)
        diff = poses - recorded if recorded is not None and recorded.shape == poses.shape else None
        tubes_summary = {
            "count": len(scene),
            "position_difference_m": _json_number(_max_abs(diff[..., :2]) if diff is not None else _NAN),
            "angle_difference_rad": _json_number(_max_abs(diff[..., 2]) if diff is not None else _NAN),
            "ticks_pushing": int(np.count_nonzero(np.any(np.diff(poses, axis=0, prepend=start) != 0, axis=(1, 2)))),
            "displacement_m": [scene.motion(i).displacement for i in range(len(scene))],
            "rotation_rad": [scene.motion(i).rotation for i in range(len(scene))],
        }
    t = data["t"]
    summary = {
        "format": "arsurf-replay-summary", "units": "SI", "n_ticks": n,
        "duration_s": float(t[-1] - t[0]), "ticks_in_contact": int(np.count_nonzero(data["in_contact"])),
        "ticks_with_signals": int(np.count_nonzero(have)), "frames": rec["frames"],
        "scan": {"path": session.metadata["scan"]["path"], "sha256": scan_hash}, "session_sha256": session_hash,
        "peak_recorded_force_N": _json_number(_max_abs(np.linalg.norm(data["recorded_force"], axis=1))),
        **{with_unit(k, _STAT_UNITS[k]): _json_number(v) if isinstance(v, float) else v
           for k, v in stats.items() if k != "tube_pose_difference"},
    }
    if tubes_summary is not None:
        summary["tubes"] = tubes_summary
    if setup.model.material is not None:  # the map was rebuilt and its hash checked (assembly.build_model)
        summary["material"] = {"sha256": setup.model.material.sha256, "channels": dict(setup.model.material.channels)}
    if not session.complete:  # only then: a complete session's summary is as before
        summary["session_incomplete"] = str(session.attrs.get("aborted", "not closed"))
        summary["session_recovered_from_journal"] = bool(session.recovered)
    (tmp / "summary.json").write_text(summary_json(summary, sort_keys=True), encoding="utf-8")

    _write_figures(tmp, session, setup, rec, data, figure_format, dpi)
    return stats


def _write_figures(tmp: Path, session: Session, setup, rec: dict, data: dict, figure_format: str, dpi) -> None:
    """forces, coupled_motion, path, tubes (a tube scene), dent (a dent): :mod:`arsurf.replay.plots`."""
    from arsurf.model import M_PX, M_PY, M_RADIUS
    from arsurf.replay import plots
    from arsurf.spline.surface import BSplineSurface

    ticks = session.ticks
    t = data["t"]
    contact = data["in_contact"] == 1

    dpi = plots.check_figure_options(figure_format, dpi)

    def save(fig, name: str) -> None:
        plots.save_figure(fig, tmp / f"{name}.{figure_format}", dpi=dpi)

    flags, feel = plots.session_flags(t, ticks["device_force"], ticks.get("safety_flags"),
                                      ticks["passivity_damping"], ticks["energy"], contact)
    save(plots.forces_figure(t, {"recorded": data["recorded_force"], "simulated": data["simulated_force"],
                                 "measured": data["measured_force"]}, contact, flags, feel), "forces")
    save(plots.coupled_motion_figure(t, data["probe_position"], ticks["device_force"], contact, flags, feel),
         "coupled_motion")
    scan, scene, model = setup.scan, setup.scene, setup.model
    before = scene.initial if scene is not None else ()
    after = ()
    if scene is not None and rec["tube_poses"] is not None:
        after = tuple(tube.with_pose(*map(float, pose)) for tube, pose in zip(scene.initial, rec["tube_poses"][-1]))
    else:
        before = ()
    save(plots.path_figure(scan.heights, scan.dx, scan.dy, data["probe_position"], contact, before, after,
                           model.tip_radius), "path")
    if after:
        save(plots.tubes_figure(scan.heights, scan.dx, scan.dy, before, after, data["probe_position"], contact),
             "tubes")
    deep = rec["deepest"]
    surface = model.surface
    if deep["tick"] >= 0 and not np.array_equal(deep["net"], surface.rest_control_points):
        k = deep["tick"]
        dented = BSplineSurface(deep["net"], surface.knots_u, surface.knots_v)
        rest = BSplineSurface(surface.rest_control_points, surface.knots_u, surface.knots_v)
        o = rec["outs"][k]
        save(plots.dent_figure(dented, rest, (o[M_PX], o[M_PY]), 2.0 * model.tip_radius,
                               contact_radius=float(o[M_RADIUS]) or None), "dent")


def load_replay(path: str | os.PathLike) -> Session:
    """Read a ``replay.h5`` written by :func:`replay` (checked like a session)."""
    return read_h5(path, fmt=REPLAY_FORMAT, versions=(REPLAY_FORMAT_VERSION,), fields=REPLAY_FIELDS,
                   what="replay")


# ---------------------------------------------------------------------------------------------
# command line


def cmd_replay(args) -> int:
    """``arsurf replay``: run :func:`replay` and print what it wrote."""
    quiet = getattr(args, "log_quiet", False)  # -q/--quiet (arsurf.cli): no progress bar, no notes, no summary
    result = replay(args.session, args.scan, args.out, frames=args.frames, progress=not quiet,
                    overwrite=args.overwrite, allow_incomplete=args.allow_incomplete, isolate=True,
                    figure_format=args.figure_format, dpi=args.dpi)
    if not quiet:
        print(f"replayed {result.n_ticks} ticks in {result.elapsed:.2f} s -> {result.out_dir}")
        print(f"  peak force {result.peak_force * 1e9:.6g} nN, max depth {result.max_depth * 1e9:.6g} nm, "
              f"max contact radius {result.max_contact_radius * 1e9:.6g} nm")
        if math.isfinite(result.depth_difference):
            print(f"  vs recording: max |depth diff| {result.depth_difference:.3g} m, "
                  f"contact-state mismatches {result.contact_mismatches}")
        for name in result.files:
            print(f"  {name}")
    return 0


def register(subparsers) -> None:
    """Add ``arsurf replay SESSION [--scan SCAN] --out DIR [--frames N] [--overwrite]`` (``-q``: arsurf.cli)."""
    s = subparsers.add_parser("replay", help="re-run the model over a recorded session; write forces, contacts, "
                                             "plots and frames")
    s.add_argument("session", help="session file (.h5) recorded by the live loop or arsurf demo")
    s.add_argument("--scan", help="the scan file the session was recorded on (hash-checked; default: the path the "
                   "session records, from this folder or the session's)")
    s.add_argument("--out", required=True, help="output folder (must not exist unless --overwrite)")
    s.add_argument("--frames", type=int, default=0, help="offscreen PNG frames to render (needs the viewer)")
    s.add_argument("--overwrite", action="store_true", help="replace an existing output folder")
    s.add_argument("--allow-incomplete", action="store_true",
                   help="replay a recording that did not end normally (killed: the ticks recovered from its "
                        "journal; stopped by a signal); a note says how many ticks it holds")
    from arsurf.replay.plots import add_figure_arguments

    add_figure_arguments(s)
    s.set_defaults(func=cmd_replay)
