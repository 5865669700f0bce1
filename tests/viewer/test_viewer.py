"""The viewer (arsurf_viewer): offscreen pictures checked pixel by pixel.

Rendering tests are marked ``viewer`` and skip only when no OpenGL context can be made here
(arsurf_viewer.backend.probe renders a sphere in a child process and says why not).
"""
from __future__ import annotations

import logging

import math
import subprocess
import sys

import numpy as np
import pytest

from arsurf.spline.surface import BSplineSurface
from arsurf_viewer.interactive import LAYER_SETS, StylusController, scripted_path
from arsurf_viewer.state import SceneState, Tube
from arsurf.errors import ViewerError

R = 12e-9  # tip radius
SIZE = (320, 240)  # small windows: llvmpipe renders them in a few ms


def sinusoid_surface(n=24, length=200e-9, amp=3e-9):
    x = np.linspace(0.0, length, n)
    z = amp * np.sin(2 * np.pi * x[:, None] / (0.6 * length)) * np.cos(2 * np.pi * x[None, :] / length)
    return BSplineSurface.from_heights(z, (0.0, length), (0.0, length))


def push_down(surface, x, y, depth, radius):
    """Dent the net as the deformation module does: only control points within ``radius`` of
    (x, y) move (a compact bump, so the patch the view re-samples is local)."""
    ctrl = surface.kernel_arrays()[0]
    d2 = (ctrl[..., 0] - x) ** 2 + (ctrl[..., 1] - y) ** 2
    ctrl[..., 2] -= depth * np.clip(1.0 - d2 / radius**2, 0.0, None) ** 2


def above(surface, x, y, gap):
    return np.array([x, y, float(surface.evaluate(x, y)[2]) + R + gap])


# -- colour classes (the view's colours are chosen to be separable from 'magma') ----------------
def blue(img):
    """The force arrow: magma's blue never exceeds its red by more than ~55 levels."""
    r, g, b = (img[..., k].astype(int) for k in range(3))
    return (b > r + 80) & (b > g + 50)


def green(img):
    r, g, b = (img[..., k].astype(int) for k in range(3))
    return (g > r + 40) & (g > b + 40)


def changed(a, b, threshold=24):
    return np.abs(a.astype(int) - b.astype(int)).sum(axis=2) > threshold


# -- no OpenGL needed ------------------------------------------------------------------------
def test_engine_and_state_do_not_import_pyvista():
    code = ("import sys, arsurf, arsurf.export, arsurf.meshes; import arsurf_viewer.state; "
            "print('pyvista' in sys.modules or 'vtk' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_scene_state_validates_and_normalises():
    s = sinusoid_surface()
    st = SceneState(s, (1e-8, 2e-8, 3e-8), R, contact_normal=(0, 0, 5), force=(3e-9, 4e-9, 0),
                    tubes=[((0, 0, 0), (2, 0, 0), 1e-7, 5e-9)])
    np.testing.assert_array_equal(st.contact_normal, [0, 0, 1])
    assert st.force_magnitude == pytest.approx(5e-9)
    assert isinstance(st.tubes[0], Tube) and st.tubes[0].axis.tolist() == [1.0, 0.0, 0.0]
    assert math.isnan(st.maugis_lambda)
    for kwargs, match in [
        (dict(tip_center=(1, 2)), "tip_center.*(3,)"),
        (dict(tip_center=(0, 0, np.nan)), "tip_center.*finite"),
        (dict(tip_radius=-1e-9), "tip_radius.*positive"),
        (dict(contact_normal=(0, 0, 0)), "contact_normal.*non-zero"),
        (dict(contact_radius=-1e-9), "contact_radius.*non-negative"),
        (dict(tubes=[(0, 0, 0)]), "a tube must be"),
    ]:
        args = dict(tip_center=(0, 0, 0), tip_radius=R) | kwargs
        with pytest.raises(ViewerError, match=match):
            SceneState(s, **args)
    with pytest.raises(ViewerError, match="BSplineSurface"):
        SceneState(np.zeros((3, 3)), (0, 0, 0), R)


def test_scene_state_from_a_contact_record():
    class Contact:  # duck-typed like arsurf.contact.projection.Contact
        point = np.array([1e-8, 1e-8, 0.0])
        normal = np.array([0.0, 0.0, 1.0])
        depth = 2e-9

    st = SceneState.from_contact(sinusoid_surface(), (1e-8, 1e-8, 1e-8), R, Contact(), contact_radius=4e-9)
    assert st.depth == 2e-9 and st.contact_point.tolist() == [1e-8, 1e-8, 0.0] and st.contact_radius == 4e-9


def test_stylus_keys_move_reset_and_pause():
    s = sinusoid_surface()
    released = []
    ctl = StylusController(s, (1e-7, 1e-7, 2e-8), step=2e-9, z_step=5e-10, on_reset=lambda: released.append(1))
    for key in ("Right", "Right", "Up", "Prior", "Next", "Next"):
        ctl.handle_key(key)
    np.testing.assert_allclose(ctl.tip_center, [1.04e-7, 1.02e-7, 1.95e-8], rtol=1e-12)
    ctl.handle_key("bracketleft")
    ctl.handle_key("Left")
    assert ctl.tip_center[0] == pytest.approx(1.03e-7)
    push_down(s, 1e-7, 1e-7, 3e-9, 2e-8)
    assert s.is_deformed
    assert ctl.handle_key("r") == "surface reset" and not s.is_deformed and released == [1]
    assert ctl.handle_key("p") == "paused" and ctl.paused
    assert ctl.handle_key("p") == "running" and not ctl.paused
    assert ctl.handle_key("q") == "quit" and ctl.quit
    with pytest.raises(ViewerError, match="steps must be positive"):
        StylusController(s, (0, 0, 0), step=-1.0)


def test_scripted_path_approaches_indents_and_retracts():
    s = sinusoid_surface()
    path = scripted_path(s, R, frames=40, indent=3e-9)
    gap = path[:, 2] - s.evaluate(path[:, 0], path[:, 1])[:, 2] - R  # > 0 above, < 0 indenting
    assert gap[0] == pytest.approx(1.5 * R) and gap[-1] == pytest.approx(1.5 * R)
    assert gap.min() == pytest.approx(-3e-9)
    assert np.ptp(path[:, 0]) == pytest.approx(0.2 * 200e-9)  # the slide
    with pytest.raises(ViewerError, match="frames"):
        scripted_path(s, R, frames=2)


def test_backend_choice_errors_name_the_way_out(monkeypatch):
    from arsurf_viewer import backend

    with pytest.raises(backend.RenderingUnavailable, match="'bogus' is not a backend; use one of native, x11, egl"):
        backend._choose.__wrapped__("bogus")
    monkeypatch.setattr(backend, "_candidates", lambda: [])
    with pytest.raises(backend.RenderingUnavailable, match="no OpenGL context.*libegl1 libegl-mesa0 libgl1-mesa-dri"):
        backend._choose.__wrapped__(None)


# -- rendering -------------------------------------------------------------------------------
def make_view(surface, **kw):
    from arsurf_viewer import SurfaceView

    kw.setdefault("window_size", SIZE)
    kw.setdefault("off_screen", True)
    kw.setdefault("anti_aliasing", None)
    return SurfaceView(surface, **kw)


@pytest.mark.viewer
def test_picture_is_not_blank_and_hud_reads_the_state(gl, tmp_path):
    s = sinusoid_surface()
    view = make_view(s)
    try:
        st = SceneState(s, above(s, 1e-7, 1e-7, -1e-9), R, depth=1e-9, contact_radius=3.5e-9,
                        force=(1e-9, -2e-9, 4e-9), maugis_lambda=0.82, loop_rate_hz=1000.0,
                        device_status="virtual ok", time=1.5)
        view.update(st)
        img = view.screenshot(tmp_path / "frame.png")
        assert img.shape == (SIZE[1], SIZE[0], 3) and img.dtype == np.uint8
        colours = np.unique(img.reshape(-1, 3), axis=0)
        assert len(colours) > 500  # shaded surface, gradient background, text
        r, g, b = (img[..., k].astype(int) for k in range(3))
        coloured = np.max([r, g, b], axis=0) - np.min([r, g, b], axis=0) > 40  # the background is grey
        assert coloured.mean() > 0.2  # the surface fills a good part of the frame
        import imageio.v3 as iio

        np.testing.assert_array_equal(iio.imread(tmp_path / "frame.png")[..., :3], img)
        text = view.hud_actor.GetInput()
        for piece in ("+1.000", "-2.000", "+4.000", "|F|   4.583", "+1.00 nm", "3.50 nm", "0.820", "1000 Hz",
                      "1.500 s", "device: virtual ok"):
            assert piece in text, (piece, text)
        with pytest.raises(ViewerError, match="PNG"):
            view.screenshot(tmp_path / "frame.jpg")
    finally:
        view.close()


@pytest.mark.viewer
def test_tip_is_where_the_camera_puts_it(gl):
    s = sinusoid_surface()
    view = make_view(s, camera="top", tip_opacity=1.0)
    try:
        w, h = SIZE
        cam = view.plotter.camera
        for x, y in ((60e-9, 130e-9), (140e-9, 50e-9)):
            c = above(s, x, y, 8e-9)
            view.set_layer("tip", True)
            view.update(SceneState(s, c, R))
            with_tip = view.screenshot()
            view.set_layer("tip", False)
            without = view.screenshot()
            mask = changed(with_tip, without)
            rows, cols = np.nonzero(mask)
            # independent reference: top-down parallel projection, nm scene, pixel centres at +0.5
            scale = (h / 2) / cam.parallel_scale  # pixels per nm
            fx, fy, _ = cam.focal_point
            expected = (h / 2 - (c[1] * 1e9 - fy) * scale - 0.5, w / 2 + (c[0] * 1e9 - fx) * scale - 0.5)
            assert rows.mean() == pytest.approx(expected[0], abs=0.75)
            assert cols.mean() == pytest.approx(expected[1], abs=0.75)
            # the silhouette of a sphere seen from above is a disc of radius R
            assert math.sqrt(mask.sum() / math.pi) == pytest.approx(R * 1e9 * scale, abs=1.0)
            np.testing.assert_allclose(view.world_to_pixel(c), expected, atol=0.05)
    finally:
        view.close()


@pytest.mark.viewer
def test_tip_projection_in_perspective(gl):
    s = sinusoid_surface()
    view = make_view(s, camera="oblique", tip_opacity=1.0, layers={"hud": False, "colorbar": False})
    try:
        c = above(s, 80e-9, 120e-9, 5e-9)
        view.update(SceneState(s, c, R))
        a = view.screenshot()
        view.set_layer("tip", False)
        mask = changed(a, view.screenshot())
        rows, cols = np.nonzero(mask)
        row, col = view.world_to_pixel(c)
        # the centroid of a sphere's perspective image sits within a pixel of its centre's projection
        assert rows.mean() == pytest.approx(row, abs=1.0) and cols.mean() == pytest.approx(col, abs=1.0)
        assert mask.sum() > 200
    finally:
        view.close()


@pytest.mark.viewer
@pytest.mark.parametrize("color_by", ["height", "deformation"])
def test_dent_shows_where_the_net_was_pushed_and_goes_away_on_reset(gl, color_by):
    s = sinusoid_surface(n=32)
    view = make_view(s, color_by=color_by, layers={"tip": False, "hud": False, "colorbar": False})
    try:
        x, y = 110e-9, 90e-9
        c = above(s, x, y, 0.0)
        view.update(SceneState(s, c, R))
        before = view.screenshot()
        push_down(s, x, y, 6e-9, 20e-9)
        view.update(SceneState(s, c, R))
        after = view.screenshot()
        # the in-place, patch-wise re-sampling equals a full re-sampling
        nu, nv = view.resolution
        np.testing.assert_allclose(view.grid.points, s.evaluate_grid(nu, nv).reshape(-1, 3) * 1e9, rtol=0, atol=1e-9)
        mask = changed(before, after)
        assert mask.sum() > 150
        rows, cols = np.nonzero(mask)
        row, col = view.world_to_pixel((x, y, float(s.evaluate(x, y)[2])))
        assert abs(np.median(rows) - row) < 8 and abs(np.median(cols) - col) < 8
        # local: nothing changes far from the dent (the B-spline patch is local)
        far = np.hypot(*np.mgrid[: SIZE[1], : SIZE[0]] - np.array([row, col])[:, None, None]) > 70
        assert not (mask & far).any()
        if color_by == "deformation":  # undeformed is the palest colour; the dent is darker
            assert after[mask].sum(axis=1).mean() < before[mask].sum(axis=1).mean() - 30
        s.reset()
        view.update(SceneState(s, c, R))
        np.testing.assert_array_equal(view.screenshot(), before)
    finally:
        view.close()


@pytest.mark.viewer
def test_shading_uses_the_exact_surface_normals(gl):
    s = sinusoid_surface(n=12, amp=20e-9)
    view = make_view(s, resolution=(20, 15), layers={"tip": False, "hud": False, "colorbar": False})
    try:
        view.update(SceneState(s, (1e-7, 1e-7, 1e-6), R))
        (u0, u1), (v0, v1) = s.domain
        uu, vv = np.meshgrid(np.linspace(u0, u1, 20), np.linspace(v0, v1, 15))
        _, su, sv = s.evaluate(uu, vv, 1)
        n = np.cross(su, sv)
        n /= np.linalg.norm(n, axis=-1, keepdims=True)
        np.testing.assert_allclose(view.grid.point_data["Normals"], n.reshape(-1, 3), atol=1e-12)
        assert (n[..., 2] > 0).all()  # out of the sample
        a = view.screenshot()
        view._normals[...] = (0.0, 0.0, 1.0)  # the renderer must use them: flat normals look different
        view.grid.GetPointData().GetArray("Normals").Modified()
        assert changed(a, view.screenshot()).sum() > 1000
    finally:
        view.close()


def test_view_refuses_bad_settings():
    from arsurf_viewer import SurfaceView

    s = sinusoid_surface()
    for kwargs, match in [(dict(color_by="slope"), "color_by"), (dict(camera="side"), "camera"),
                          (dict(force_scale=0.0), "force_scale"), (dict(tip_opacity=0.0), "tip_opacity"),
                          (dict(anti_aliasing="4x"), "anti_aliasing"), (dict(window_size=(8, 8)), "window_size"),
                          (dict(resolution=1), "resolution.*2..4096")]:
        with pytest.raises(ViewerError, match=match):
            SurfaceView(s, **kwargs)
    with pytest.raises(ViewerError, match="BSplineSurface"):
        SurfaceView(np.zeros((3, 3)))


@pytest.mark.viewer
def test_force_arrow_appears_points_along_the_force_and_hides(gl):
    s = sinusoid_surface()
    view = make_view(s, camera="top", layers={"hud": False, "colorbar": False}, force_threshold=1e-12)
    try:
        c = above(s, 100e-9, 100e-9, 5e-9)
        view.update(SceneState(s, c, R))
        assert blue(view.screenshot()).sum() == 0
        view.update(SceneState(s, c, R, force=(0.0, 0.0, 1e-13)))  # below the threshold
        assert blue(view.screenshot()).sum() == 0
        row0, col0 = view.world_to_pixel(c)
        for force, drow, dcol in (((5e-9, 0, 0), 0, 1), ((0, -5e-9, 0), 1, 0), ((-2e-9, 2e-9, 0), -1, -1)):
            view.update(SceneState(s, c, R, force=force))
            m = blue(view.screenshot())
            assert m.sum() > 40, force
            rows, cols = np.nonzero(m)
            if drow:
                assert np.sign(rows.mean() - row0) == drow
            if dcol:
                assert np.sign(cols.mean() - col0) == dcol
        # longer for a larger force (logarithmic law)
        view.update(SceneState(s, c, R, force=(1e-9, 0, 0)))
        small = np.nonzero(blue(view.screenshot()))[1].max()
        view.update(SceneState(s, c, R, force=(30e-9, 0, 0)))
        large = np.nonzero(blue(view.screenshot()))[1].max()
        assert large > small + 10
        view.set_layer("force", False)
        assert blue(view.screenshot()).sum() == 0
    finally:
        view.close()


@pytest.mark.viewer
def test_contact_normal_arrow_and_layers(gl):
    s = sinusoid_surface()
    # 640 x 480: the oblique view leaves room for the scale bar and the colour bar, and the 1.8 R
    # arrow inside the translucent tip is ~17 px long at 320 x 240, too few to judge its colour
    view = make_view(s, camera="oblique", tip_opacity=0.3, layers={"hud": False}, window_size=(640, 480))
    try:
        c = above(s, 100e-9, 100e-9, -1e-9)
        p = s.evaluate(100e-9, 100e-9)
        view.update(SceneState(s, c, R))
        assert green(view.screenshot()).sum() == 0
        view.update(SceneState(s, c, R, contact_point=p, contact_normal=(0, 0, 1)))
        g = green(view.screenshot())
        assert g.sum() > 20
        rows, _ = np.nonzero(g)
        top = view.world_to_pixel(p + np.array([0, 0, 1.8 * R]))
        assert rows.min() == pytest.approx(top[0], abs=3)  # the arrow ends 1.8 R along n
        view.set_layer("contact", False)
        assert green(view.screenshot()).sum() == 0
        view.set_layer("surface", False)
        img = view.screenshot()
        r, g_, b = (img[..., k].astype(int) for k in range(3))
        assert (np.max([r, g_, b], axis=0) - np.min([r, g_, b], axis=0) > 40).mean() < 0.01  # no surface colours
        with pytest.raises(ViewerError, match="unknown layer 'nope'"):
            view.set_layer("nope", True)
    finally:
        view.close()


@pytest.mark.viewer
def test_update_is_in_place(gl):
    s = sinusoid_surface()
    view = make_view(s)
    try:
        tube = ((50e-9, 50e-9, 5e-9), (1, 1, 0), 60e-9, 5e-9)
        view.update(SceneState(s, above(s, 1e-7, 1e-7, 2e-9), R, contact_point=(1e-7, 1e-7, 0),
                               contact_normal=(0, 0, 1), force=(0, 0, 2e-9), tubes=[tube]))
        actors = dict(view.plotter.renderer.actors)
        grid, tip, tube_actor = view.grid, view.tip_actor, view._tubes[0][0]
        points = view.grid.GetPoints().GetData()
        for k in range(5):
            push_down(s, 1e-7, 1e-7, 0.5e-9, 15e-9)
            moved = ((60e-9 + k * 1e-9, 50e-9, 5e-9), (1, 1, 0), 60e-9, 5e-9)
            view.update(SceneState(s, above(s, 1e-7 + k * 1e-9, 1e-7, 2e-9), R, contact_point=(1e-7, 1e-7, 0),
                                   contact_normal=(0, 1, 1), force=(k * 1e-9, 0, 2e-9), tubes=[moved]))
        assert dict(view.plotter.renderer.actors).keys() == actors.keys()
        assert view.grid is grid and view.tip_actor is tip and view._tubes[0][0] is tube_actor
        assert view.grid.GetPoints().GetData() is points
        np.testing.assert_allclose(np.asarray(view.tip_actor.user_matrix)[:3, 3], (np.array([1.04e-7, 1e-7, 0]) +
                                   [0, 0, above(s, 1.04e-7, 1e-7, 2e-9)[2]]) * 1e9)
        np.testing.assert_allclose(np.asarray(tube_actor.user_matrix)[:3, 3], [64.0, 50.0, 5.0])
    finally:
        view.close()


@pytest.mark.viewer
def test_color_by_and_layer_sets(gl):
    s = sinusoid_surface()
    view = make_view(s)
    try:
        view.update(SceneState(s, above(s, 1e-7, 1e-7, 5e-9), R))
        ctl = StylusController(s, (1e-7, 1e-7, 3e-8), view=view)
        assert ctl.handle_key("c") == "colour by deformation"
        assert view.grid.point_data.active_scalars_name == "deformation_nm"
        assert ctl.handle_key("t") == f"layers: {LAYER_SETS[1][0]}"
        assert view.layers["tip"] is False and view.layers["surface"] is True
        assert ctl.handle_key("2") == "tip on"
        assert ctl.handle_key("v") == "camera top" and view.plotter.camera.parallel_projection
        with pytest.raises(ViewerError, match="color_by"):
            view.set_color_by("slope")
    finally:
        view.close()


@pytest.mark.viewer
def test_probe_layer_draws_the_pyramid_over_the_tip(gl):
    pytest.importorskip("trimesh")
    s = sinusoid_surface()
    view = make_view(s, camera="top", layers={"hud": False, "colorbar": False})
    try:
        c = above(s, 100e-9, 100e-9, 5e-9)
        view.update(SceneState(s, c, R))
        a = view.screenshot()
        view.set_layer("probe", True)
        b = view.screenshot()
        mask = changed(a, b)
        # seen from above, the pyramid hides a square around the tip, wider than the tip
        rows, cols = np.nonzero(mask)
        row, col = view.world_to_pixel(c)
        assert rows.min() < row - 20 < row + 20 < rows.max() and cols.min() < col - 20 < col + 20 < cols.max()
    finally:
        view.close()


@pytest.mark.viewer
def test_render_frames_writes_pngs_and_a_movie(gl, tmp_path):
    from arsurf_viewer.frames import movie_support, render_frames

    s = sinusoid_surface()
    path = scripted_path(s, R, frames=8)
    states = (SceneState(s, c, R, force=(0, 0, 1e-9 * k)) for k, c in enumerate(path))
    out = render_frames(states, tmp_path / "out", fps=10, window_size=(160, 120), anti_aliasing=None)
    assert [p.name for p in out.paths] == [f"frame_{k:05d}.png" for k in range(8)]
    assert not list((tmp_path / "out").glob("*.part*"))
    first, last = (np.asarray(__import__("imageio.v3").v3.imread(p)) for p in (out.paths[0], out.paths[-1]))
    assert changed(first, last).sum() > 20  # the tip moved
    if movie_support() is None:
        import imageio.v3 as iio

        frames = iio.imread(out.movie, index=None)
        assert frames.shape[0] == 8 and frames.shape[1:3] == (120, 160)
    else:
        assert out.movie is None and "no movie" in out.note
    with pytest.raises(ViewerError, match="no states"):
        render_frames(iter(()), tmp_path / "empty", movie=None)


@pytest.mark.viewer
def test_without_a_display_the_viewer_renders_offscreen(gl, tmp_path, monkeypatch, caplog):
    import arsurf_viewer.interactive as inter

    caplog.set_level(logging.INFO, logger="arsurf")
    monkeypatch.setattr(inter, "has_display", lambda: False)
    s = sinusoid_surface()
    poses = iter([above(s, 1e-7, 1e-7, 6e-9), above(s, 1e-7, 1e-7, 3e-9), None, above(s, 1e-7, 1e-7, 1e-9)])
    seen = []

    def physics(center, dt):  # the lead's loop plugs in here; duck-typed
        seen.append(np.array(center))
        return SceneState(s, center, R, loop_rate_hz=1.0 / dt)

    res = inter.run_interactive(s, tip_radius=R, physics=physics, pose_source=lambda: next(poses, None),
                                out_dir=tmp_path / "view", frames=4, window_size=(160, 120), anti_aliasing=None)
    assert "no display" in caplog.text and all(r.name == "arsurf.viewer" for r in caplog.records)
    assert len(res.paths) == 4 and all(p.is_file() for p in res.paths)
    assert len(seen) == 4
    np.testing.assert_array_equal(seen[2], seen[1])  # a None pose keeps the last one


def test_contact_physics_dents_and_releases():
    pytest.importorskip("arsurf.contact.projection")
    from arsurf_viewer.interactive import ContactPhysics

    s = BSplineSurface.from_heights(np.zeros((30, 30)), (0.0, 200e-9), (0.0, 200e-9))
    phys = ContactPhysics(s, R)
    free = phys((1e-7, 1e-7, R + 5e-9), 1e-3)
    assert free.depth == pytest.approx(-5e-9, abs=1e-15) and not s.is_deformed
    st = phys((1e-7, 1e-7, R - 2e-9), 1e-3)
    assert st.depth == pytest.approx(2e-9, abs=1e-15)
    assert st.force[2] > 0 and abs(st.force[0]) < 1e-15 and st.contact_radius > 0
    assert s.is_deformed and s.evaluate(1e-7, 1e-7)[2] < -0.25 * 2e-9  # dented under the tip
    phys((1e-7, 1e-7, R + 30e-9), 1e-3)
    assert not s.is_deformed


@pytest.mark.viewer
def test_view_scan_levels_smooths_fits_and_falls_back_offscreen(gl, tmp_path, monkeypatch, caplog):
    pytest.importorskip("arsurf.contact.projection")
    caplog.set_level(logging.INFO, logger="arsurf")
    import arsurf
    import arsurf_viewer.interactive as inter

    monkeypatch.setattr(inter, "has_display", lambda: False)
    z = np.fromfunction(lambda i, j: 2e-9 * np.sin(i / 4.0) + 1e-10 * j, (40, 40))  # with a tilt
    scan = arsurf.Scan(z, dx=5e-9, dy=5e-9)
    res = inter.view_scan(scan, tip_radius=R, sigma=5e-9, out_dir=tmp_path, frames=4, window_size=(160, 120),
                          anti_aliasing=None, movie=None)
    assert [p.name for p in res.paths] == [f"frame_{k:05d}.png" for k in range(4)]
    assert "rendering 4 frames offscreen" in caplog.text


def test_headless_view_that_cannot_render_fails_saying_what_to_install(tmp_path, monkeypatch, capsys):
    """No frames written is never a success: a renderer failure is one line naming the packages."""
    import arsurf
    import arsurf_viewer.interactive as inter
    from arsurf.cli import main
    from arsurf.errors import RenderingUnavailable

    monkeypatch.setattr(inter, "has_display", lambda: False)
    monkeypatch.setattr(inter, "choose_backend", lambda: None)

    class NoContext:
        def __init__(self, *args, **kwargs):
            raise RuntimeError("vtkEGLRenderWindow: failed to initialize EGL\nsecond line")

    monkeypatch.setattr("arsurf_viewer.view.SurfaceView", NoContext)
    s = sinusoid_surface()
    with pytest.raises(RenderingUnavailable, match=r"rendering failed \(RuntimeError: vtkEGLRenderWindow: failed to "
                       r"initialize EGL\); install EGL .*libegl1 .*libosmesa6"):
        inter.run_interactive(s, tip_radius=R, out_dir=tmp_path / "v", frames=4)
    assert not list((tmp_path / "v").glob("*.png")) if (tmp_path / "v").exists() else True
    code = main(["view", str(tmp_path / "missing.npz")])  # a bad scan: the scan's error, not a rendering one
    assert code == 2 and "missing.npz" in capsys.readouterr().err
    scan = arsurf.save_scan(arsurf.Scan(np.zeros((24, 24)), dx=5e-9, dy=5e-9), tmp_path / "flat.npz")
    code = main(["view", str(scan), "--frames", "4", "--out", str(tmp_path / "cli")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and err[-1].startswith("arsurf view: error:") and "install EGL" in err[-1]
    assert not list((tmp_path / "cli").glob("*.png")) if (tmp_path / "cli").exists() else True


@pytest.mark.viewer
def test_a_pushed_tube_is_drawn_where_the_scene_moved_it(gl):
    """The tube scene feeds SceneState.tubes: after an end push the tube's pixels move at the
    pushed end and stay at the pivot ([MWCNT]'s rotation about s(l))."""
    from arsurf.manipulation.nanotube import Nanotube, rotation_centre
    from arsurf.manipulation.scene import TubeScene

    s = BSplineSurface.from_heights(np.zeros((12, 12)), (0.0, 200e-9), (0.0, 200e-9))
    tube = Nanotube(120e-9, 10e-9, x=100e-9, y=90e-9, angle=0.0)
    scene = TubeScene([tube])
    view = make_view(s, camera="top", layers={"hud": False, "colorbar": False, "tip": False})
    try:
        tip = np.array([100e-9 + 0.45 * tube.length, 90e-9 - 17.5e-9, 12e-9])
        view.update(SceneState(s, tip, R, tubes=scene.viewer_tubes()))
        before = view.screenshot()
        step = scene.step(tip, tip + [0.0, 45e-9, 0.0], R)
        view.update(SceneState(s, tip + [0.0, 45e-9, 0.0], R, tubes=scene.viewer_tubes()))
        after = view.screenshot()
        moved = scene.tubes[0]
        assert step.touched[0] and moved.angle > 0.3
        mask = changed(before, after)
        old_end, new_end = (view.world_to_pixel(t.point_at(0.97 * t.length)) for t in (tube, moved))
        pivot = view.world_to_pixel(tube.point_at(float(rotation_centre(0.95 * tube.length, tube.length))))

        def window(point):  # changed pixels in the 5 x 5 pixels around a projected point
            r, c = (int(round(v)) for v in point)
            return mask[r - 2:r + 3, c - 2:c + 3]

        for end in (old_end, new_end):  # the end left its old place and is drawn at the new one
            assert window(end).mean() > 0.6
        # the tube turned about the pivot: there only the edges' shading changes
        assert not mask[tuple(int(round(v)) for v in pivot)] and window(pivot).mean() < 0.4
        assert mask.sum() > 100
    finally:
        view.close()


@pytest.mark.viewer
def test_close_up_centres_the_tip_and_fills_the_frame(gl):
    s = sinusoid_surface()
    view = make_view(s, camera="oblique", tip_opacity=1.0, layers={"hud": False, "colorbar": False})
    try:
        c = above(s, 80e-9, 120e-9, 5e-9)
        view.update(SceneState(s, c, R))
        view.set_layer("tip", True)
        far = view.screenshot()
        view.set_layer("tip", False)
        far_mask = changed(far, view.screenshot())
        view.set_layer("tip", True)
        view.close_up(c, 8 * R)
        near = view.screenshot()
        view.set_layer("tip", False)
        near_mask = changed(near, view.screenshot())
        h, w = near_mask.shape
        row, col = view.world_to_pixel(c)
        assert row == pytest.approx(h / 2, abs=2.0) and col == pytest.approx(w / 2, abs=2.0)
        assert near_mask.sum() > 3 * far_mask.sum()  # the tip is larger in the close-up...
        cols = np.nonzero(near_mask.any(axis=0))[0]
        assert np.ptp(cols) + 1 == pytest.approx(w / 4, rel=0.35)  # ...2R across a field of 8R
        with pytest.raises(ViewerError, match="positive width"):
            view.close_up(c, 0.0)
    finally:
        view.close()


def test_live_loop_runs_in_its_thread_and_the_view_reads_its_snapshots():
    """The real-time loop (Scheduler thread, 1 kHz) drives the tip; the viewer hook returns scenes
    built from the loop's snapshots while it runs."""
    import time as _time

    from arsurf.contact.maugis_dugdale import MaugisDugdale
    from arsurf.assembly import LEVER
    from arsurf.force.cantilever import Cantilever
    from arsurf.haptics.loop import HapticLoop
    from arsurf.haptics.virtual_device import HandModel, VirtualDevice
    from arsurf.model import ARModel
    from arsurf.haptics.live_loop import LiveLoop
    from arsurf_viewer.live import live_scene

    s = BSplineSurface.from_heights(np.zeros((60, 60)), (0.0, 57 * 4e-9), (0.0, 57 * 4e-9))  # 4 nm net
    model = ARModel(s, R, MaugisDugdale(R, 10e9, 0.1), Cantilever(**LEVER))
    c = (100e-9, 100e-9)
    origin = (*c, float(s.evaluate(*c)[2]) + R + 3e-9)
    hand = HandModel((np.array([0.0, 0.3, 10.0]), np.array([[0, 0, 0], [0, 0, -0.6e-3], [0, 0, -0.6e-3]])))
    dev = VirtualDevice(dt=1e-3, hand=hand)
    live = LiveLoop(HapticLoop.direct(model, dev.info, origin), dev).start()
    try:
        first = live_scene(live, np.zeros(3), 1 / 30)
        deadline = _time.monotonic() + 15.0  # 600 ticks (0.6 s of the hand's motion), however busy CI is
        while live.scheduler.ticks < 601 and _time.monotonic() < deadline:  # a snapshot after the 600th tick
            _time.sleep(0.01)
        scene = live_scene(live, np.zeros(3), 1 / 30)
        assert live.scheduler.ticks >= 600 and scene.loop_rate_hz > 0
        np.testing.assert_allclose(scene.tip_center, live.pose())
        assert scene.depth > 0 and scene.force[2] > 0 and scene.contact_radius > 0   # pressed in by the hand
        assert scene.surface is model.surface and s.is_deformed
        assert first.time != scene.time
    finally:
        stats = live.stop()
    assert stats.ticks > 300 and not dev.is_open


# -- notebooks (arsurf_viewer.notebook) --------------------------------------------------------
def test_notebook_show_refuses_what_it_cannot_draw(monkeypatch):
    import importlib.util

    from arsurf.errors import MissingDependency
    from arsurf_viewer import notebook

    s = sinusoid_surface()
    with pytest.raises(ViewerError, match="backend must be one of static, trame"):
        notebook.show(s, backend="vtkjs")
    with pytest.raises(ViewerError, match="takes a BSplineSurface or a SceneState"):
        notebook.show(np.zeros((4, 4)))
    with pytest.raises(ViewerError, match="close_up frames the tip: pass a SceneState"):
        notebook.show(s, close_up=1e-7)
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name.startswith("trame") else real(name))
    with pytest.raises(MissingDependency, match=r"view needs trame, trame_vtk, .*: pip install 'arsurf\[notebook\]'"):
        notebook.show(s, backend="trame")
    with pytest.raises(ViewerError, match="uint8"):
        notebook.Picture(np.zeros((4, 4, 3)))


@pytest.mark.viewer
def test_notebook_show_is_the_application_view_as_a_png(gl, tmp_path):
    import io

    from PIL import Image

    from arsurf_viewer.notebook import show

    s = sinusoid_surface()
    push_down(s, 1e-7, 1e-7, 2e-9, 3e-8)
    st = SceneState(s, above(s, 1e-7, 1e-7, -1e-9), R, contact_point=(1e-7, 1e-7, float(s.evaluate(1e-7, 1e-7)[2])),
                    contact_normal=(0, 0, 1), depth=1e-9, contact_radius=3e-9, force=(1e-9, 0.0, 4e-9))
    picture = show(st, window_size=SIZE, color_by="deformation")
    view = make_view(s, color_by="deformation")
    try:
        view.update(st)
        expected = view.screenshot()
    finally:
        view.close()
    np.testing.assert_array_equal(picture.array, expected)  # the same scene as the application's
    decoded = np.asarray(Image.open(io.BytesIO(picture._repr_png_())))[..., :3]
    np.testing.assert_array_equal(decoded, picture.array)
    assert blue(picture.array).sum() > 50  # the force arrow
    assert picture.save(tmp_path / "view.png").read_bytes() == picture.png
    # a bare surface: no HUD, no tip; the dent shows in the deformation colours only where it is
    kw = dict(window_size=SIZE, color_by="deformation", camera="top", layers={"colorbar": False})
    bare, flat = show(s, **kw).array, show(sinusoid_surface(), **kw).array
    moved = changed(bare, flat)
    ys, xs = np.nonzero(moved)
    assert moved.sum() > 100 and np.ptp(xs) < SIZE[0] / 2 and np.ptp(ys) < SIZE[1] / 2
