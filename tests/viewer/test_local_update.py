"""The view's per-frame update is local (arsurf_viewer.patch) and equals a full re-sample.

A frame re-samples only the samples whose control points a dent moved, contours only the
deformed samples and keeps its colour limits; these tests check that what it shows after a
sequence of moving dents (one jumping away, one deeper, a release) is what a view re-sampling
and contouring the whole grid shows: the points, normals, heights and deformation to 1e-9 nm,
the old patch back at rest bitwise, the dent's contour points those of VTK's contour filter on the
whole grid, and the picture that of a new view of the same surface.
"""
from __future__ import annotations

import numpy as np
import pytest

from arsurf.contact.deformation import Deformer
from arsurf.spline.surface import BSplineSurface

R = 12e-9  # tip radius, m
SIZE = (320, 240)


def rough_surface(n=40, length=200e-9):
    x = np.linspace(0.0, length, n)
    z = 3e-9 * np.sin(2 * np.pi * x[:, None] / 70e-9) * np.cos(2 * np.pi * x[None, :] / 110e-9)
    return BSplineSurface.from_heights(z, (0.0, length), (0.0, length))


def make_view(surface, **kw):
    from arsurf_viewer import SurfaceView

    kw.setdefault("window_size", SIZE)
    kw.setdefault("off_screen", True)
    kw.setdefault("anti_aliasing", None)
    kw.setdefault("layers", {"hud": False, "colorbar": False, "scalebar": False})
    return SurfaceView(surface, **kw)


def vtk_contour_points(values, pts, levels):
    """Reference: VTK's flying edges on the whole (rows, cols) grid of ``values`` at ``levels``,
    each point put on the surface ``pts`` (rows, cols, 3) along its grid edge."""
    from vtkmodules.util.numpy_support import numpy_to_vtk, vtk_to_numpy
    from vtkmodules.vtkCommonDataModel import vtkImageData
    from vtkmodules.vtkFiltersCore import vtkFlyingEdges2D

    rows, cols = values.shape
    image = vtkImageData()
    image.SetDimensions(cols, rows, 1)
    image.GetPointData().SetScalars(numpy_to_vtk(np.ascontiguousarray(values).ravel(), deep=1))
    fe = vtkFlyingEdges2D()
    fe.SetInputData(image)
    fe.SetNumberOfContours(len(levels))
    for k, level in enumerate(levels):
        fe.SetValue(k, float(level))
    fe.Update()
    out = fe.GetOutput()
    if out.GetNumberOfPoints() == 0:
        return np.zeros((0, 3))
    q = vtk_to_numpy(out.GetPoints().GetData()).astype(np.float64)
    i0 = np.clip(np.floor(q[:, 0]).astype(int), 0, cols - 2)
    j0 = np.clip(np.floor(q[:, 1]).astype(int), 0, rows - 2)
    tx, ty = (q[:, 0] - i0)[:, None], (q[:, 1] - j0)[:, None]  # one of them is 0 or 1: a grid edge
    return ((1 - ty) * ((1 - tx) * pts[j0, i0] + tx * pts[j0, i0 + 1])
            + ty * ((1 - tx) * pts[j0 + 1, i0] + tx * pts[j0 + 1, i0 + 1]))


def same_point_sets(a, b, tol):
    from scipy.spatial import cKDTree

    if len(a) == 0 or len(b) == 0:
        return len(a) == len(b)
    return cKDTree(b).query(a)[0].max() < tol and cKDTree(a).query(b)[0].max() < tol


def dent_lines(view):
    from vtkmodules.util.numpy_support import vtk_to_numpy

    n = view._dent_segments
    return vtk_to_numpy(view._dent_lines.GetPoints().GetData())[: 2 * n], n


def full_resample(view, surface, rest):
    """The grid re-sampled from scratch: points (nm), unit normals, deformation |S - S_rest| (nm)."""
    nu, nv = view.resolution
    (u0, u1), (v0, v1) = surface.domain
    uu, vv = np.meshgrid(np.linspace(u0, u1, nu), np.linspace(v0, v1, nv))
    S, Su, Sv = surface.evaluate(uu, vv, 1)
    n = np.cross(Su, Sv)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    pts = S * 1e9
    return pts, n, np.linalg.norm(pts - rest.evaluate(uu, vv) * 1e9, axis=-1)


def test_contour_patch_equals_vtk_contours_on_a_saddled_field():
    from arsurf_viewer.patch import contour_patch

    rng = np.random.default_rng(3)
    f = rng.random((23, 31))  # every case of marching squares, saddles included
    yy, xx = np.mgrid[0:23, 0:31].astype(float)
    pts = np.stack([0.7 * xx, 1.3 * yy, 5.0 * f], axis=-1)
    levels = np.array([0.25, 0.5, 0.8])
    out = np.empty((8, 3))  # too small: the count says how much room the segments need
    n = contour_patch(f, pts, 0, 31, 0, 23, levels, out)
    assert n > 4
    out = np.empty((2 * n, 3))
    assert contour_patch(f, pts, 0, 31, 0, 23, levels, out) == n
    ref = vtk_contour_points(f, pts, levels)
    assert same_point_sets(out, ref, 1e-5)
    # every end lies on a grid edge, where the field interpolated linearly equals a level
    fz = out[:, 2] / 5.0
    assert np.min(np.abs(fz[:, None] - levels[None, :]), axis=1).max() < 1e-12
    # a box of the field contours the same as the whole field where the field is 0 outside it
    g = np.zeros_like(f)
    g[5:15, 8:20] = f[5:15, 8:20]
    whole = np.empty((4 * n, 3))
    box = np.empty((4 * n, 3))
    nw = contour_patch(g, pts, 0, 31, 0, 23, levels, whole)
    nb = contour_patch(g, pts, 7, 21, 4, 16, levels, box)  # one sample of margin each side
    assert nb == nw and same_point_sets(box[: 2 * nb], whole[: 2 * nw], 1e-12)


@pytest.mark.viewer
def test_local_frames_equal_a_full_resample_after_moving_dents(gl):
    from arsurf_viewer import SceneState

    s = rough_surface()
    rest = s.copy()
    dent = Deformer(s)
    view = make_view(s, resolution=150)
    try:
        pts0 = view._pts.copy()
        # the tip slides 2 nm a frame, jumps 70 nm away, presses deeper there, then lifts off
        frames = [(60e-9 + 2e-9 * k, 80e-9, 2e-9) for k in range(6)] + [(140e-9, 120e-9, 2e-9),
                                                                           (140e-9, 120e-9, 4e-9), None]
        for frame in frames:
            if frame is None:
                dent.release()
            else:
                x, y, depth = frame
                z = float(rest.evaluate(x, y)[2]) + R - depth
                dent.apply((x, y, z), R, (0.0, 0.0, 1.0), 7e-9, depth=depth, zone_radius=9e-9)
            view.update(SceneState(s, (100e-9, 100e-9, 40e-9), R), render=False)
            pts, normals, deform = full_resample(view, s, rest)
            np.testing.assert_allclose(view._pts, pts, rtol=0, atol=1e-9)
            np.testing.assert_allclose(view._normals, normals, rtol=0, atol=1e-12)
            np.testing.assert_allclose(view._height, pts[..., 2], rtol=0, atol=1e-9)
            np.testing.assert_allclose(view._deform, deform, rtol=0, atol=1e-9)
            # outside the dent box the grid is the rest grid, bitwise (the old patch restored)
            iu0, iu1, jv0, jv1 = view._dent_box
            outside = np.ones(deform.shape, bool)
            outside[jv0:jv1, iu0:iu1] = False
            assert (view._deform[outside] == 0.0).all()
            np.testing.assert_array_equal(view._pts[outside], pts0[outside])
            # the dent's lines: those of the whole grid contoured by VTK at the same levels
            lines, n = dent_lines(view)
            if view.dent_step_nm > 0.0:
                levels = np.arange(1, int(deform.max() / view.dent_step_nm) + 1) * view.dent_step_nm
                assert n > 0 and same_point_sets(lines, vtk_contour_points(deform, pts, levels), 1e-4)
            else:
                assert n == 0
        assert frame is None and view.dent_step_nm == 0.0 and view._dent_box == (0, 0, 0, 0)
        np.testing.assert_array_equal(view._pts, pts0)
    finally:
        view.close()


@pytest.mark.viewer
def test_two_contacts_far_apart_are_two_small_patches(gl):
    from arsurf_viewer import SceneState

    s = rough_surface()
    rest = s.copy()
    near, far = Deformer(s), Deformer(s)
    view = make_view(s, resolution=150)
    try:
        for k in range(4):  # two tips sliding at opposite corners of the scan
            for dent, (x, y) in ((near, (30e-9 + 2e-9 * k, 30e-9)), (far, (170e-9 - 2e-9 * k, 170e-9))):
                z = float(rest.evaluate(x, y)[2]) + R - 2e-9
                dent.apply((x, y, z), R, (0.0, 0.0, 1.0), 5e-9, depth=2e-9, zone_radius=6e-9)
            view.update(SceneState(s, (100e-9, 100e-9, 40e-9), R), render=False)
            pts, normals, deform = full_resample(view, s, rest)
            np.testing.assert_allclose(view._pts, pts, rtol=0, atol=1e-9)
            np.testing.assert_allclose(view._deform, deform, rtol=0, atol=1e-9)
            boxes = view._dent_boxes
            assert len(boxes) == 2 and all(b[1] - b[0] < 40 and b[3] - b[2] < 40 for b in boxes)  # of 150 x 150
            lines, n = dent_lines(view)
            levels = np.arange(1, int(deform.max() / view.dent_step_nm) + 1) * view.dent_step_nm
            assert same_point_sets(lines, vtk_contour_points(deform, pts, levels), 1e-4)
            assert (lines[:, 0] < 100).any() and (lines[:, 0] > 100).any()  # around both dents
    finally:
        view.close()


@pytest.mark.viewer
@pytest.mark.parametrize("color_by", ["height", "deformation"])
def test_the_locally_updated_picture_is_that_of_a_new_view(gl, color_by):
    from arsurf_viewer import SceneState

    s = rough_surface()
    rest = s.copy()
    dent = Deformer(s)
    view = make_view(s, resolution=150, color_by=color_by, camera="top")
    try:
        for k in range(8):  # a dent sliding 3 nm a frame, 3 nm deep: its box moves with it
            x, y = 70e-9 + 3e-9 * k, 90e-9
            z = float(rest.evaluate(x, y)[2]) + R - 3e-9
            dent.apply((x, y, z), R, (0.0, 0.0, 1.0), 7e-9, depth=3e-9, zone_radius=9e-9)
            view.update(SceneState(s, (x, y, z), R), render=False)
        local = view.screenshot()
        fresh = make_view(s, resolution=150, color_by=color_by, camera="top")
        try:
            fresh.update(SceneState(s, (x, y, z), R), render=False)
            np.testing.assert_array_equal(local, fresh.screenshot())
        finally:
            fresh.close()
    finally:
        view.close()


@pytest.mark.viewer
def test_colour_limits_hold_still_until_the_dent_goes_deeper(gl):
    from arsurf._figure_style import robust_limits
    from arsurf_viewer import SceneState

    s = rough_surface()
    rest = s.copy()
    dent = Deformer(s)
    view = make_view(s, resolution=150, color_by="deformation")
    try:
        def press(x, depth):
            z = float(rest.evaluate(x, 100e-9)[2]) + R - depth
            a = (R * depth) ** 0.5  # Hertz: a^2 = R delta
            dent.apply((x, 100e-9, z), R, (0.0, 0.0, 1.0), a, depth=depth, zone_radius=1.3 * a)
            view.update(SceneState(s, (x, 100e-9, z), R), render=False)
            return tuple(float(v) for v in view._mapper.scalar_range)

        def round_up(nm):  # the smallest of 0.5, 1, 2, 5, 10 ... nm at or above nm
            return min(v for v in (0.5, 1.0, 2.0, 5.0, 10.0, 20.0) if v >= nm)

        assert press(80e-9, 0.3e-9) == (0.0, 0.5)  # a shallow dent: the floor of the scale
        deep = press(80e-9, 1.5e-9)
        top = view._dent_top
        assert 1.0 < top <= 1.5 and deep == (0.0, round_up(top))  # deeper than the limit: it grows, once
        ticks = view._bar_ticks
        for k in range(1, 6):  # sliding at the same depth, then shallower: the limits hold still
            assert press(80e-9 + 1e-9 * k, 1.5e-9) == deep
        assert press(90e-9, 0.3e-9) == deep and view._bar_ticks is ticks
        assert robust_limits(view._rest_points[..., 2]) == pytest.approx(view._height_clim)  # the rest surface's
        view.refresh_color_limits()  # on demand: from the surface as it is now
        assert tuple(view._mapper.scalar_range) == (0.0, round_up(view._dent_top)) == (0.0, 0.5)
        now = robust_limits(view._height)
        view.set_color_by("height")
        assert tuple(view._mapper.scalar_range) == pytest.approx(now)
        press(100e-9, 4e-9)  # the heights' limits do not follow a dent
        assert tuple(view._mapper.scalar_range) == pytest.approx(now)
        view.refresh_color_limits()
        assert tuple(view._mapper.scalar_range) == pytest.approx(robust_limits(view._height))
        assert robust_limits(view._height) != pytest.approx(now)  # the 4 nm dent moved the 1st percentile
    finally:
        view.close()
