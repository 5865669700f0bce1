"""Surface meshes and STL/PLY/GLB export (arsurf.export), read back with trimesh."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

trimesh = pytest.importorskip("trimesh", reason="the [mesh] extra (trimesh) is not installed")

from arsurf.export import export_surface, surface_mesh  # noqa: E402
from arsurf.errors import ExportError
from arsurf.spline.surface import BSplineSurface  # noqa: E402

DOMAIN = ((10e-9, 130e-9), (-20e-9, 60e-9))  # 120 x 80 nm, not at the origin
NM = 1e9  # meshes and files are in nanometres


def plane(a=3e-9, b=0.05, c=-0.02, shape=(9, 7)):
    """z = a + b x + c y (a bicubic B-spline reproduces it exactly from Greville heights)."""
    s = BSplineSurface.from_heights(np.zeros(shape), *DOMAIN)
    ctrl = np.array(s.control_points)
    z = a + b * ctrl[..., 0] + c * ctrl[..., 1]
    return BSplineSurface.from_heights(z, *DOMAIN)


def bumpy(rng, shape=(14, 11), amp=4e-9):
    return BSplineSurface.from_heights(amp * rng.standard_normal(shape), *DOMAIN)


def dent(surface, x, y, depth, radius):
    """Push control points down around (x, y) with a smooth bump, as the deformation module will."""
    ctrl = surface.kernel_arrays()[0]
    d2 = (ctrl[..., 0] - x) ** 2 + (ctrl[..., 1] - y) ** 2
    ctrl[..., 2] -= depth * np.exp(-d2 / radius**2)


def test_flat_sheet_area_and_bounds_are_the_domain():
    s = BSplineSurface.from_heights(np.full((6, 5), 2e-9), *DOMAIN)
    m = surface_mesh(s, (17, 12))
    (u0, u1), (v0, v1) = DOMAIN
    assert m.area == pytest.approx((u1 - u0) * (v1 - v0) * NM**2, rel=1e-12)
    np.testing.assert_allclose(m.bounds, np.array([[u0, v0, 2e-9], [u1, v1, 2e-9]]) * NM, rtol=1e-12, atol=1e-12)
    assert len(m.faces) == 2 * 16 * 11
    assert (m.face_normals[:, 2] > 0.999).all()  # oriented out of the sample (+z)
    assert m.units == "nanometers"
    si = m.copy()
    si.convert_units("meters")
    assert si.area == pytest.approx((u1 - u0) * (v1 - v0), rel=1e-12)


def test_sheet_vertices_are_the_surface_samples(rng):
    s = bumpy(rng)
    m = surface_mesh(s, (23, 19))
    np.testing.assert_array_equal(m.vertices, s.evaluate_grid(23, 19).reshape(-1, 3) * NM)
    default = surface_mesh(s)  # one sample per control point
    assert default.metadata["resolution"] == s.shape


def test_sheet_area_converges_to_the_surface_area(rng):
    s = bumpy(rng, amp=6e-9)
    (u0, u1), (v0, v1) = DOMAIN
    # slow reference: area = integral of |S_u x S_v| by the midpoint rule on a fine grid
    n = 600
    u = u0 + (np.arange(n) + 0.5) * (u1 - u0) / n
    v = v0 + (np.arange(n) + 0.5) * (v1 - v0) / n
    uu, vv = np.meshgrid(u, v)
    _, su, sv = s.evaluate(uu, vv, 1)
    ref = np.linalg.norm(np.cross(su, sv), axis=-1).mean() * (u1 - u0) * (v1 - v0)
    assert surface_mesh(s, 400).area == pytest.approx(ref * NM**2, rel=2e-4)


def test_solid_of_a_plane_is_exact():
    s = plane()
    base = -5e-9
    m = surface_mesh(s, (13, 10), solid=True, base=base)
    assert m.is_watertight and m.is_winding_consistent and m.is_volume
    (u0, u1), (v0, v1) = DOMAIN
    area = (u1 - u0) * (v1 - v0)
    mean_z = 3e-9 + 0.05 * 0.5 * (u0 + u1) - 0.02 * 0.5 * (v0 + v1)
    assert m.volume == pytest.approx(area * (mean_z - base) * NM**3, rel=1e-10)
    assert m.bounds[0, 2] == pytest.approx(base * NM, rel=1e-15)
    # closed 2-manifold of genus 0
    assert m.euler_number == 2


def test_solid_volume_matches_the_integral(rng):
    s = bumpy(rng)
    base = -40e-9
    m = surface_mesh(s, 200, solid=True, base=base)
    assert m.is_watertight and m.is_volume
    (u0, u1), (v0, v1) = DOMAIN
    n = 800
    u = u0 + (np.arange(n) + 0.5) * (u1 - u0) / n
    v = v0 + (np.arange(n) + 0.5) * (v1 - v0) / n
    uu, vv = np.meshgrid(u, v)
    ref = (s.evaluate(uu, vv)[..., 2] - base).mean() * (u1 - u0) * (v1 - v0)  # height field
    assert m.volume == pytest.approx(ref * NM**3, rel=1e-4)


def test_default_base_lies_below_the_surface(rng):
    s = bumpy(rng)
    m = surface_mesh(s, 30, solid=True)
    zmin = s.evaluate_grid(30, 30)[..., 2].min()
    assert m.metadata["base"] < zmin
    assert m.bounds[0, 2] == pytest.approx(m.metadata["base"] * NM, rel=1e-15)
    assert m.is_watertight and m.volume > 0
    flat = surface_mesh(BSplineSurface.from_heights(np.zeros((5, 5)), *DOMAIN), 5, solid=True)
    assert flat.volume > 0  # a flat surface still gets a body (5 % of the lateral size)


@settings(max_examples=25, deadline=None)
@given(nu=st.integers(2, 30), nv=st.integers(2, 30), seed=st.integers(0, 2**16))
def test_solid_is_closed_for_any_resolution(nu, nv, seed):
    s = bumpy(np.random.default_rng(seed), shape=(6, 5))
    m = surface_mesh(s, (nu, nv), solid=True)
    assert m.is_watertight and m.is_winding_consistent and m.euler_number == 2
    ring = 2 * (nu + nv) - 4
    assert len(m.vertices) == nu * nv + ring + 1
    assert len(m.faces) == 2 * (nu - 1) * (nv - 1) + 3 * ring
    assert m.volume > 0


def test_export_follows_the_deformation(rng):
    s = bumpy(rng, amp=1e-9)
    before = surface_mesh(s, 60, solid=True, base=-30e-9)
    dent(s, 70e-9, 20e-9, 8e-9, 25e-9)
    after = surface_mesh(s, 60, solid=True, base=-30e-9)
    assert after.is_watertight
    assert after.bounds[0, 2] == before.bounds[0, 2]  # the base
    np.testing.assert_array_equal(after.vertices[: 60 * 60], s.evaluate_grid(60, 60).reshape(-1, 3) * NM)
    assert after.vertices[: 60 * 60, 2].min() < before.vertices[: 60 * 60, 2].min() - 4.0
    assert after.volume < before.volume
    s.reset()
    np.testing.assert_array_equal(surface_mesh(s, 60, solid=True, base=-30e-9).vertices, before.vertices)


@pytest.mark.parametrize("ext", ["stl", "ply", "glb"])
def test_files_read_back_in_nanometres(tmp_path, rng, ext):
    s = bumpy(rng)
    m = surface_mesh(s, (31, 27), solid=True)
    path = export_surface(s, tmp_path / f"surface.{ext}", (31, 27), solid=True)
    assert path.is_file() and not list(tmp_path.glob("*.part"))
    back = trimesh.load(path, force="mesh")
    assert back.is_watertight
    np.testing.assert_allclose(back.bounds, m.bounds, rtol=1e-6, atol=1e-5)  # float32 files
    assert back.area == pytest.approx(m.area, rel=1e-5)
    assert back.volume == pytest.approx(m.volume, rel=1e-5)
    (u0, u1), (v0, v1) = DOMAIN
    np.testing.assert_allclose(back.bounds[:, :2], np.array([[u0, v0], [u1, v1]]) * NM, rtol=1e-6)


def test_sheet_file_is_open_and_metres_on_request(tmp_path, rng):
    s = bumpy(rng)
    path = export_surface(s, tmp_path / "sheet.ply", 20, unit="m")
    # metres: load without trimesh's processing, whose absolute 1e-8 merge tolerance would
    # collapse a nanometre mesh in metres (the reason files default to nm)
    back = trimesh.load(path, force="mesh", process=False)
    assert not back.is_watertight
    np.testing.assert_allclose(back.vertices, s.evaluate_grid(20, 20).reshape(-1, 3), rtol=1e-6, atol=1e-15)
    colours = np.asarray(back.visual.vertex_colors)[:, :3].astype(int)
    z = back.vertices[:, 2]
    assert colours[np.argmax(z)].sum() > colours[np.argmin(z)].sum()  # afmhot: high = bright


@pytest.mark.parametrize("kwargs, match", [
    (dict(path="s.obj"), r"unknown extension '\.obj'.*\.stl, \.ply, \.glb"),
    (dict(path="s.stl", unit="mm"), r"`unit` must be one of \['m', 'nm'\]"),
    (dict(path="s.stl", resolution=1), "resolution.*2..4096"),
    (dict(path="s.stl", resolution=(10, 2.5)), "resolution"),
    (dict(path="s.stl", solid=True, base=1.0), "below the lowest point"),
    (dict(path="no/such/dir/s.stl"), "does not exist"),
])
def test_bad_export_requests_are_refused(tmp_path, rng, kwargs, match):
    s = bumpy(rng)
    kwargs = dict(kwargs)
    path = tmp_path / kwargs.pop("path")
    with pytest.raises(ExportError, match=match):
        export_surface(s, path, **kwargs)
    assert not list(tmp_path.rglob("*.*"))


def test_not_a_surface_is_refused():
    with pytest.raises(ExportError, match="must be a BSplineSurface"):
        surface_mesh(np.zeros((4, 4)), 4)


def test_failed_write_leaves_no_file(tmp_path, rng, monkeypatch):
    s = bumpy(rng)
    target = tmp_path / "s.stl"
    export_surface(s, target, 10)
    good = target.read_bytes()

    def boom(self, *a, **k):
        raise OSError("disk full")

    monkeypatch.setattr(trimesh.Trimesh, "export", boom)
    with pytest.raises(OSError, match="disk full"):
        export_surface(s, target, 12)
    assert target.read_bytes() == good  # the old file is untouched, no partial file
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.stl"]
