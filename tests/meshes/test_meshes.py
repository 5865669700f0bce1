"""Probe and nano-object meshes (arsurf.meshes) and the files in meshes/."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

trimesh = pytest.importorskip("trimesh", reason="the [mesh] extra (trimesh) is not installed")

from arsurf import meshes  # noqa: E402
from arsurf.meshes import MeshError  # noqa: E402

MESH_DIR = Path(__file__).resolve().parents[2] / "meshes"


NM = 1e9  # the meshes are in nanometres (trimesh's tolerances are absolute)


def test_spherical_tip_is_a_closed_sphere():
    r = 20.0
    s = meshes.spherical_tip(r / NM)
    assert s.units == "nanometers"
    assert s.is_watertight and s.is_winding_consistent
    dist = np.linalg.norm(s.vertices, axis=1)
    np.testing.assert_allclose(dist, r, rtol=1e-12)  # every vertex on the sphere
    # an inscribed icosphere (1280 faces) falls short of 4/3 pi r^3 by < 1 %
    v = 4.0 / 3.0 * math.pi * r**3
    assert 0.98 * v < s.volume < v


def _big_faces(mesh, n):
    order = np.argsort(mesh.area_faces)[::-1][:n]
    return mesh.face_normals[order], mesh.triangles[order, 0]


def test_pyramidal_tip_faces_are_tangent_to_the_apex_sphere():
    r, h, th = 20.0, 2000.0, math.radians(20.0)
    t = meshes.pyramidal_tip(r / NM, h / NM, th, sides=4)
    assert t.is_watertight and t.is_convex and t.volume > 0
    # the four largest triangles are the faces: normal (cos th e_k, -sin th), plane n.x = R
    normals, points = _big_faces(t, 6)
    sides = [(n, p) for n, p in zip(normals, points) if n[2] < 0]
    assert len(sides) == 4
    for n, p in sides:
        assert n[2] == pytest.approx(-math.sin(th), abs=1e-9)
        assert float(np.dot(n, p)) == pytest.approx(r, rel=1e-9)
    dirs = sorted(round(math.degrees(math.atan2(n[1], n[0]))) % 360 for n, _ in sides)
    assert dirs == [0, 90, 180, 270]
    # rounded apex at -R (on the sphere), flat top at H whose apothem is (H sin th + R)/cos th
    assert t.bounds[0, 2] == pytest.approx(-r, rel=1e-12)
    assert t.bounds[1, 2] == pytest.approx(h, rel=1e-12)
    apothem = (h * math.sin(th) + r) / math.cos(th)
    assert t.bounds[1, 0] == pytest.approx(apothem, rel=1e-9)
    # near the apex the mesh is the sphere: vertices below the faces' tangent circle lie on it
    low = t.vertices[t.vertices[:, 2] < -r * math.sin(th) - 1e-3 * r]
    assert len(low) > 20
    np.testing.assert_allclose(np.linalg.norm(low, axis=1), r, rtol=1e-9)


@settings(max_examples=15, deadline=None)
@given(r=st.floats(2.0, 100.0), ratio=st.floats(5.0, 2000.0), deg=st.floats(5.0, 45.0), sides=st.integers(3, 6))
def test_pyramidal_tip_properties(r, ratio, deg, sides):
    t = meshes.pyramidal_tip(r / NM, r * ratio / NM, math.radians(deg), sides=sides)
    assert t.is_watertight and t.is_winding_consistent
    assert t.bounds[0, 2] == pytest.approx(-r, rel=1e-9)
    assert t.bounds[1, 2] == pytest.approx(r * ratio, rel=1e-9)
    # nothing pokes out of the face planes n_k . x <= R (convex body tangent to the sphere)
    phi = np.arange(sides) * 2 * math.pi / sides
    th = math.radians(deg)
    n = np.column_stack([math.cos(th) * np.cos(phi), math.cos(th) * np.sin(phi), np.full(sides, -math.sin(th))])
    assert (t.vertices @ n.T).max() <= r * (1 + 1e-9)


def test_cantilever_box_and_tip_offset():
    b = meshes.cantilever(200e-6, 30e-6, 3e-6, tip_height=12e-6, tip_setback=15e-6)
    assert b.is_watertight
    um = 1e3  # nm per micrometre
    np.testing.assert_allclose(b.bounds, np.array([[-185, -15, 12], [15, 15, 15]]) * um, rtol=1e-12)
    assert b.volume == pytest.approx(200 * 30 * 3 * um**3, rel=1e-12)
    # the default probe assembles: beam underside at the tip's top
    parts = meshes.probe_meshes()
    assert parts["cantilever"].bounds[0, 2] == pytest.approx(parts["tip_pyramid"].bounds[1, 2], rel=1e-12)


def test_nanotube_is_a_capsule():
    L, r = 300.0, 6.0
    t = meshes.nanotube(L / NM, r / NM)
    assert t.is_watertight
    np.testing.assert_allclose(t.bounds, [[-L / 2 - r, -r, -r], [L / 2 + r, r, r]], rtol=1e-9, atol=1e-9)
    v = math.pi * r**2 * L + 4.0 / 3.0 * math.pi * r**3
    assert 0.97 * v < t.volume <= v  # polygonal sections are inscribed
    # every vertex is at distance r from the axis segment
    x = np.clip(t.vertices[:, 0], -L / 2, L / 2)
    d = np.linalg.norm(t.vertices - np.column_stack([x, 0 * x, 0 * x]), axis=1)
    np.testing.assert_allclose(d, r, rtol=1e-9)


@pytest.mark.parametrize("call, match", [
    (lambda: meshes.spherical_tip(-1e-9), "radius.*positive"),
    (lambda: meshes.pyramidal_tip(20e-9, half_angle=20.0), "half_angle.*radians, not degrees"),
    (lambda: meshes.pyramidal_tip(20e-9, height=30e-9), "height.*twice the apex radius"),
    (lambda: meshes.pyramidal_tip(20e-9, sides=2), "sides.*>= 3"),
    (lambda: meshes.cantilever(100e-6, tip_setback=100e-6), r"tip_setback.*\[0, length\)"),
    (lambda: meshes.nanotube(-1e-9, 5e-9), "length.*>= 0"),
    (lambda: meshes.nanotube(1e-7, float("nan")), "radius.*positive"),
])
def test_bad_dimensions_are_refused(call, match):
    with pytest.raises(MeshError, match=match):
        call()


def test_written_files_match_the_committed_meshes(tmp_path):
    paths = meshes.write_meshes(tmp_path)
    assert sorted(p.name for p in paths) == sorted(meshes.MESH_FILES.values())
    assert not list(tmp_path.glob("*.part"))
    total = 0
    for p in paths:
        committed = MESH_DIR / p.name
        assert committed.is_file(), f"{committed} is missing: regenerate with python -m arsurf.meshes meshes"
        total += committed.stat().st_size
        new = trimesh.load(p, force="mesh")
        old = trimesh.load(committed, force="mesh")
        assert new.is_watertight and old.is_watertight
        np.testing.assert_allclose(np.sort(old.vertices, axis=0), np.sort(new.vertices, axis=0), atol=1e-3)
    assert total < 1_000_000
    assert "nanometres" in (MESH_DIR / "README.md").read_text()


def test_load_mesh_reads_the_nanometre_files(tmp_path):
    meshes.write_meshes(tmp_path)
    tip = meshes.load_mesh(tmp_path / meshes.MESH_FILES["tip_pyramid"])
    ref = meshes.pyramidal_tip()
    assert tip.units == "nanometers"
    np.testing.assert_allclose(tip.bounds, ref.bounds, rtol=1e-6)  # STL stores float32
    np.testing.assert_allclose(ref.bounds[:, 2], [-meshes.TIP_RADIUS * NM, meshes.TIP_HEIGHT * NM], rtol=1e-12)
    si = tip.copy()
    si.convert_units("meters")
    np.testing.assert_allclose(si.bounds, ref.bounds / NM, rtol=1e-6)
    with pytest.raises(MeshError, match="does not exist"):
        meshes.load_mesh(tmp_path / "nope.stl")
