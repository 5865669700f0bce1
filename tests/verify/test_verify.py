"""arsurf verify: the drift and the pushed tubes' poses recovered on virtual-instrument sessions
against the truth the instrument knows, a wrong model flagged, bad inputs refused in one line,
the next scene written and read back."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy.ndimage import fourier_shift, gaussian_filter

from arsurf.errors import VerifyError
from arsurf.scan.io import load_scan, save_scan
from arsurf.scan.scan import Scan
from arsurf.verify.register import phase_shift, register
from arsurf.verify.virtual import Case, run_experiment, true_map_error

pytestmark = pytest.mark.timeout(300)

#: the seeded table: pushes (end, middle, near the other end), drifts, noise levels, tip radii
TABLE = [
    Case(seed=3, tip_radius=8e-9, drift_rate=0.05e-9, noise=0.1e-9, push_at=0.85, push=40e-9),
    Case(seed=4, tip_radius=20e-9, drift_rate=0.12e-9, noise=0.3e-9, push_at=0.15, push=30e-9),
    Case(seed=5, tip_radius=12e-9, drift_rate=0.08e-9, noise=0.2e-9, push_at=0.5, push=40e-9),
    Case(seed=6, tip_radius=10e-9, drift_rate=0.1e-9, noise=0.2e-9, push_at=0.8, push=40e-9, wrong="pivot"),
]


@pytest.fixture(scope="module")
def experiments(tmp_path_factory):
    from arsurf.verify.verify import verify_session

    out = []
    for case in TABLE:
        d = tmp_path_factory.mktemp(f"case{case.seed}")
        e = run_experiment(case, d)
        out.append((e, verify_session(e.session, e.after)))
    return out


@pytest.mark.parametrize("row", range(len(TABLE)))
def test_drift_and_poses_are_recovered_within_the_issue_tolerances(experiments, row):
    e, r = experiments[row]
    dx = r.dx
    assert true_map_error(r.registration.affine, e.true_affine, (96, 96)) < 0.2  # pixels, worst corner
    assert np.abs(r.registration.shift_px).max() > 0.3 or row == 0  # the drift was there to find
    for c in r.checks:
        truth = e.true_poses[c.index]
        assert c.found is not None
        assert math.hypot(c.found.x - truth[0], c.found.y - truth[1]) < 1.0 * dx
        assert abs((c.found.angle - truth[2] + math.pi / 2) % math.pi - math.pi / 2) < math.radians(1.0)
    pushed = r.checks[e.pushed]
    assert pushed.moved and not r.checks[1 - e.pushed].moved


def test_a_wrong_model_is_flagged_and_a_right_one_is_not(experiments):
    for e, r in experiments:
        wrong = e.case.wrong == "pivot"
        assert r.wrong == wrong, r.reasons
        if wrong:  # the model translated what truly turned
            model_turn = e.model_poses[e.pushed, 2]
            assert abs(r.checks[e.pushed].angle_error) > math.radians(5.0)
            assert any("turned" in reason for reason in r.reasons)
            assert np.isfinite(model_turn)


def test_the_wrong_model_fails_the_test_without_the_flag(experiments):
    """The flag is what fails: with thresholds as loose as the error, nothing is flagged."""
    from arsurf.verify.compare import model_wrong

    e, r = experiments[-1]
    c = r.checks[e.pushed]
    assert model_wrong(r.checks, r.dx, c.position_error * 1.01, abs(c.angle_error) * 1.01)[0] is False
    assert model_wrong(r.checks, r.dx)[0] is True


def test_the_cli_writes_the_report_the_figure_and_the_next_scene(experiments, tmp_path, capsys):
    from arsurf.cli import main
    from arsurf.manipulation.scene import TubeScene

    e, _ = experiments[-1]
    rc = main(["verify", str(e.session), str(e.after), "--out", str(tmp_path / "v"), "--reseed",
               str(tmp_path / "next.npz"), "--dpi", "60"])
    out = capsys.readouterr().out
    assert rc == 1 and "model WRONG" in out  # flagged: exit status 1
    report = json.loads((tmp_path / "v" / "verify.json").read_text())
    assert report["model_wrong"] is True and report["registration"]["drift_x_nm"] == pytest.approx(
        report["registration"]["drift_x_px"] * report["registration"]["pixel_dx_nm"])
    assert (tmp_path / "v" / "verify.png").stat().st_size > 10_000
    nxt = load_scan(tmp_path / "next.npz")
    scene = TubeScene.from_scan(nxt)
    found = report["found_tubes"]
    assert len(scene) == len(found) == 2
    for t, f in zip(scene.initial, found):
        assert (t.x * 1e9, t.y * 1e9, t.length * 1e9) == pytest.approx((f["x_nm"], f["y_nm"], f["length_nm"]), abs=1e-6)
    assert np.array_equal(nxt.heights, load_scan(e.after).heights)


def test_a_planted_link_as_the_report_is_never_written_through(experiments, tmp_path, capsys):
    """A second user plants ``verify.json -> victim`` in the output folder: refused, victim intact."""
    import os

    from arsurf.cli import main

    e, _ = experiments[-1]
    out, victim = tmp_path / "v", tmp_path / "victim"
    out.mkdir()
    victim.write_text("precious")
    os.symlink(victim, out / "verify.json")
    rc = main(["verify", str(e.session), str(e.after), "--out", str(out), "--dpi", "60"])
    err = capsys.readouterr().err
    assert rc == 2 and "symbolic link" in err and len(err.strip().splitlines()) == 1
    assert victim.read_text() == "precious"


def test_the_tip_radius_is_estimated_from_the_tubes(experiments):
    from arsurf.verify.tubes import find_tubes

    e, r = experiments[1]  # R = 20 nm
    tubes = find_tubes(load_scan(e.after), None)
    assert tubes[0].tip_radius == pytest.approx(e.case.tip_radius, rel=0.25)
    assert [t.diameter for t in tubes] == pytest.approx(sorted([14e-9, 12e-9], reverse=True), rel=0.15)


# ---------------------------------------------------------------------------------------------
# registration on its own


def test_phase_correlation_finds_a_sub_pixel_shift():
    rng = np.random.default_rng(1)
    a = gaussian_filter(rng.standard_normal((128, 128)), 2.5)
    b = np.fft.ifft2(fourier_shift(np.fft.fft2(a), (0.37, -1.71))).real
    s, peak = phase_shift(a, b, upsample=100)
    assert s == pytest.approx([0.37, -1.71], abs=0.1) and peak > 0.2  # the window's bias; refined below
    r = register(Scan(a * 1e-9, 5e-9, 5e-9), Scan(b * 1e-9, 5e-9, 5e-9))
    assert r.shift_px == pytest.approx([1.71, -0.37], abs=0.01)


def _pair():
    rng = np.random.default_rng(2)
    h = gaussian_filter(rng.standard_normal((64, 64)), 2.0) * 1e-9
    return Scan(h, 5e-9, 5e-9), Scan(np.roll(h, 1, axis=1), 5e-9, 5e-9)


@pytest.mark.parametrize("change, match", [
    (lambda s: Scan(s.heights[:, :60], s.dx, s.dy), "different sizes"),
    (lambda s: Scan(s.heights, 6e-9, s.dy), "different pixel spacings"),
    (lambda s: Scan(s.heights, s.dx, s.dy, channel="Phase"), "different channels"),
    (lambda s: Scan(gaussian_filter(np.random.default_rng(9).standard_normal((64, 64)), 2.0) * 1e-9, s.dx, s.dy),
     "do not (overlap|show the same substrate)"),
])
def test_scans_that_cannot_be_compared_are_one_line(change, match):
    before, after = _pair()
    with pytest.raises(VerifyError, match=match) as info:
        register(before, change(after))
    assert "\n" not in str(info.value)


def test_no_objects_and_no_scene_are_one_line(experiments, tmp_path, capsys):
    from arsurf.cli import main
    from arsurf.verify.tubes import find_tubes

    with pytest.raises(VerifyError, match="no objects found"):
        find_tubes(_pair()[0], 10e-9)
    e, _ = experiments[0]
    flat = load_scan(e.before)
    from arsurf.verify.register import level_substrate

    h, mask = level_substrate(flat)
    empty = flat.with_heights(np.where(mask, np.median(h), h))  # the tubes gone: nothing to find
    save_scan(empty, tmp_path / "empty.npz")
    assert main(["verify", str(e.session), str(tmp_path / "empty.npz")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no objects found" in err[0]
    assert main(["verify", str(e.session), str(e.after), "--before", str(tmp_path / "missing.npz")]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


def test_the_docs_page_code_runs_and_shows_the_flag(capsys):
    """docs/verify.rst's Python block runs as printed."""
    import re
    from pathlib import Path

    text = (Path(__file__).resolve().parents[2] / "docs" / "verify.rst").read_text(encoding="utf-8")
    block = re.search(r"\.\. code-block:: python\n\n((?:    .*\n|\n)+)", text).group(1)
    code = "\n".join(line[4:] for line in block.splitlines())
    exec(compile(code, "docs/verify.rst", "exec"), {})
    assert capsys.readouterr().out.startswith("True [")


def test_the_virtual_afm_images_what_the_session_left_and_the_model_agrees_with_it(experiments, tmp_path):
    """session_sample: the substrate, the model's dent (where the tip pressed, <= 0) and the tubes at
    the model's final poses; the virtual AFM's image of it, checked by verify against the same
    session, agrees with the model (it is the model's own world) and shows the dent."""
    from arsurf.instrument.imaging import ScanSettings, TipShape, acquire
    from arsurf.verify.verify import verify_session
    from arsurf.verify.virtual import session_sample

    e, _ = experiments[0]
    sample = session_sample(e.session)
    assert sample.dent.min() < -0.1e-9 and sample.dent.max() < 0.02 * -sample.dent.min()  # a dent (spline ringing aside)
    iy, ix = np.unravel_index(int(np.argmin(sample.dent)), sample.dent.shape)
    end = load_scan(e.before)
    np.testing.assert_allclose(np.array([o.pose for o in sample.objects]), e.model_poses, rtol=0, atol=1e-15)
    ny, nx = sample.substrate.shape
    st = ScanSettings((nx, ny), (nx * end.dx, ny * end.dy), feedback_bandwidth=1e6)
    image, _ = acquire(sample, st, TipShape(e.case.tip_radius), noise_sigma=0.05e-9, seed=3)
    flat, _ = acquire(type(sample)(sample.substrate, objects=sample.objects), st, TipShape(e.case.tip_radius),
                      noise_sigma=0.05e-9, seed=3)
    seen = (image.heights - flat.heights)[iy, ix]  # the dent is in the image, shallower: the tip, wider than the
    assert sample.dent.min() < seen < -0.01e-9     # dent, cannot reach its bottom (the dilation)
    save_scan(image.with_heights(image.heights, step={"operation": "virtual scan of the session's sample"}),
              tmp_path / "model_world.npz")
    r = verify_session(e.session, tmp_path / "model_world.npz", before_path=e.before)
    assert not r.wrong and max(c.position_error for c in r.checks) < 0.5 * r.dx
    assert np.abs(r.registration.shift_px).max() < 0.1  # no drift in this image
