"""Paper figures: every map has a scale bar, nm axes and a colour bar naming its unit, colour limits
equal to the data's 1st/99th percentiles (shared by compared panels), a perceptually uniform colour
map; time series carry their units and the feel/safety flags; PDF and SVG are valid vector files
with the same bytes each time; the functions return Figures. Checked on synthetic inputs and on
every figure the demo writes (headless: matplotlib's Agg canvas)."""
from __future__ import annotations

import re
import xml.etree.ElementTree as ET
import zlib
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("matplotlib", reason="figures need matplotlib (pip install 'arsurf[viewer]')")

from matplotlib.figure import Figure  # noqa: E402
from matplotlib.image import AxesImage  # noqa: E402
from matplotlib.text import Text  # noqa: E402

from arsurf import status  # noqa: E402
from arsurf.errors import FigureError  # noqa: E402
from arsurf.haptics.feel import reversal_ticks, score_force  # noqa: E402
from arsurf.manipulation.nanotube import Nanotube  # noqa: E402
from arsurf.replay import plots  # noqa: E402
from arsurf.spline.surface import BSplineSurface  # noqa: E402

UNIFORM = {"viridis", "magma", "cividis", "inferno", "plasma"}


# -- the checks ------------------------------------------------------------------------------


def check_maps(fig) -> int:
    """Every image axes: nm axes, a scale bar whose label states its length, a uniform colour map,
    colour limits = the percentiles of the images sharing them, a colour bar with the unit."""
    images = [im for ax in fig.axes for im in ax.images if isinstance(im, AxesImage)]
    groups: dict = {}
    for im in images:
        ax = im.axes
        assert ax.get_xlabel() == "x (nm)" and ax.get_ylabel() in ("y (nm)", ""), (ax.get_xlabel(), ax.get_ylabel())
        bars = [a for a in ax.artists if a.get_gid() == "scale_bar"]
        assert len(bars) == 1, "one scale bar per map"
        bar = bars[0]
        text = bar.txt_label._text.get_text()
        value, unit = re.fullmatch(r"([0-9.]+) (nm|µm)", text).groups()
        assert float(value) * (1000.0 if unit == "µm" else 1.0) == pytest.approx(bar.length_nm)
        width = abs(np.diff(ax.get_xlim())[0])
        assert 0.1 * width <= bar.length_nm <= 0.25 * width  # 1-2-5 steps: between a tenth and a quarter
        assert im.get_cmap().name in UNIFORM
        groups.setdefault(tuple(im.get_clim()), []).append(im)
    for clim, ims in groups.items():
        shown = {np.ma.getdata(im.get_array()).tobytes(): np.ma.getdata(im.get_array()) for im in ims}
        data = np.concatenate([z.ravel() for z in shown.values()])  # two views of one map count once
        data = data[np.isfinite(data)]
        assert clim == pytest.approx(tuple(np.percentile(data, plots.PERCENTILES)), rel=1e-12, abs=1e-12)
        bars = [im.colorbar for im in ims if im.colorbar is not None]
        assert len(bars) == 1 and bars[0].ax.get_ylabel() == "height (nm)"
    return len(images)


def check_no_source_titles(fig) -> None:
    for t in fig.findobj(Text):
        assert not re.search(r"seed|Fig\.|cf\.", t.get_text()), t.get_text()


def _pdf_path_ops(data: bytes) -> int:
    assert data.startswith(b"%PDF-") and data.rstrip().endswith(b"%%EOF")
    ops = 0
    for m in re.finditer(rb"stream\r?\n(.*?)\r?\nendstream", data, re.S):
        try:
            body = zlib.decompress(m.group(1))
        except zlib.error:
            continue
        ops += len(re.findall(rb"(?m)[\d.\-]+ [\d.\-]+ l$", body)) + len(re.findall(rb" l\n", body))
    return ops


def _svg_paths(data: bytes) -> int:
    root = ET.fromstring(data)
    assert root.tag.endswith("svg")
    return sum(1 for el in root.iter() if el.tag.endswith("path") and el.get("d", "").strip())


def check_vector(build, tmp_path: Path, name: str) -> None:
    """PDF and SVG of ``build()``: valid, with drawn paths, the same bytes for a second figure
    built from the same data; PNG at the dpi asked."""
    fig = build()
    pdf = plots.save_figure(fig, tmp_path / f"{name}.pdf")
    assert _pdf_path_ops(pdf.read_bytes()) > 20
    svg = plots.save_figure(fig, tmp_path / f"{name}.svg")
    assert _svg_paths(svg.read_bytes()) > 20
    twin = build()  # saved in the same order (each draw re-runs the constrained layout)
    assert plots.save_figure(twin, tmp_path / f"{name}-again.pdf").read_bytes() == pdf.read_bytes()
    again = plots.save_figure(twin, tmp_path / f"{name}-again", format="svg")
    assert again.suffix == ".svg" and again.read_bytes() == svg.read_bytes()
    import matplotlib.image as mpimg

    png = plots.save_figure(fig, tmp_path / f"{name}.png", dpi=300)
    h, w = mpimg.imread(png).shape[:2]
    fw, fh = fig.get_size_inches()
    assert (w, h) == (round(fw * 300), round(fh * 300))


# -- synthetic inputs ------------------------------------------------------------------------


@pytest.fixture(scope="module")
def scene():
    rng = np.random.default_rng(3)
    heights = rng.normal(0.0, 0.3e-9, (100, 120))
    dx = dy = 5e-9
    before = [Nanotube(250e-9, 12e-9, x=300e-9, y=250e-9, angle=0.4), Nanotube(150e-9, 12e-9, x=150e-9, y=100e-9)]
    after = [before[0].with_pose(300e-9, 235e-9, 0.3), before[1]]
    n = 400
    k = np.arange(n)
    probe = np.column_stack([200e-9 + 40e-9 * k / n, 180e-9 - 20e-9 * k / n, np.full(n, 20e-9)])
    contact = (k > 100) & (k < 350)
    return dict(heights=heights, dx=dx, dy=dy, before=before, after=after, probe=probe, contact=contact)


def _forces(n=3000, dt=1e-3):
    t = np.arange(n) * dt
    f = np.zeros((n, 3))
    f[:, 2] = np.clip(t - 1.0, 0.0, 1.0) * 5e-3
    f[2000, 0] = 1e-3  # one spike: a reversal at its top
    flags = np.zeros(n, np.int64)
    flags[2500:2510] |= status.SATURATED
    flags[2700] |= status.WATCHDOG
    flags[1100:1103] |= status.PASSIVITY
    return t, f, flags


@pytest.mark.slow
def test_functions_return_figures_that_save_as_vector(scene, tmp_path):
    s = scene
    t, f, word = _forces()
    flags, feel = plots.session_flags(t, f, word, in_contact=t > 1.0)
    builders = {
        "forces": lambda: plots.forces_figure(t, {"recorded": f * 1e-6}, t > 1.0, flags, feel),
        "coupled": lambda: plots.coupled_motion_figure(t, np.zeros((t.size, 3)), f, t > 1.0, flags, feel),
        "path": lambda: plots.path_figure(s["heights"], s["dx"], s["dy"], s["probe"], s["contact"], s["before"],
                                          s["after"], 20e-9),
        "tubes": lambda: plots.tubes_figure(s["heights"], s["dx"], s["dy"], s["before"], s["after"], s["probe"],
                                            s["contact"]),
    }
    for name, build in builders.items():
        fig = build()
        assert isinstance(fig, Figure), name
        check_no_source_titles(fig)
        check_vector(build, tmp_path, name)
    assert check_maps(builders["path"]()) == 2 and check_maps(builders["tubes"]()) == 2


def test_path_is_zoomed_on_where_the_tip_went(scene):
    s = scene
    fig = plots.path_figure(s["heights"], s["dx"], s["dy"], s["probe"], s["contact"], tip_radius=20e-9)
    zoom = fig.axes[1]
    (x0, x1), (y0, y1) = zoom.get_xlim(), zoom.get_ylim()
    p = s["probe"] * 1e9
    assert x0 < p[:, 0].min() and p[:, 0].max() < x1 and y0 < p[:, 1].min() and p[:, 1].max() < y1
    # the 40 x 20 nm path fills a good part of the zoom, a speck in the 600 x 500 nm scan
    assert (x1 - x0) < 0.35 * 600 and np.ptp(p[:, 0]) / (x1 - x0) > 0.2
    box = [a for a in fig.axes[0].patches if type(a).__name__ == "Rectangle"]
    assert len(box) == 1 and box[0].get_width() == pytest.approx(x1 - x0)


def test_tubes_before_and_after_side_by_side_share_colour_limits(scene):
    s = scene
    fig = plots.tubes_figure(s["heights"], s["dx"], s["dy"], s["before"], s["after"])
    a, b = fig.axes[0].images[0], fig.axes[1].images[0]
    assert a.get_clim() == b.get_clim()
    za, zb = np.asarray(a.get_array()), np.asarray(b.get_array())
    assert not np.array_equal(za, zb)  # the tube moved
    # the maps show the tube 12 nm high (true shape) over the +-0.3 nm substrate
    assert 11.0 < za.max() < 13.0 and 11.0 < zb.max() < 13.0
    # centre of the moved tube before: on top of it in (a), beside it in (b)
    extent = a.get_extent()
    ny, nx = za.shape
    ix = int((300.0 - extent[0]) / (extent[1] - extent[0]) * nx)
    iy = int((250.0 - extent[2]) / (extent[3] - extent[2]) * ny)
    assert za[iy, ix] > 10.0 and zb[iy, ix] < 2.0
    with pytest.raises(FigureError, match="same tubes"):
        plots.tubes_figure(s["heights"], s["dx"], s["dy"], s["before"], s["after"][:1])


def test_dent_is_drawn_over_the_topography():
    x = np.linspace(0.0, 200e-9, 41)
    z = 2e-9 * np.sin(x[:, None] / 30e-9) * np.cos(x[None, :] / 40e-9)
    surface = BSplineSurface.from_heights(z, (0.0, 200e-9), (0.0, 200e-9))
    rest = surface.copy()
    ctrl = surface.kernel_arrays()[0]
    ctrl[19:22, 19:22, 2] -= 1.5e-9  # a dent of ~1.5 nm about (100, 100) nm
    fig = plots.dent_figure(surface, rest, (100e-9, 100e-9), 40e-9, contact_radius=6e-9)
    assert isinstance(fig, Figure) and check_maps(fig) == 1
    im = fig.axes[0].images[0]
    shown = np.asarray(im.get_array())
    assert np.ptp(shown) > 2.0  # the topography itself (sine ridges), not the dent only
    contours = [c for c in fig.axes[0].collections if c.get_gid() == "dent_contours"]
    assert len(contours) == 1 and len(contours[0].levels) == 4
    assert 0.0 < min(contours[0].levels) and max(contours[0].levels) < 1.6
    profile = fig.axes[1]
    assert profile.get_xlabel() == "x (nm)" and profile.get_ylabel() == "height (nm)"
    rest_line, dent_line = profile.lines[:2]
    assert (rest_line.get_ydata() - dent_line.get_ydata()).max() == pytest.approx(1.5, abs=0.5)


def test_flags_are_marked_where_they_happened(tmp_path):
    t, f, word = _forces()
    flags, feel = plots.session_flags(t, f, word, in_contact=t > 1.0)
    assert np.flatnonzero(flags["buzz"]).tolist() == [2000]
    assert np.flatnonzero(flags["saturated"]).tolist() == list(range(2500, 2510))
    assert np.flatnonzero(flags["watchdog"]).tolist() == [2700]
    assert np.flatnonzero(flags["passivity"]).tolist() == [1100, 1101, 1102]
    assert feel.buzzes and int(feel.reversals.sum()) == 1
    fig = plots.forces_figure(t, {"recorded": f}, t > 1.0, flags, feel)
    strip = fig.axes[3]
    assert [x.get_text() for x in strip.get_yticklabels()] == [label for _, label in plots.FLAG_ROWS][::-1]
    bars = {c.get_gid(): c for c in strip.collections if (c.get_gid() or "").startswith("flag_")}
    assert sorted(bars) == ["flag_buzz", "flag_passivity", "flag_saturated", "flag_watchdog"]
    x0, _ = bars["flag_watchdog"].get_paths()[0].vertices.min(axis=0)
    assert x0 == pytest.approx(2.7)
    assert "BUZZES" in strip.get_title(loc="left")
    for ax, unit in zip(fig.axes[:3], ("(nN)",) * 3):
        assert ax.get_ylabel().endswith(unit)
    assert fig.axes[-1].get_xlabel() == "time (s)"
    # without the flag word (a session from before it was recorded): "not recorded", passivity from damping
    damping = np.zeros(t.size)
    damping[5] = 1.0
    flags2, _ = plots.session_flags(t, f, None, damping)
    assert flags2["saturated"] is None and flags2["watchdog"] is None and np.flatnonzero(flags2["passivity"]) == [5]
    fig2 = plots.coupled_motion_figure(t, np.zeros((t.size, 3)), f, None, flags2)
    texts = [x.get_text() for x in fig2.axes[4].texts]
    assert texts.count("not recorded") == 2
    assert [ax.get_ylabel() for ax in fig2.axes[:4]] == ["probe z (nm)", "device F$_z$ (mN)", "probe y (nm)",
                                                         "device F$_y$ (mN)"]


def test_reversal_ticks_agree_with_the_feel_score(rng):
    f = np.zeros((3000, 3))
    f[:, 2] = 0.02
    f[:, 0] = 0.004 * rng.standard_normal(3000)
    f[:, 1] = 0.002 * np.sin(np.arange(3000) * 2.1)
    marks = reversal_ticks(f, 1e-3, settle=1.0)
    score = score_force(f, 1e-3, settle=1.0)
    assert not marks[:1001].any()
    assert marks.sum() <= score.reversals.sum() and marks.sum() >= score.reversals.max()


def test_save_and_options_refuse_bad_values(tmp_path):
    fig = plots.forces_figure(np.arange(3.0), {"recorded": np.zeros((3, 3))})
    with pytest.raises(FigureError, match="format must be one of png, pdf, svg"):
        plots.save_figure(fig, tmp_path / "f.jpg")
    for dpi in (0, 49, 1201, 2.5, "x"):
        with pytest.raises(FigureError, match="dpi"):
            plots.save_figure(fig, tmp_path / "f.png", dpi=dpi)
    assert plots.check_figure_options("svg") == plots.DEFAULT_DPI
    assert plots.scale_bar_length(1000.0) == 200.0 and plots.scale_bar_length(0.9) == 0.2
    with pytest.raises(FigureError):
        plots.scale_bar_length(0.0)


def test_cli_flags_are_checked(tmp_path, capsys):
    from arsurf.cli import main

    with pytest.raises(SystemExit) as exc:
        main(["replay", "s.h5", "--scan", "x.npz", "--out", str(tmp_path / "o"), "--dpi", "10"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--dpi" in err[0] and "[50, 1200]" in err[0]
    with pytest.raises(SystemExit) as exc:
        main(["demo", "--out", str(tmp_path / "d"), "--format", "jpg"])
    assert exc.value.code == 2
    assert "--format" in capsys.readouterr().err


# -- every figure the demo writes ------------------------------------------------------------


@pytest.fixture(scope="module")
def demo_figures(tmp_path_factory):
    """Run the demo (4 s: the push has begun) with SVG figures; keep every Figure it saved."""
    from arsurf.demo import run_demo

    saved, given = {}, {}
    real, real_forces = plots.save_figure, plots.forces_figure

    def keep(fig, path, format=None, dpi=plots.DEFAULT_DPI):
        out = real(fig, path, format, dpi)
        saved[out.name] = (fig, out)
        return out

    def forces_given(t, forces, in_contact=None, flags=None, feel=None, **kw):
        given.update(forces=forces, feel=feel, in_contact=in_contact, **kw)
        return real_forces(t, forces, in_contact, flags, feel, **kw)

    mp = pytest.MonkeyPatch()
    mp.setattr(plots, "save_figure", keep)
    mp.setattr(plots, "forces_figure", forces_given)
    try:
        out = tmp_path_factory.mktemp("demo") / "out"
        summary = run_demo(out, seconds=4.0, images=False, figure_format="svg")
    finally:
        mp.undo()
    saved["given"] = given
    return saved, summary, out


@pytest.mark.slow
def test_every_demo_figure_passes_the_checks(demo_figures, tmp_path):
    saved, summary, out = demo_figures
    saved = {k: v for k, v in saved.items() if k != "given"}
    assert sorted(saved) == ["coupled_motion.svg", "dent.svg", "forces.svg", "path.svg", "tubes.svg"]
    assert sorted(p.name for p in (out / "replay").glob("*.svg")) == sorted(saved)
    maps = 0
    for name, (fig, _) in saved.items():
        assert isinstance(fig, Figure)
        check_no_source_titles(fig)
        maps += check_maps(fig)
        assert _svg_paths((out / "replay" / name).read_bytes()) > 20, name  # written, then moved into place
    assert maps == 5  # path (2), tubes (2), dent (1)
    fig, _ = saved["forces.svg"]
    # the loop's safety flags were recorded and drawn: every row is recorded (none says "not recorded")
    strip = fig.axes[3]
    assert "not recorded" not in [x.get_text() for x in strip.texts]
    assert summary["tube"]["end_displacement_m"] > 1e-9


def test_the_feel_in_both_summaries_is_the_one_drawn(demo_figures):
    """One score, one window: the demo's summary.json, the replay's and the strip of forces.svg."""
    import json

    from arsurf.units import summary_json

    saved, summary, out = demo_figures
    feel = saved["given"]["feel"]
    drawn = json.loads(summary_json(feel.as_dict()))
    assert summary["feel"] == drawn
    assert json.loads((out / "replay" / "summary.json").read_text())["feel"] == drawn
    first_contact = np.flatnonzero(saved["given"]["in_contact"])[0] * 1e-3
    assert feel.start == pytest.approx(first_contact) and feel.window == pytest.approx(4.0 - first_contact)
    strip = saved["forces.svg"][0].axes[3]
    assert f"feel ({feel.window:.2f} s scored)" in strip.get_title(loc="left")
    assert "ticks_with_tube_force" in summary["tube"]  # the demo's count: ticks with a tube reaction


def test_forces_figure_explains_its_curves_and_the_tube_reaction(demo_figures):
    """The recorded force is the loop's: the blend of measured and simulated, low-pass filtered, plus
    the tubes' reaction. Drawn with the replayed reaction, recorded - simulated - tube is small
    where the tube pushes back, though recorded - simulated is not; the caption says so."""
    saved, summary, out = demo_figures
    given = saved["given"]
    tube = np.asarray(given["forces"]["tube"])
    recorded, simulated = np.asarray(given["forces"]["recorded"]), np.asarray(given["forces"]["simulated"])
    pushing = np.linalg.norm(tube, axis=1) > 2e-9
    assert pushing.sum() > 100 and given["tube_contact"][pushing].all()
    gap = np.linalg.norm(recorded - simulated, axis=1)[pushing]
    rest = np.linalg.norm(recorded - simulated - tube, axis=1)[pushing]
    assert np.median(rest) < 0.25 * np.median(gap)
    fig = saved["forces.svg"][0]
    caption = fig._supxlabel.get_text()
    for name in ("recorded:", "simulated:", "measured:", "tube reaction:", "shading: grey"):
        assert name in caption
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    only_tube = bool((given["tube_contact"] & ~np.asarray(given["in_contact"], bool)).any())
    assert labels == ["contact"] + ["tube contact only"] * only_tube + ["recorded", "simulated", "measured",
                                                                         "tube reaction"]
    assert fig.get_size_inches()[0] == pytest.approx(7.0)  # a two-column page's width
