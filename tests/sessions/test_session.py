"""Session files: writer/reader round trip, atomic writing, reproducible bytes, every bad input."""
from __future__ import annotations

import datetime
import hashlib
import json
import time

import h5py
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from arsurf.contact.maugis_dugdale import MaugisDugdale
from arsurf.errors import ScanFileNotFound, SessionError
from arsurf.force.cantilever import Cantilever
from arsurf.assembly import scan_sha256, session_metadata
from arsurf.sessions.sealed import seal_file
from arsurf.sessions.journal import journal_path
from arsurf.sessions.reader import load_session
from arsurf.sessions.schema import SAFETY_FLAGS, TICK_FIELDS
from arsurf.sessions.writer import SessionWriter
from arsurf.errors import SessionFileNotFound

R = 20e-9
LEVER = Cantilever(450e-6, 50e-6, 2.5e-6, 15e-6, 169e9, 0.27)
MD = MaugisDugdale(R, 50e9, 0.1)
SCAN = {"path": "scans/sinusoid.npz", "sha256": "ab" * 32, "channel": None,
        "processing": {"level": "plane", "sigma": 2e-9, "inpaint": True}}
#: what a writer writes: the fields of every session, and the optional flag word (tube_poses: test_scene)
WRITTEN = (*TICK_FIELDS, SAFETY_FLAGS)
FIELDS = {f.name: f for f in WRITTEN}


def meta(**over):
    kw = dict(scan=SCAN, tip_radius=R, contact=MD, cantilever=LEVER, friction=0.25,
              calibration={"vertical_sensitivity": -1.3e-2, "gains": [1.5, 2.0]},
              haptics={"device": "virtual", "position_scale": 1e-6}, loop_rate=1000.0)
    kw.update(over)
    return session_metadata(**kw)


def write(path, n=5, **over):
    with SessionWriter(path, meta(), **over) as w:
        for k in range(n):
            w.append(t=k * 1e-3, probe_position=(1e-7, 2e-7, 3e-8 - 1e-9 * k), probe_velocity=(1e-6, 0, -1e-6),
                     force=(0.0, 0.0, k * 1e-9), buttons=k % 2, in_contact=int(k > 2), md_status=0)
    return path


def _equal(a, b):
    """Bitwise equality (NaN payloads and signed zeros included)."""
    a = np.ascontiguousarray(a)
    b = np.ascontiguousarray(b)
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


# ---------------------------------------------------------------------------------------------
# round trip


#: fields the reader checks for plausibility (tests/sessions/test_session_integrity.py): their drawn values stay
#: within what it accepts (half the bound per component, or NaN: not given), every other float is arbitrary
PLAUSIBLE = {"probe_position": 1e-2, "tip_position": 1e-2, "contact_point": 1e-2, "instrument_position": 1e-2,
             "stylus_position": 1.0, "device_force": 100.0, "force": 1e6}


def _field_arrays(draw, n, names):
    out = {}
    for name in names:
        f = FIELDS[name]
        shape = (n,) if f.width == 0 else (n, f.width)
        if name == "t":  # strictly increasing, finite
            t = draw(hnp.arrays(np.float64, shape, elements=st.floats(-1e9, 1e9), unique=True))
            out[name] = np.sort(t)
            continue
        if name in PLAUSIBLE:
            b = PLAUSIBLE[name] / 2
            elems = st.floats(-b, b, width=64) | st.just(float("nan"))
        elif f.dtype == "f8":
            elems = st.floats(allow_nan=True, allow_infinity=True, width=64)
        else:
            elems = st.integers(-2**31, 2**31 - 1)
        out[name] = draw(hnp.arrays(np.dtype(f.dtype), shape, elements=elems))
    return out


@st.composite
def recordings(draw):
    n = draw(st.integers(0, 12))
    optional = [f.name for f in WRITTEN if f.name not in ("t", "probe_position")]
    given_names = draw(st.lists(st.sampled_from(optional), unique=True))
    arrays = _field_arrays(draw, n, ["t", "probe_position", *given_names])
    capacity = draw(st.integers(1, 8))
    return n, arrays, capacity


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(rec=recordings())
def test_round_trip_keeps_every_value_bit_for_bit_and_fills_missing_fields(tmp_path, rec):
    n, arrays, capacity = rec
    path = tmp_path / "s.h5"
    with SessionWriter(path, meta(), capacity=capacity, when_full="wait") as w:
        for k in range(n):
            w.append(**{name: a[k] for name, a in arrays.items()})
        assert w.n_ticks == n
    s = load_session(path)
    assert s.n_ticks == n
    assert set(s.ticks) == set(FIELDS)
    for f in WRITTEN:
        got = s.ticks[f.name]
        assert got.dtype == np.dtype(f.dtype)
        assert got.shape == ((n,) if f.width == 0 else (n, f.width))
        if f.name in arrays:
            assert _equal(got, arrays[f.name]), f.name
        else:  # the documented fill value
            want = np.full(got.shape, f.fill, dtype=np.dtype(f.dtype))
            assert _equal(got, want), f.name


@settings(max_examples=25, deadline=None)
@given(x=st.floats(allow_nan=False, allow_infinity=False, min_value=1e-300, max_value=1e300),
       text=st.text(max_size=20))
def test_metadata_free_values_round_trip_exactly(tmp_path_factory, x, text):
    path = tmp_path_factory.mktemp("m") / "s.h5"
    m = meta(calibration={"k": x, "note": text, "nested": {"list": [x, -x, 1, None, True]}})
    with SessionWriter(path, m) as w:
        w.append(t=0.0, probe_position=(0.0, 0.0, 1e-8))
    got = load_session(path).metadata
    assert got == m
    assert got["calibration"]["k"] == x and got["calibration"]["note"] == text


def test_metadata_builds_the_recorded_model_objects_exactly():
    m = meta()
    assert m["cantilever"] == {"length": 450e-6, "width": 50e-6, "thickness": 2.5e-6, "tip_height": 15e-6,
                               "youngs_modulus": 169e9, "poisson_ratio": 0.27,
                               "normal_stiffness": LEVER.normal_stiffness,
                               "torsional_stiffness": LEVER.torsional_stiffness, "beta": LEVER.beta}
    from arsurf import assembly

    tip, md, lever, kwargs, deform = assembly._model_parts(json.loads(json.dumps(m)))
    friction = kwargs["friction"]
    assert kwargs["static_friction"] == friction and kwargs["coupling_stiffness"] == float("inf")
    assert lever == LEVER  # dataclass equality: every field identical after the JSON round trip
    assert md.kernel_args == MD.kernel_args and tip == R and friction == 0.25 and deform is True
    assert m["contact"]["dugdale_stress"] == MD.dugdale_stress


def test_the_friction_law_is_recorded_and_rebuilt_and_old_sessions_keep_theirs():
    """New sessions record the adhesive law (mu (P + |P_c|)); a session without the key was
    recorded when friction acted only under compressive load, and is rebuilt with that law so
    its replay stays bit-identical; the area law needs its shear strength."""
    from arsurf import assembly

    m = meta()
    assert m["friction_law"] == "adhesive" and "shear_strength" not in m
    assert assembly._model_parts(json.loads(json.dumps(m)))[3]["friction_law"] == "adhesive"
    old = {k: v for k, v in m.items() if k != "friction_law"}
    assert assembly._model_parts(old)[3]["friction_law"] == "compressive"
    area = meta(friction_law="area", shear_strength=5e7)
    kwargs = assembly._model_parts(json.loads(json.dumps(area)))[3]
    assert (kwargs["friction_law"], kwargs["shear_strength"]) == ("area", 5e7)
    with pytest.raises(SessionError, match="shear_strength"):
        meta(friction_law="area")
    with pytest.raises(SessionError, match="friction_law"):
        meta(friction_law="viscous")


def test_root_attributes_and_growth(tmp_path):
    path = write(tmp_path / "s.h5", n=37, capacity=1, when_full="wait")
    s = load_session(path)
    assert s.n_ticks == 37
    np.testing.assert_array_equal(s.ticks["t"], np.arange(37) * 1e-3)
    np.testing.assert_array_equal(s.ticks["buttons"], np.arange(37) % 2)
    a = s.attrs
    assert a["format"] == "arsurf-session" and a["format_version"] == 2 and a["units"] == "SI"
    assert a["complete"] is True and a["n_ticks"] == 37 and a["dropped_ticks"] == 0
    assert s.verified and not s.recovered
    import arsurf

    assert a["arsurf_version"] == arsurf.__version__
    created = datetime.datetime.fromisoformat(a["created"])
    assert created.tzinfo is not None
    assert abs((datetime.datetime.now(datetime.timezone.utc) - created).total_seconds()) < 600
    with h5py.File(path) as f:  # no timestamps on any object
        for obj in (f, f["metadata"], f["ticks"], *f["ticks"].values()):
            info = h5py.h5o.get_info(obj.id)
            assert (info.atime, info.mtime, info.ctime, info.btime) == (0, 0, 0, 0)


def test_same_content_and_created_give_identical_bytes(tmp_path):
    a = write(tmp_path / "a.h5", created="2026-01-02T03:04:05+00:00")
    time.sleep(1.1)  # HDF5 timestamps have a resolution of one second
    b = write(tmp_path / "b.h5", created="2026-01-02T03:04:05+00:00")
    assert a.read_bytes() == b.read_bytes()
    c = write(tmp_path / "c.h5")  # only `created` differs
    assert c.read_bytes() != a.read_bytes()
    assert load_session(c).ticks.keys() == load_session(a).ticks.keys()


def test_close_is_atomic_and_leaves_no_part_file(tmp_path, monkeypatch):
    path = write(tmp_path / "s.h5", n=3)
    before = path.read_bytes()
    assert not (tmp_path / "s.h5.part").exists()
    # a failure while writing the new file keeps the old one intact
    w = SessionWriter(path, meta())
    w.append(t=0.0, probe_position=(0, 0, 1e-8))

    def boom(*args, **kwargs):
        raise OSError("disk full (simulated)")

    monkeypatch.setattr(h5py.Group, "create_dataset", boom)
    with pytest.raises(OSError, match="disk full"):
        w.close()
    assert not (tmp_path / "s.h5.part").exists()
    monkeypatch.undo()
    assert path.read_bytes() == before
    assert not (tmp_path / "s.h5.part").exists()
    # the ticks are not lost: the journal is complete, and a second close writes the file
    assert journal_path(path).exists()
    assert load_session(journal_path(path)).n_ticks == 1
    w.close()
    assert load_session(path).n_ticks == 1 and not journal_path(path).exists()


def test_aborted_recording_is_marked_incomplete(tmp_path):
    path = tmp_path / "s.h5"
    with pytest.raises(RuntimeError, match="device lost"):
        with SessionWriter(path, meta()) as w:
            w.append(t=0.0, probe_position=(0, 0, 1e-8))
            w.append(t=1e-3, probe_position=(0, 0, 1e-8))
            raise RuntimeError("device lost")
    with pytest.raises(SessionError, match=r"incomplete .*RuntimeError: device lost.*allow_incomplete=True"):
        load_session(path)
    s = load_session(path, allow_incomplete=True)
    assert s.n_ticks == 2 and s.attrs["complete"] is False


def test_scan_sha256_is_the_hash_of_the_file_bytes(tmp_path, rng):
    p = tmp_path / "scan.bin"
    data = rng.bytes(3 * (1 << 20) + 17)  # more than one read block
    p.write_bytes(data)
    assert scan_sha256(p) == hashlib.sha256(data).hexdigest()
    with pytest.raises(ScanFileNotFound, match="does not exist"):
        scan_sha256(tmp_path / "nope.npz")


def test_session_metadata_hashes_a_scan_path(tmp_path):
    p = tmp_path / "scan.npz"
    p.write_bytes(b"not really a scan, but bytes to hash")
    m = meta(scan=p, level="rows-median", sigma=1e-9, inpaint=False, control_shape=(12, 10), smoothing=0.5)
    assert m["scan"] == {"path": str(p), "sha256": hashlib.sha256(p.read_bytes()).hexdigest(), "channel": None,
                         "processing": {"level": "rows-median", "sigma": 1e-9, "inpaint": False,
                                        "control_shape": [12, 10], "smoothing": 0.5}}


# ---------------------------------------------------------------------------------------------
# bad input: writer


def test_writer_rejects_bad_metadata_before_recording(tmp_path):
    with pytest.raises(SessionError, match="lacks"):
        SessionWriter(tmp_path / "s.h5", {"scan": SCAN})
    with pytest.raises(SessionError, match="valid model.*tip_radius"):
        meta(tip_radius=-1e-9)
    with pytest.raises(SessionError, match="friction must be >= 0"):
        meta(friction=-0.1)
    with pytest.raises(SessionError, match="sha256 must be 64"):
        meta(scan={**SCAN, "sha256": "abc"})
    with pytest.raises(SessionError, match="sigma must be >= 0"):
        meta(scan={**SCAN, "processing": {"level": "plane", "sigma": -1e-9, "inpaint": True}})
    with pytest.raises(SessionError, match="lacks scan.processing.inpaint"):
        meta(scan={**SCAN, "processing": {"level": "plane", "sigma": 0.0}})
    with pytest.raises(SessionError, match="JSON has no NaN"):
        meta(calibration={"gain": float("nan")})
    with pytest.raises(SessionError, match="which JSON cannot hold"):
        meta(calibration={"fn": print})
    with pytest.raises(SessionError, match="unknown arguments"):
        meta(cantilever={"length": 1e-4, "colour": "red"})
    with pytest.raises(SessionError, match="does not exist; create it"):
        SessionWriter(tmp_path / "missing" / "s.h5", meta())
    with pytest.raises(SessionError, match="is a directory"):
        SessionWriter(tmp_path, meta())


def test_append_rejects_bad_ticks_and_keeps_the_row_clean(tmp_path):
    w = SessionWriter(tmp_path / "s.h5", meta())
    with pytest.raises(SessionError, match=r"unknown session field\(s\) \['forse'\]"):
        w.append(t=0.0, probe_position=(0, 0, 0), forse=(1, 2, 3))
    with pytest.raises(SessionError, match="'force' must be 3 numbers per tick"):
        w.append(t=0.0, probe_position=(0, 0, 0), force=(1.0, 2.0))
    with pytest.raises(SessionError, match="needs `t`"):
        w.append(probe_position=(0, 0, 0), force=(1.0, 2.0, 3.0))
    # the failed appends left nothing behind in the row that is now used
    w.append(t=0.5, probe_position=(0, 0, 1e-8))
    assert w.n_ticks == 1
    w.close()
    with pytest.raises(SessionError, match="closed"):
        w.append(t=1.0, probe_position=(0, 0, 1e-8))
    s = load_session(tmp_path / "s.h5")
    assert np.isnan(s.ticks["force"]).all() and s.ticks["t"].tolist() == [0.5]


# ---------------------------------------------------------------------------------------------
# bad input: reader


def test_missing_file_and_directory(tmp_path):
    with pytest.raises(SessionFileNotFound, match="does not exist"):
        load_session(tmp_path / "nope.h5")
    with pytest.raises(SessionError, match="is a directory"):
        load_session(tmp_path)


def test_not_hdf5(tmp_path):
    p = tmp_path / "s.h5"
    p.write_text("t,x,y,z\n0,1,2,3\n")
    with pytest.raises(SessionError, match="not a readable HDF5 session file"):
        load_session(p)


@pytest.mark.parametrize("keep", [0.0, 0.1, 0.5, 0.9, 0.99])
def test_truncated_file(tmp_path, keep):
    good = write(tmp_path / "good.h5", n=200)
    data = good.read_bytes()
    cut = tmp_path / "cut.h5"
    cut.write_bytes(data[: int(len(data) * keep)])
    with pytest.raises(SessionError, match="truncated"):
        load_session(cut)


def _edit(path, fn, reseal=True):
    """Edit a session with h5py, then (by default) seal it again, so only the schema and
    checksum checks behind the seal can catch the edit."""
    with h5py.File(path, "r+") as f:
        fn(f)
    if reseal:
        seal_file(path)
    return path


def test_every_dataset_carries_its_si_unit(tmp_path):
    p = write(tmp_path / "s.h5")
    with h5py.File(p, "r") as f:
        units = {name: f["ticks"][name].attrs["units"] for name in f["ticks"]}
    assert units == {fl.name: fl.unit for fl in WRITTEN}
    assert (units["t"], units["probe_position"], units["force"], units["passivity_damping"]) == ("s", "m", "N", "N s/m")
    assert units["in_contact"] == units["contact_normal"] == "1"
    assert load_session(p).units == units


def test_a_session_written_before_datasets_carried_units_still_loads(tmp_path):
    """format_version 2 files of an older arsurf have no ``units`` attributes: verified, the format's units."""
    p = _edit(write(tmp_path / "s.h5"), lambda f: [f["ticks"][n].attrs.__delitem__("units") for n in f["ticks"]])
    s = load_session(p)
    assert s.verified and s.units == {fl.name: fl.unit for fl in TICK_FIELDS}
    np.testing.assert_array_equal(s.ticks["force"][:, 2], np.arange(5) * 1e-9)


def test_a_dataset_in_another_unit_is_refused(tmp_path):
    p = _edit(write(tmp_path / "s.h5"), lambda f: f["ticks"]["probe_position"].attrs.__setitem__("units", "nm"))
    with pytest.raises(SessionError, match=r"/ticks/probe_position .* is in 'nm', but the format stores it in 'm'"):
        load_session(p)
    q = _edit(write(tmp_path / "q.h5"), lambda f: f["ticks"]["t"].attrs.__setitem__("units", np.arange(3)))
    with pytest.raises(SessionError, match="units attribute that is not a short text"):
        load_session(q)


def test_wrong_format(tmp_path):
    p = _edit(write(tmp_path / "s.h5"), lambda f: f.attrs.__setitem__("format", "netcdf-thing"))
    with pytest.raises(SessionError, match="not an arsurf-session file .*'netcdf-thing'"):
        load_session(p)
    q = tmp_path / "other.h5"
    with h5py.File(q, "w") as f:
        f["x"] = np.arange(3)
    with pytest.raises(SessionError, match="format attribute is None"):
        load_session(q)


@pytest.mark.parametrize("version", [0, 3, 99])
def test_unknown_version(tmp_path, version):
    p = _edit(write(tmp_path / "s.h5"), lambda f: f.attrs.__setitem__("format_version", np.int64(version)))
    with pytest.raises(SessionError, match=rf"format_version {version}.*supported versions: 1, 2"):
        load_session(p)


def test_missing_dataset(tmp_path):
    p = _edit(write(tmp_path / "s.h5"), lambda f: f["ticks"].__delitem__("depth"))
    with pytest.raises(SessionError, match=r"lacks the per-tick dataset\(s\) \['depth'\]"):
        load_session(p)


def test_inconsistent_lengths(tmp_path):
    def shorten(f):
        del f["ticks"]["load"]
        f["ticks"].create_dataset("load", data=np.zeros(3))

    p = _edit(write(tmp_path / "s.h5", n=5), shorten)
    with pytest.raises(SessionError, match="inconsistent.*'load': 3"):
        load_session(p)
    q = _edit(write(tmp_path / "q.h5", n=5), lambda f: f.attrs.__setitem__("n_ticks", np.int64(7)))
    with pytest.raises(SessionError, match="inconsistent: n_ticks=7"):
        load_session(q)


def test_wrong_shape_and_dtype(tmp_path):
    def flat_force(f):
        del f["ticks"]["force"]
        f["ticks"].create_dataset("force", data=np.zeros(5))

    p = _edit(write(tmp_path / "s.h5", n=5), flat_force)
    with pytest.raises(SessionError, match=r"/ticks/force .* shape \(5,\), expected \(n, 3\)"):
        load_session(p)

    def text_buttons(f):
        del f["ticks"]["buttons"]
        f["ticks"].create_dataset("buttons", data=np.zeros(5))

    q = _edit(write(tmp_path / "q.h5", n=5), text_buttons)
    with pytest.raises(SessionError, match="/ticks/buttons .* dtype float64, expected int32"):
        load_session(q)


def test_complete_flag_must_be_true(tmp_path):
    p = _edit(write(tmp_path / "s.h5"), lambda f: f.attrs.__setitem__("complete", np.bool_(False)))
    with pytest.raises(SessionError, match="incomplete"):
        load_session(p)
    q = _edit(write(tmp_path / "q.h5"), lambda f: f.attrs.__delitem__("complete"))
    with pytest.raises(SessionError, match=r"incomplete \(complete=None"):
        load_session(q)


def test_broken_metadata(tmp_path):
    p = _edit(write(tmp_path / "s.h5"), lambda f: f["metadata"].attrs.__setitem__("friction", "{not json"))
    with pytest.raises(SessionError, match="metadata 'friction' .* not valid JSON"):
        load_session(p)
    q = _edit(write(tmp_path / "q.h5"), lambda f: f["metadata"].attrs.__delitem__("cantilever"))
    with pytest.raises(SessionError, match=r"lacks \['cantilever'\]"):
        load_session(q)


# ---------------------------------------------------------------------------------------------
# integrity: seal and checksums


def test_an_edit_without_a_new_seal_is_refused_before_hdf5_reads_it(tmp_path):
    p = _edit(write(tmp_path / "s.h5"), lambda f: f.attrs.__setitem__("n_ticks", np.int64(5)), reseal=False)
    with pytest.raises(SessionError, match="seal"):
        load_session(p)


@pytest.mark.parametrize("target", ["force", "t", "buttons"])
def test_altered_ticks_behind_a_valid_seal_fail_their_checksum(tmp_path, target):
    def alter(f):
        ds = f["ticks"][target]
        a = ds[()]
        a.flat[-1] = a.flat[-1] + 1 if a.dtype.kind == "i" else np.nextafter(np.nan_to_num(a.flat[-1]), 1.0)
        ds[...] = a

    p = _edit(write(tmp_path / "s.h5"), alter)
    with pytest.raises(SessionError, match=rf"/ticks/{target} does not match the SHA-256"):
        load_session(p)


def test_altered_metadata_or_attributes_fail_their_checksum(tmp_path):
    p = _edit(write(tmp_path / "s.h5"), lambda f: f["metadata"].attrs.__setitem__("friction", "0.26"))
    with pytest.raises(SessionError, match="/metadata does not match"):
        load_session(p)
    q = _edit(write(tmp_path / "q.h5"), lambda f: f.attrs.__setitem__("created", "2020-01-01T00:00:00+00:00"))
    with pytest.raises(SessionError, match="root attributes does not match"):
        load_session(q)
    r = _edit(write(tmp_path / "r.h5"), lambda f: f.attrs.__delitem__("checksums"))
    with pytest.raises(SessionError, match="has no checksums although its format_version 2"):
        load_session(r)


def _write_v1(path, n=4):
    """A session exactly as arsurf wrote them before checksums (format_version 1, no seal)."""
    m = meta()
    with h5py.File(path, "w") as f:
        for k, v in {"format": "arsurf-session", "format_version": np.int64(1), "arsurf_version": "0.1.0",
                     "created": "2025-01-01T00:00:00+00:00", "units": "SI", "complete": np.bool_(True),
                     "n_ticks": np.int64(n)}.items():
            f.attrs[k] = v
        mg = f.create_group("metadata")
        for key in sorted(m):
            mg.attrs[key] = json.dumps(m[key], sort_keys=True)
        tg = f.create_group("ticks")
        for fl in TICK_FIELDS:
            shape = (n,) if fl.width == 0 else (n, fl.width)
            data = np.full(shape, fl.fill, dtype=fl.dtype)
            if fl.name == "t":
                data = np.arange(n) * 1e-3
            if fl.name == "probe_position":
                data = np.arange(3 * n, dtype=float).reshape(n, 3) * 1e-9
            tg.create_dataset(fl.name, data=data, compression="gzip", shuffle=True, track_times=False)
    return path


def test_version_1_files_still_load_unverified_in_an_isolated_reader(tmp_path):
    p = _write_v1(tmp_path / "old.h5")
    s = load_session(p)  # isolate="auto": no seal -> child process
    assert s.n_ticks == 4 and s.attrs["format_version"] == 1 and not s.verified
    assert any("isolated" in n for n in s.notes) and any("cannot be verified" in n for n in s.notes)
    np.testing.assert_array_equal(s.ticks["probe_position"], np.arange(12.0).reshape(4, 3) * 1e-9)
    assert np.isnan(s.ticks["force"]).all() and (s.ticks["md_status"] == -99).all()
    assert s.units == {fl.name: fl.unit for fl in TICK_FIELDS}  # no units attributes: the format's
    same = load_session(p, isolate=False)  # trusted: in-process, same answer
    for name in s.ticks:
        assert _equal(s.ticks[name], same.ticks[name]), name
    # a damaged old file is refused by the child, with the child's message
    data = bytearray(p.read_bytes())
    cut = tmp_path / "cut.h5"
    cut.write_bytes(bytes(data[: len(data) // 2]))
    with pytest.raises(SessionError, match="truncated"):
        load_session(cut)


def test_isolation_turns_a_crash_or_a_hang_into_a_session_error():
    from arsurf.errors import IsolatedReadFailure
    from arsurf.sessions.sealed import run_isolated

    with pytest.raises(IsolatedReadFailure, match="crashed the HDF5 library .SIGSEGV."):
        run_isolated("import ctypes; ctypes.string_at(0)", [], timeout=60, memory_limit=None, what="reading x")
    with pytest.raises(IsolatedReadFailure, match="did not finish within 1 s"):
        run_isolated("import time; time.sleep(60)", [], timeout=1, memory_limit=None, what="reading x")
    with pytest.raises(IsolatedReadFailure, match="more than .* bytes of memory"):
        run_isolated("import numpy; numpy.ones(1 << 34)", [], timeout=60, memory_limit=1 << 30, what="reading x")
    with pytest.raises(SessionError, match="^the refusal$"):
        run_isolated("import sys; print('the refusal', file=sys.stderr); sys.exit(3)", [], timeout=60,
                     memory_limit=None, what="reading x")


def test_a_sealed_file_with_a_huge_dataset_claim_is_refused_before_allocating(tmp_path):
    def huge(f):  # every dataset 10^9 rows long, stored in a few kB (no chunk written)
        for fl in WRITTEN:
            del f["ticks"][fl.name]
            shape = (10**9,) if fl.width == 0 else (10**9, fl.width)
            f["ticks"].create_dataset(fl.name, shape=shape, dtype=fl.dtype, chunks=(64, *shape[1:]),
                                      compression="gzip")
        f.attrs["n_ticks"] = np.int64(10**9)

    p = _edit(write(tmp_path / "s.h5"), huge)
    assert p.stat().st_size < 200_000
    with pytest.raises(SessionError, match=r"declares \d+ bytes of data but stores 0"):  # arsurf._h5safe, before any read
        load_session(p)


def test_names_that_are_not_text_are_refused(tmp_path):
    """Found by bench/fuzz_sessions.py: a flipped bit made an attribute name invalid UTF-8, which
    h5py returns as bytes; the checksum step then raised a raw TypeError."""
    p = _edit(write(tmp_path / "s.h5"), lambda f: f.attrs.__setitem__(b"\xffcomplete", 1))
    with pytest.raises(SessionError, match="root attribute whose name is not text"):
        load_session(p)
    q = _edit(write(tmp_path / "q.h5"), lambda f: f["metadata"].attrs.__setitem__(b"\xfe", "1"))
    with pytest.raises(SessionError, match="/metadata key is not text"):
        load_session(q)
