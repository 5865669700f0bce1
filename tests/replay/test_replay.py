"""Offline replay: a session recorded here (sinusoid scan, press-slide-retract, cantilever signals)
is replayed and must give back the recorded contact states exactly, byte-identical outputs, and
nothing at all when interrupted."""
from __future__ import annotations

import hashlib
import json
import shutil
import struct
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from arsurf.cli import main
from arsurf.scan.prepare import prepare_scan
from arsurf.contact.maugis_dugdale import MaugisDugdale
from arsurf.errors import MissingDependency, RenderingUnavailable, ScanFileNotFound, SessionError
from arsurf.force.cantilever import Cantilever
from arsurf.model import ARModel
from arsurf.replay import plots
from arsurf.replay.replay import REPLAY_FIELDS, load_replay, replay
from arsurf.assembly import session_metadata
from arsurf.sessions.reader import load_session
from arsurf.sessions.schema import contact_fields
from arsurf.sessions.writer import SessionWriter
from arsurf.scan import synthetic
from arsurf.scan.io import save_scan
from arsurf.spline.fit import fit_surface

R = 20e-9
E_STAR, W_ADH = 50e9, 0.1
MU = 0.3
LEVER = Cantilever(450e-6, 50e-6, 2.5e-6, 15e-6, 169e9, 0.27)
N, DT = 240, 1e-3
NO_SIGNALS = 20           # the AFM stream starts after the first 20 ticks
DEVICE_GAIN = 2e6         # N on the stylus per N on the tip (haptic scaling of the recording loop)
DEVICE_LIMIT = 3.0        # N, saturation of the recording loop


def _sinusoid():
    return synthetic.sinusoid(shape=(24, 24), pixel=10e-9, amplitude=3e-9, period=160e-9, angle=0.3)


def _path(surface):
    """Tip centres: press in at (60, 100) nm, slide obliquely to (170, 122) nm, retract."""
    k = np.arange(N)
    s = np.clip((k - 50) / 140.0, 0.0, 1.0)
    x = 60e-9 + 110e-9 * s
    y = 100e-9 + 22e-9 * s
    depth = np.interp(k, [0, 50, 190, N - 1], [-5e-9, 1.5e-9, 1.5e-9, -6e-9])
    z = np.array([surface.evaluate(xi, yi)[2] for xi, yi in zip(x, y)]) + R - depth
    p = np.column_stack([x, y, z])
    return p, np.gradient(p, DT, axis=0)


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """Record a session the way a live loop does, with a model built by hand (not build_model)."""
    d = tmp_path_factory.mktemp("recording")
    scan_path = save_scan(_sinusoid(), d / "scan.npz")
    prepared = prepare_scan(scan_path, None, "plane", 0.0, True)
    loop = ARModel(fit_surface(prepared), R, MaugisDugdale(R, E_STAR, W_ADH), LEVER, friction=MU)
    # the "sample": the same physics, whose force the cantilever turns into the measured angles
    sample = ARModel(fit_surface(prepared), R, MaugisDugdale(R, E_STAR, W_ADH), LEVER, friction=MU, deform=False)
    pos, vel = _path(loop.surface)
    meta = session_metadata(scan=scan_path, tip_radius=R, contact=loop.contact, cantilever=LEVER, friction=MU,
                            level="plane", sigma=0.0, inpaint=True, loop_rate=1.0 / DT,
                            calibration={"vertical_sensitivity": 1.0, "lateral_sensitivity": 1.0},
                            haptics={"device": "virtual", "force_gain": DEVICE_GAIN, "force_limit": DEVICE_LIMIT})
    rec = {k: [] for k in ("truth", "ticks", "force", "signals")}
    with SessionWriter(d / "session.h5", meta) as w:
        for k in range(N):
            truth = sample.step(pos[k]).simulated_force
            signals = LEVER.angles(truth) if k >= NO_SIGNALS else None
            tick = loop.step(pos[k], signals=signals)
            force = tick.measured_force if signals is not None else tick.simulated_force
            device = np.clip(force * DEVICE_GAIN, -DEVICE_LIMIT, DEVICE_LIMIT)
            w.append(t=k * DT, probe_position=pos[k], probe_velocity=vel[k], stylus_position=pos[k] * 1e5,
                     stylus_velocity=vel[k] * 1e5, buttons=1, signals=signals if signals is not None else (np.nan,) * 2,
                     force=force, device_force=device, **contact_fields(tick))
            rec["truth"].append(truth)
            rec["ticks"].append(tick)
            rec["force"].append(force)
            rec["signals"].append(signals is not None)
    return SimpleNamespace(dir=d, scan=scan_path, session=d / "session.h5", meta=meta,
                           truth=np.array(rec["truth"]), ticks=rec["ticks"], force=np.array(rec["force"]),
                           have_signals=np.array(rec["signals"]))


@pytest.fixture(scope="module")
def replayed(recording):
    out = recording.dir / "replay-1"
    result = replay(recording.session, recording.scan, out, progress=False)
    return SimpleNamespace(out=out, result=result, data=load_replay(out / "replay.h5"))


def _files(root: Path) -> dict:
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def _png_chunks(data: bytes) -> list[str]:
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    pos, kinds = 8, []
    while pos < len(data):
        (length,) = struct.unpack(">I", data[pos:pos + 4])
        kinds.append(data[pos + 4:pos + 8].decode("ascii"))
        pos += 12 + length
    return kinds


# ---------------------------------------------------------------------------------------------
# the replay recomputes what the loop computed


def test_replay_recovers_the_recorded_contact_states_exactly(recording, replayed):
    rep = replayed.data.ticks
    ticks = recording.ticks
    for name, attr in (("depth", "depth"), ("load", "load"), ("contact_radius", "contact_radius"),
                       ("md_status", "md_status"), ("distance", "distance")):
        want = np.array([getattr(t, attr) for t in ticks])
        np.testing.assert_array_equal(rep[name], want, err_msg=name)
    np.testing.assert_array_equal(rep["in_contact"], [int(t.in_contact) for t in ticks])
    np.testing.assert_array_equal(rep["contact_point"], [t.point for t in ticks])
    np.testing.assert_array_equal(rep["contact_normal"], [t.normal for t in ticks])
    np.testing.assert_array_equal(rep["simulated_force"], [t.simulated_force for t in ticks])
    # measured force: the decoupled signals where the session has them, NaN elsewhere
    np.testing.assert_array_equal(rep["measured_force"], [t.measured_force for t in ticks])
    assert np.isnan(rep["measured_force"][:NO_SIGNALS]).all()
    np.testing.assert_array_equal(rep["recorded_force"], recording.force)
    r = replayed.result
    assert r.n_ticks == N and r.contact_mismatches == 0 and r.collision_failures == 0
    assert r.depth_difference == 0.0 and r.load_difference == 0.0


def test_the_recorded_session_is_physically_sensible(recording, replayed):
    rep = replayed.data.ticks
    contact = rep["in_contact"] == 1
    assert 100 < contact.sum() < N  # approach and retraction out of contact, the slide in contact
    assert (rep["load"][contact] > 0).mean() > 0.9
    # the decoupling inverts the cantilever forward model where it is well posed
    good = (rep["decoupling_flags"] == 0) & recording.have_signals & contact
    assert good.sum() > 50
    np.testing.assert_allclose(rep["measured_force"][good], recording.truth[good], rtol=1e-8, atol=1e-15)
    # friction opposes the sliding: the lateral simulated force points against the velocity
    sliding = contact & (np.linalg.norm(rep["probe_velocity"][:, :2], axis=1) > 1e-7)
    lateral = np.einsum("ij,ij->i", rep["simulated_force"][sliding, :2], rep["probe_velocity"][sliding, :2])
    assert sliding.sum() > 50 and (lateral < 0).all()
    assert replayed.result.peak_force == pytest.approx(np.linalg.norm(rep["simulated_force"], axis=1).max(), rel=0)


def test_forces_csv_holds_the_h5_values_exactly(replayed):
    text = (replayed.out / "forces.csv").read_text()
    header = text.splitlines()[0].split(",")
    assert header == ["t_s", "F_recorded_x_N", "F_recorded_y_N", "F_recorded_z_N", "F_simulated_x_N",
                      "F_simulated_y_N", "F_simulated_z_N", "F_measured_x_N", "F_measured_y_N", "F_measured_z_N",
                      "depth_m", "contact_radius_m", "load_N", "in_contact"]
    table = np.loadtxt(replayed.out / "forces.csv", delimiter=",", skiprows=1)
    rep = replayed.data.ticks
    want = np.column_stack([rep["t"], rep["recorded_force"], rep["simulated_force"], rep["measured_force"],
                            rep["depth"], rep["contact_radius"], rep["load"], rep["in_contact"]])
    assert table.shape == (N, 14)
    np.testing.assert_array_equal(table, want)  # repr round trip: exact, NaN where absent


def test_replay_h5_schema_and_summary(recording, replayed):
    d = replayed.data
    assert d.attrs["format"] == "arsurf-replay" and d.attrs["format_version"] == 1
    assert "created" not in d.attrs
    assert d.metadata == recording.meta
    assert set(d.ticks) == {f.name for f in REPLAY_FIELDS}
    summary = json.loads((replayed.out / "summary.json").read_text())
    assert summary["n_ticks"] == N and summary["duration_s"] == pytest.approx((N - 1) * DT)
    assert summary["ticks_with_signals"] == N - NO_SIGNALS
    assert summary["contact_mismatches"] == 0 and summary["depth_difference_m"] == 0.0
    assert summary["peak_force_N"] == replayed.result.peak_force
    units = {f.name: f.unit for f in REPLAY_FIELDS}
    assert d.units == units and units["simulated_force"] == "N" and units["probe_velocity"] == "m/s"
    created = load_session(recording.session).attrs["created"].encode()
    for name, data in _files(replayed.out).items():
        assert created not in data, name


def test_plots_are_pngs_without_text_or_time_chunks(replayed):
    import matplotlib.image as mpimg

    for name in ("forces.png", "coupled_motion.png", "path.png", "dent.png"):
        data = (replayed.out / name).read_bytes()
        kinds = _png_chunks(data)
        assert kinds[0] == "IHDR" and kinds[-1] == "IEND"
        assert not {"tEXt", "iTXt", "zTXt", "tIME"} & set(kinds), (name, kinds)
        img = mpimg.imread(replayed.out / name)
        assert img[..., :3].std() > 0.05, name  # not blank
    # the probe path is drawn in white over the height map
    img = mpimg.imread(replayed.out / "path.png")[..., :3]
    assert (img > 0.99).all(axis=2).sum() > 200


def test_same_input_gives_bit_identical_output(recording, replayed, tmp_path):
    out2 = tmp_path / "replay-2"
    replay(recording.session, recording.scan, out2, progress=False)
    first, second = _files(replayed.out), _files(out2)
    assert sorted(first) == sorted(second) == ["arsurf-manifest.json", "coupled_motion.png", "dent.png",
                                               "forces.csv", "forces.png",
                                               "path.png", "replay.h5", "summary.json"]
    for name in first:
        assert first[name] == second[name], name


# ---------------------------------------------------------------------------------------------
# interruption and overwrite


def _interrupt_after(monkeypatch, n_ticks):
    real = ARModel.tick
    calls = {"n": 0}

    def tick(self, *args, **kwargs):
        calls["n"] += 1
        if calls["n"] > n_ticks:
            raise RuntimeError("power cut (simulated)")
        return real(self, *args, **kwargs)

    monkeypatch.setattr(ARModel, "tick", tick)
    return calls


def test_interrupted_replay_leaves_no_output(recording, tmp_path, monkeypatch):
    calls = _interrupt_after(monkeypatch, N // 2)
    out = tmp_path / "out"
    with pytest.raises(RuntimeError, match="power cut"):
        replay(recording.session, recording.scan, out, progress=False)
    assert calls["n"] == N // 2 + 1  # it did stop midway
    assert list(tmp_path.iterdir()) == []  # no out_dir, no temporary folder


def test_interrupted_overwrite_keeps_the_old_output(recording, replayed, tmp_path, monkeypatch):
    out = tmp_path / "out"
    out.mkdir()
    (out / "old.txt").write_text("previous results")
    before = _files(out)
    _interrupt_after(monkeypatch, 10)
    with pytest.raises(RuntimeError, match="power cut"):
        replay(recording.session, recording.scan, out, progress=False, overwrite=True)
    assert _files(out) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]
    # a failure while writing the outputs (after the loop) is just as clean
    monkeypatch.undo()

    def broken_plot(*args, **kwargs):
        raise OSError("disk full (simulated)")

    monkeypatch.setattr(plots, "path_figure", broken_plot)
    with pytest.raises(OSError, match="disk full"):
        replay(recording.session, recording.scan, out, progress=False, overwrite=True)
    assert _files(out) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_existing_output_needs_overwrite(recording, replayed, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "stale.txt").write_text("x")
    with pytest.raises(SessionError, match="exists; choose another folder or pass overwrite=True"):
        replay(recording.session, recording.scan, out, progress=False)
    assert _files(out) == {"stale.txt": b"x"}
    replay(recording.session, recording.scan, out, progress=False, overwrite=True)
    # the outputs are written; the file arsurf did not write is kept
    assert _files(out) == {**_files(replayed.out), "stale.txt": b"x"}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


@pytest.mark.slow
def test_overwrite_deletes_only_what_its_manifest_lists(recording, replayed, tmp_path):
    """replay --overwrite keeps a user's files: a foreign file, one in a subfolder, one that has
    the name of an output the new run does not write, and refuses to replace a foreign file that
    holds an output's name (before anything changed)."""
    out = tmp_path / "out"
    replay(recording.session, recording.scan, out, progress=False)
    manifest = json.loads((out / "arsurf-manifest.json").read_text())
    assert {e["path"] for e in manifest["files"]} == set(_files(replayed.out)) - {"arsurf-manifest.json"}
    for e in manifest["files"]:
        assert hashlib.sha256((out / e["path"]).read_bytes()).hexdigest() == e["sha256"]
    (out / "notes.txt").write_text("my notes")
    (out / "mine").mkdir()
    (out / "mine" / "data.csv").write_text("1,2")
    (out / "frames").mkdir()
    (out / "frames" / "frame_00000.png").write_bytes(b"my own picture")  # not listed: not arsurf's
    replay(recording.session, recording.scan, out, progress=False, overwrite=True)
    assert (out / "notes.txt").read_text() == "my notes"
    assert (out / "mine" / "data.csv").read_text() == "1,2"
    assert (out / "frames" / "frame_00000.png").read_bytes() == b"my own picture"
    (out / "forces.csv").unlink()
    (out / "forces.csv").write_text("a user's table under an output's name")
    manifest = json.loads((out / "arsurf-manifest.json").read_text())
    manifest["files"] = [e for e in manifest["files"] if e["path"] != "forces.csv"]
    (out / "arsurf-manifest.json").write_text(json.dumps(manifest))
    before = _files(out)
    with pytest.raises(SessionError, match="'forces.csv', which arsurf did not write there"):
        replay(recording.session, recording.scan, out, progress=False, overwrite=True)
    assert _files(out) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


# ---------------------------------------------------------------------------------------------
# bad input


def test_scan_hash_mismatch_names_both_hashes(recording, tmp_path):
    other = _sinusoid()
    other = type(other)(other.heights + 1e-12, dx=other.dx, dy=other.dy)
    wrong = save_scan(other, tmp_path / "other.npz")
    from arsurf.assembly import scan_sha256

    with pytest.raises(SessionError, match=rf"SHA-256 {scan_sha256(wrong)}.*SHA-256 {recording.meta['scan']['sha256']}"):
        replay(recording.session, wrong, tmp_path / "out", progress=False)
    assert not (tmp_path / "out").exists()
    with pytest.raises(ScanFileNotFound, match="does not exist"):
        replay(recording.session, tmp_path / "missing.npz", tmp_path / "out", progress=False)


def _small_session(path, meta, velocities):
    with SessionWriter(path, meta) as w:
        for k, v in enumerate(velocities):
            w.append(t=k * DT, probe_position=(100e-9, 100e-9, 40e-9), probe_velocity=v)
    return path


def test_unreplayable_sessions(recording, tmp_path):
    bad = _small_session(tmp_path / "nan.h5", recording.meta, [(0, 0, 0)] * 3 + [(np.nan, 0, 0)] + [(0, 0, 0)])
    with pytest.raises(SessionError, match=r"probe_velocity is not finite at 1 tick\(s\), first at tick 3"):
        replay(bad, recording.scan, tmp_path / "out", progress=False)
    missing_v = tmp_path / "nov.h5"
    with SessionWriter(missing_v, recording.meta) as w:
        w.append(t=0.0, probe_position=(100e-9, 100e-9, 40e-9))
    with pytest.raises(SessionError, match="probe_velocity is not finite"):
        replay(missing_v, recording.scan, tmp_path / "out", progress=False)
    empty = _small_session(tmp_path / "empty.h5", recording.meta, [])
    with pytest.raises(SessionError, match="no ticks"):
        replay(empty, recording.scan, tmp_path / "out", progress=False)
    truncated = tmp_path / "cut.h5"
    truncated.write_bytes(recording.session.read_bytes()[:5000])
    with pytest.raises(SessionError, match="truncated"):
        replay(truncated, recording.scan, tmp_path / "out", progress=False)
    with pytest.raises(SessionError, match="frames` must be >= 0"):
        replay(recording.session, recording.scan, tmp_path / "out", frames=-1)
    assert not (tmp_path / "out").exists()


# ---------------------------------------------------------------------------------------------
# frames, progress and the command line


def test_frames_without_the_viewer_are_refused_before_any_work(recording, tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "arsurf_viewer", None)  # import fails
    with pytest.raises(MissingDependency, match=r"replay frames need the viewer.*pip install 'arsurf\[viewer\]'"):
        replay(recording.session, recording.scan, tmp_path / "out", frames=3, progress=True)
    assert not (tmp_path / "out").exists() and list(tmp_path.iterdir()) == []
    assert replay(recording.session, recording.scan, tmp_path / "out", frames=0, progress=False).frames == 0
    # the command line: exit status 2, one line on stderr, nothing written
    assert main(["replay", str(recording.session), "--scan", str(recording.scan), "--out", str(tmp_path / "cli"),
                 "--frames", "2"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "arsurf[viewer]" in err[0] and not (tmp_path / "cli").exists()


@pytest.mark.slow
@pytest.mark.viewer
def test_frames_render_offscreen_and_are_reproducible(recording, tmp_path):
    viewer = pytest.importorskip("arsurf_viewer")
    probe = viewer.probe()
    if not probe.ok:
        pytest.skip(f"no OpenGL context: {probe.detail}")
    import matplotlib.image as mpimg

    runs = [replay(recording.session, recording.scan, tmp_path / f"out{i}", frames=2, frame_size=(160, 120),
                   progress=False) for i in range(2)]
    assert all(r.frames == 2 and not r.notes for r in runs)
    a, b = _files(tmp_path / "out0"), _files(tmp_path / "out1")
    assert [n for n in a if n.startswith("frames/")] == ["frames/frame_00000.png", "frames/frame_00001.png"]
    assert a == b
    img = mpimg.imread(tmp_path / "out0" / "frames" / "frame_00001.png")
    assert img.shape[:2] == (120, 160) and img[..., :3].std() > 0.02


def test_command_line(recording, replayed, tmp_path, capsys):
    out = tmp_path / "cli"
    assert main(["replay", str(recording.session), "--scan", str(recording.scan), "--out", str(out)]) == 0
    captured = capsys.readouterr()
    assert f"replayed {N} ticks" in captured.out and "forces.csv" in captured.out
    assert captured.err == ""  # no bar (stderr is not a terminal: tests/foundation/test_logging.py) and no note
    assert _files(out) == _files(replayed.out)
    # an existing folder, then a wrong scan: exit status 2 and a message
    assert main(["replay", str(recording.session), "--scan", str(recording.scan), "--out", str(out), "--quiet"]) == 2
    assert "exists" in capsys.readouterr().err
    assert main(["replay", str(recording.session), "--scan", str(recording.session), "--out",
                 str(tmp_path / "x"), "--quiet"]) == 2
    captured = capsys.readouterr()
    assert "SHA-256" in captured.err and captured.out == ""


def test_a_failing_renderer_stops_the_replay_saying_what_to_install(recording, tmp_path, monkeypatch, capsys):
    seen = []

    def render_frames(states, out_dir, **kwargs):
        Path(out_dir).mkdir(parents=True)
        (Path(out_dir) / "frame_00000.png").write_bytes(b"half a frame")
        seen.append(next(iter(states)))
        raise RuntimeError("OpenGL context lost")

    fake = SimpleNamespace(SceneState=lambda *args, **kwargs: (args, kwargs), render_frames=render_frames)
    monkeypatch.setitem(sys.modules, "arsurf_viewer", fake)
    with pytest.raises(RenderingUnavailable, match=r"replay frames: rendering failed \(RuntimeError: OpenGL context "
                       r"lost\); install EGL .*libegl1.* or OSMesa .*libosmesa6"):
        replay(recording.session, recording.scan, tmp_path / "out", frames=4, progress=False)
    assert len(seen) == 1 and seen[0][1]["time"] == 0.0  # the first frame is tick 0
    assert list(tmp_path.iterdir()) == []  # no output folder, no half frame, no temporary folder
    assert main(["replay", str(recording.session), "--scan", str(recording.scan), "--out", str(tmp_path / "cli"),
                 "--frames", "2"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "install EGL" in err[0] and not (tmp_path / "cli").exists()

    # an error inside the model loop is not mistaken for a rendering problem
    def render_all(states, out_dir, **kwargs):
        return SimpleNamespace(paths=list(states))

    fake.render_frames = render_all
    _interrupt_after(monkeypatch, 30)
    with pytest.raises(RuntimeError, match="power cut"):
        replay(recording.session, recording.scan, tmp_path / "out2", frames=4, progress=False)
    assert not (tmp_path / "out2").exists()


@pytest.mark.slow
def test_cli_writes_the_figures_as_pdf_or_svg(recording, tmp_path):
    """--format pdf: the same figures as vector PDFs (no PNG); --format svg --dpi: SVG XML."""
    import xml.etree.ElementTree as ET

    out = tmp_path / "pdf"
    assert main(["-q", "replay", str(recording.session), "--scan", str(recording.scan), "--out", str(out),
                 "--format", "pdf"]) == 0
    names = sorted(p.name for p in out.iterdir() if p.suffix in (".pdf", ".png", ".svg"))
    assert names == ["coupled_motion.pdf", "dent.pdf", "forces.pdf", "path.pdf"]
    for name in names:
        data = (out / name).read_bytes()
        assert data.startswith(b"%PDF-") and data.rstrip().endswith(b"%%EOF") and len(data) > 5000, name
    out = tmp_path / "svg"
    assert main(["-q", "replay", str(recording.session), "--scan", str(recording.scan), "--out", str(out),
                 "--format", "svg", "--dpi", "300"]) == 0
    for name in ("coupled_motion.svg", "dent.svg", "forces.svg", "path.svg"):
        assert ET.fromstring((out / name).read_bytes()).tag.endswith("svg"), name


# ---------------------------------------------------------------------------------------------
# notebook display (arsurf.sessions.display)


def _display_rows(text: str) -> dict[str, str]:
    import html
    import re

    return {html.unescape(k): html.unescape(v)
            for k, v in re.findall(r"<th[^>]*>(.*?)</th><td[^>]*>(.*?)</td>", text)}


def test_a_session_shows_what_it_recorded(recording):
    s = load_session(recording.session)
    rows = _display_rows(s._repr_html_())
    assert rows["ticks"] == f"{N} over 239 ms at 1 kHz"
    assert rows["status"] == "complete, checksums verified"
    assert rows["tip radius"] == "20 nm" and rows["contact"] == "E* 50 GPa, w 0.1 J/m^2"
    assert rows["ticks in contact"] == str(int(s.ticks["in_contact"].sum())) != "0"
    peak = np.linalg.norm(recording.force, axis=1).max()
    assert rows["peak force on the tip"] == f"{peak * 1e9:.4g} nN"
    assert rows["scan"].startswith(str(recording.scan))
    import base64

    png = s._repr_png_()
    assert _png_chunks(png)[0] == "IHDR"
    assert base64.b64encode(png).decode() in s._repr_html_()  # the same thumbnail, inline


def test_a_session_without_forces_has_no_thumbnail(tmp_path, recording):
    meta = dict(recording.meta)
    with SessionWriter(tmp_path / "s.h5", meta) as w:
        for k in range(5):
            w.append(t=k * DT, probe_position=(1e-7, 1e-7, 3e-8))
    s = load_session(tmp_path / "s.h5")
    assert s._repr_png_() is None
    html = s._repr_html_()
    assert "<img" not in html and _display_rows(html)["peak force on the tip"] == "n/a"


def test_a_replay_result_shows_its_peaks_and_a_force_thumbnail(replayed):
    r = replayed.result
    rows = _display_rows(r._repr_html_())
    assert rows["ticks"] == str(N) and rows["peak force (model)"] == f"{r.peak_force * 1e9:.4g} nN"
    assert rows["max depth"] == f"{r.max_depth * 1e9:.4g} nm"
    assert rows["contact-state mismatches"] == "0" and rows["vs recording: depth"] == "0 m"
    assert rows["files"].startswith("7: coupled_motion.png, dent.png, forces.csv")
    import matplotlib.image as mpimg
    import io

    img = mpimg.imread(io.BytesIO(r._repr_png_()), format="png")
    assert img.shape[:2] == (216, 288) and img[..., :3].std() > 0.05


def test_a_replay_result_whose_folder_is_gone_still_shows_its_numbers(replayed, tmp_path):
    import dataclasses

    gone = dataclasses.replace(replayed.result, out_dir=tmp_path / "nowhere")
    assert gone._repr_png_() is None
    assert "<img" not in gone._repr_html_() and "nowhere" in gone._repr_html_()
    damaged = tmp_path / "damaged"
    damaged.mkdir()
    (damaged / "replay.h5").write_bytes(b"not an HDF5 file")
    assert dataclasses.replace(replayed.result, out_dir=damaged)._repr_png_() is None


@pytest.mark.slow
def test_the_scan_defaults_to_the_one_the_session_names(recording, replayed, tmp_path, monkeypatch, capsys):
    """#30: ``arsurf replay SESSION --out DIR`` without ``--scan`` takes the scan the session records
    (absolute, or relative from here or the session's folder), refusing it on a hash mismatch as with --scan."""
    out = tmp_path / "cli"
    assert main(["replay", str(recording.session), "--out", str(out)]) == 0
    assert _files(out) == _files(replayed.out)
    # a session that names its scan relatively, replayed from another folder: found beside the session
    d = tmp_path / "moved"
    d.mkdir()
    shutil.copyfile(recording.scan, d / "scan.npz")
    meta = {**recording.meta, "scan": {**recording.meta["scan"], "path": "scan.npz"}}
    session = _small_session(d / "s.h5", meta, [(0, 0, 0)] * 3)
    monkeypatch.chdir(tmp_path)
    assert replay(session, None, tmp_path / "r1", progress=False).n_ticks == 3
    (d / "scan.npz").write_bytes((d / "scan.npz").read_bytes() + b"\0")  # another file under that name
    assert main(["replay", str(session), "--out", str(tmp_path / "r2"), "-q"]) == 2
    assert "SHA-256" in capsys.readouterr().err and not (tmp_path / "r2").exists()
    (d / "scan.npz").unlink()
    assert main(["replay", str(session), "--out", str(tmp_path / "r3"), "-q"]) == 2
    assert "pass the scan with --scan" in capsys.readouterr().err
