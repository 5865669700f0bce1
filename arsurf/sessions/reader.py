r"""Reading a session file, or the journal of a recording that never closed (:func:`load_session`).

The file is the one :mod:`arsurf.sessions.schema` describes and :mod:`arsurf.sessions.writer`
writes; :func:`read_h5` reads any file :func:`~arsurf.sessions.writer.write_h5` wrote (replay
outputs too).

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
process with time and memory limits (:func:`arsurf.sessions.sealed.run_isolated`), so a libhdf5
crash or hang on it becomes a SessionError; ``isolate=True`` does that for every file (a file
crafted to carry a valid seal is then harmless too) and is what ``arsurf replay`` uses;
``isolate=False`` reads unsealed files in-process (trusted files, no child process). Version 1
files load with ``Session.verified`` False: they carry no checksums.
"""
from __future__ import annotations

import json
import math
import os
import re
import stat
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from arsurf._files import check_regular, read_regular
from arsurf._h5safe import GZIP_LIMIT, open_hdf5
from arsurf.assembly import check_metadata, tube_count
from arsurf.errors import SessionError, SessionFileNotFound
from arsurf.sessions import journal as _journal
from arsurf.sessions.journal import journal_path
from arsurf.sessions.schema import (_CHECKSUMMED_FROM, _KNOWN_EXTRA, _NAN, FORMAT, FORMAT_VERSION, INSTRUMENT_POSITION,
                                    SAFETY_FLAGS, SUPPORTED_VERSIONS, TICK_FIELDS, TUBE_POSES, TickField, _array_digest,
                                    _attr, _canonical, _h5py, _layout, _session_fields, _sha)
from arsurf.sessions.sealed import check_superblock, read_sealed, run_isolated
from arsurf.units import UNITS_ATTR

__all__ = ["Session", "SessionFileNotFound", "load_session", "read_h5"]

#: gzip cannot inflate more than ~1032x: data claiming more than this per file byte is damage
_MAX_INFLATION = 1100
_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]{0,63}$")


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
        from arsurf.sessions.display import session_html

        return session_html(self)

    def _repr_png_(self) -> bytes | None:
        """|force on the tip| against time, contact shaded (IPython)."""
        from arsurf.sessions.display import session_png

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
                           f"record sessions with arsurf.SessionWriter")
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
from arsurf.sessions.reader import _isolated_child
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
#: Haption's Virtuose 6D, spans about 1.1 m): the bound of a session that records no device
#: workspace (older than arsurf 0.9), and the most a recorded one may claim
DEVICE_REACH = 1.0
#: no desk haptic device pushes harder than this, N (the strongest give ~35-40 N peak): the bound
#: of a session that records no device ``max_force``, and the most a recorded one may claim
DEVICE_FORCE_LIMIT = 100.0
#: no tip position in a scan frame lies farther than this from its origin, m (AFM scanners travel
#: at most ~0.1 mm); the replay checks the scan's own extent once the scan is read
PROBE_REACH = 1e-2


def _first(bad: np.ndarray) -> int:
    return int(np.flatnonzero(bad)[0])


def device_bounds(metadata) -> tuple[np.ndarray, str, float, str]:
    r"""``(reach (3,) m, why, force limit N, why)``: how far from home a recorded stylus may be,
    per axis, and how hard the device may push, from the session's ``device`` record
    (:class:`~arsurf.config.DeviceConfig`).

    The reach is the workspace half-extent plus the same again, :math:`|x_j| \le w_j`, the
    margin the live loop's sample check uses (:class:`~arsurf.haptics.samples.SampleCheck`); the
    force limit is ``max_force`` plus 1 %. A session without a usable record (recorded before
    the device was, or by a script) gets :data:`DEVICE_REACH` and :data:`DEVICE_FORCE_LIMIT`,
    which also cap what a record may claim.

    >>> reach, _, limit, _ = device_bounds({"device": {"max_force": 7.9, "workspace": [0.12, 0.16, 0.12]}})
    >>> reach.tolist(), round(limit, 3)
    ([0.12, 0.16, 0.12], 7.979)
    """
    device = metadata.get("device") if isinstance(metadata.get("device"), dict) else {}
    reach, where = np.full(3, DEVICE_REACH), "no desk haptic device reaches farther"
    ws = device.get("workspace")
    if (isinstance(ws, list) and len(ws) == 3
            and all(isinstance(x, (int, float)) and not isinstance(x, bool) and 0 < x < math.inf for x in ws)):
        reach = np.minimum(np.asarray(ws, dtype=np.float64), DEVICE_REACH)
        where = "outside the recorded device workspace (half-extent plus as much again, per axis)"
    limit, what = DEVICE_FORCE_LIMIT, "no desk haptic device pushes harder"
    mf = device.get("max_force")
    if isinstance(mf, (int, float)) and not isinstance(mf, bool) and 0 < mf < DEVICE_FORCE_LIMIT:
        limit, what = 1.01 * mf, "above the recorded device's max_force (plus 1 %)"
    return reach, where, limit, what


def check_ticks(s: Session, name: str) -> None:
    """Refuse ticks that cannot be real, naming the tick and the field (:class:`SessionError`).

    - ``t``: finite and strictly increasing;
    - ``probe_position`` (and ``tip_position``, ``contact_point``, ``instrument_position`` where
      given): finite, within :data:`PROBE_REACH` of the scan frame's origin (the replay then checks
      the scan's extent, :func:`arsurf.replay.replay.check_probe_extent`);
    - ``stylus_position`` where given: within the recorded device workspace (:func:`device_bounds`);
    - ``device_force`` where given: finite, norm within the recorded device's ``max_force``
      (:func:`device_bounds`); ``force`` finite where given.

    NaN is the fill of an optional field (not given) and is allowed there; an infinity never is.
    A sealed session is checked the same way: the seal says the bytes are intact, not that they
    make sense.
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
    reach, where, limit, what = device_bounds(s.metadata)
    # (field, bound: a norm, or (3,) per-axis magnitudes, unit, why)
    checks = [("probe_position", PROBE_REACH, "m", "outside any scanner's travel"),
              ("tip_position", PROBE_REACH, "m", "outside any scanner's travel"),
              ("contact_point", PROBE_REACH, "m", "outside any scanner's travel"),
              ("instrument_position", PROBE_REACH, "m", "outside any scanner's travel"),
              ("stylus_position", reach, "m", where),
              ("device_force", limit, "N", what),
              ("force", math.inf, "N", "")]
    for field_name, bound, unit, why in checks:
        a = s.ticks.get(field_name)
        if a is None or not a.size:
            continue
        a = a.reshape(a.shape[0], -1)
        given = ~np.isnan(a).any(axis=1)
        inf = np.isinf(a).any(axis=1)
        if inf.any():
            k = _first(inf)
            raise SessionError(f"{name}: tick {k}: {field_name} = {a[k].tolist()} {unit} is infinite")
        a0 = np.where(given[:, None], a, 0.0)
        if np.ndim(bound):
            far = (np.abs(a0) > bound).any(axis=1)
            size, shown = np.abs(a0).max(axis=1), f"per axis {np.asarray(bound).tolist()} {unit}"
        else:
            size = np.linalg.norm(a0, axis=1)
            far, shown = size > bound, f"{bound:g} {unit}"
        if far.any():
            k = _first(far)
            raise SessionError(f"{name}: tick {k}: {field_name} = {a[k].tolist()} {unit} is {why} ({shown}); "
                               "the file is damaged or crafted")


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
               + (f" ({index.total_dropped} dropped while recording)" if index.total_dropped else ""))
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
             "complete": complete, "n_ticks": n, "dropped_ticks": index.total_dropped}
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
        ``metadata`` (dict), ``ticks`` (dict name -> array, see
        :data:`~arsurf.sessions.schema.TICK_FIELDS`; plus ``tube_poses`` (n, k, 3) when the
        session recorded a tube scene),
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
