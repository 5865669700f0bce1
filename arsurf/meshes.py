r"""Triangle meshes of the probe and of nano-objects (trimesh), and the files in meshes/.

Dimensions are given in metres (SI, like the rest of arsurf); every builder returns a watertight
:class:`trimesh.Trimesh` whose coordinates are in **nanometres** (``mesh.units ==
"nanometers"``; ``mesh.convert_units("meters")`` gives SI). The conversion happens here, at the
edge to trimesh, because trimesh's tolerances are absolute (``trimesh.tol.zero`` = 1e-12,
``trimesh.tol.merge`` = 1e-8): a nanometre object in metres has zero face normals and its
vertices collapse whenever trimesh processes it. The meshes are in the *probe frame*: the origin is the centre of the tip's apex sphere (the sphere the contact model
uses), +z points up along the tip axis, away from the sample, and the cantilever runs along x
with its free end towards +x. The pieces therefore assemble without transforms:

- :func:`spherical_tip` - the model tip itself, a sphere of radius R;
- :func:`pyramidal_tip` - an n-sided pyramid whose faces are tangent to the apex sphere, i.e. a
  pyramid of half-angle θ with its apex rounded off by the sphere (the convex hull of the sphere
  and the pyramid's top polygon);
- :func:`cantilever` - the rectangular beam whose underside sits at the tip height;
- :func:`nanotube` - a capsule (cylinder with hemispherical caps) along x, centred at the origin,
  the same shape :func:`arsurf.synthetic.nanotubes` draws into a height map.

Files (:func:`write_meshes`, ``python -m arsurf.meshes meshes/``) are binary STL in
nanometres too: STL has no unit field, and viewers and slicers handle numbers of order 1-10⁴
well but lose 10⁻⁹-sized ones below their tolerances. :func:`load_mesh` reads them back.

Geometry of the pyramidal tip: a face with outward normal
:math:`\mathbf n_k = (\cos θ\,\mathbf e_k, -\sin θ)` (:math:`\mathbf e_k` horizontal, θ the angle
between face and axis) is the plane :math:`\mathbf n_k\cdot\mathbf x = R`, tangent to the apex
sphere; the sharp apex of those planes would sit at :math:`z = -R/\sin θ`, the rounded one at
:math:`z = -R`. The half-width of the top polygon (apothem) at height H is
:math:`(H \sin θ + R)/\cos θ`.

Sources: default dimensions of the cantilever from [Bolopion] (L = 220 µm, w = 27 µm,
t = 2.9 µm); tip height and side angle from the datasheet of a common silicon tapping-mode
probe (Bruker RTESPA-300: tip height 10-15 µm, side angle 20°, tip radius 8-12 nm).

Examples
--------
>>> from arsurf.meshes import pyramidal_tip
>>> tip = pyramidal_tip(apex_radius=20e-9, height=2e-6)
>>> tip.is_watertight, round(float(tip.bounds[0, 2]), 6), tip.units   # nanometres
(True, -20.0, 'nanometers')
"""
from __future__ import annotations

import math
import os
import sys
from pathlib import Path

import numpy as np

from arsurf import _validation
from arsurf._files import write_bytes
from arsurf.errors import MeshError, require

__all__ = [
    "MeshError",
    "MESH_FILES",
    "MESH_SCALE",
    "spherical_tip",
    "pyramidal_tip",
    "cantilever",
    "nanotube",
    "probe_meshes",
    "write_meshes",
    "load_mesh",
]

# Defaults, with where each comes from.
TIP_RADIUS = 20e-9  #: apex radius, m (a worn Si tip; new ones are 8-12 nm, Bruker RTESPA datasheet)
TIP_HEIGHT = 12e-6  #: tip height, m (Bruker RTESPA-300: 10-15 µm)
TIP_HALF_ANGLE = math.radians(20.0)  #: face-to-axis angle, rad (RTESPA-300 side angle 20°)
CANTILEVER_LENGTH = 220e-6  #: m, [Bolopion]
CANTILEVER_WIDTH = 27e-6  #: m, [Bolopion]
CANTILEVER_THICKNESS = 2.9e-6  #: m, [Bolopion]
TIP_SETBACK = 15e-6  #: distance of the tip axis from the free end, m (RTESPA-300: 15 ± 5 µm)
TUBE_RADIUS = 7.5e-9  #: m, a 15 nm MWCNT ([MWCNT] manipulates 10-20 nm tubes)
TUBE_LENGTH = 500e-9  #: m, axis end to end, caps excluded

#: Coordinates of the trimesh objects and files per metre (nanometres).
MESH_SCALE = 1e9
MESH_UNITS = "nanometers"

#: The files in meshes/ (name -> file name) and what they hold.
MESH_FILES = {
    "tip_sphere": "tip_sphere.stl",
    "tip_pyramid": "tip_pyramid.stl",
    "cantilever": "cantilever.stl",
    "nanotube": "nanotube.stl",
}


def _trimesh():
    return require("trimesh", "mesh", "building probe and nano-object meshes")


def _nm(mesh, length: float):
    """Scale a mesh built in units of ``length`` (metres) to nanometres and label it.

    Shapes are built at unit size because trimesh's tolerances are absolute."""
    mesh.apply_scale(length * MESH_SCALE)
    mesh.units = MESH_UNITS
    return mesh


def _positive(name: str, value, what: str) -> float:
    return _validation.positive(value, name, MeshError, hint=f"it is {what}")


def spherical_tip(radius: float = TIP_RADIUS, subdivisions: int = 3):
    """The model tip: an icosphere of the given radius centred at the origin.

    Parameters
    ----------
    radius : float, metres
    subdivisions : int
        Icosphere refinement (3 gives 1280 triangles; the faceting error is ~0.3 % of R).

    Returns
    -------
    trimesh.Trimesh, nanometres, watertight.

    Examples
    --------
    >>> round(float(spherical_tip(10e-9).bounds[1, 0]), 6)
    10.0
    """
    trimesh = _trimesh()
    r = _positive("radius", radius, "the tip radius in metres")
    if int(subdivisions) != subdivisions or not 0 <= subdivisions <= 6:
        raise MeshError(f"`subdivisions` must be an integer in 0..6 (got {subdivisions!r})")
    return _nm(trimesh.creation.icosphere(subdivisions=int(subdivisions), radius=1.0), r)


def pyramidal_tip(apex_radius: float = TIP_RADIUS, height: float = TIP_HEIGHT,
                  half_angle: float = TIP_HALF_ANGLE, sides: int = 4, cap_resolution: int = 4):
    r"""An n-sided pyramidal tip whose apex is rounded by the apex sphere (centre at the origin).

    The solid is the convex hull of the apex sphere and the top polygon at z = H; its faces are
    the planes :math:`\mathbf n_k\cdot\mathbf x = R` with
    :math:`\mathbf n_k = (\cos θ\,\mathbf e_k, -\sin θ)`, tangent to the sphere, so near the
    apex the mesh *is* the model sphere and further up it is the pyramid.

    Parameters
    ----------
    apex_radius : float, metres
        R, the radius of the sphere the contact model uses.
    height : float, metres
        H, from the sphere centre to the base of the pyramid (where the cantilever is).
    half_angle : float, rad
        θ, the angle between each face and the axis (0 < θ < π/2).
    sides : int
        Number of faces (4 for the usual Si/Si3N4 tips, 3 for some).
    cap_resolution : int
        Icosphere subdivisions used for the rounded apex.

    Returns
    -------
    trimesh.Trimesh, nanometres, watertight and convex; lowest point at z = -R.

    Examples
    --------
    >>> t = pyramidal_tip(10e-9, height=1e-6)
    >>> round(float(t.bounds[1, 2]), 6)
    1000.0
    """
    trimesh = _trimesh()
    r = _positive("apex_radius", apex_radius, "the radius of the rounded apex in metres")
    h = _positive("height", height, "the tip height above the apex-sphere centre in metres")
    th = _positive("half_angle", half_angle, "the face-to-axis angle in radians")
    if th >= math.pi / 2:
        raise MeshError(f"`half_angle` must be below pi/2 (got {half_angle!r} rad); it is in radians, not degrees")
    if int(sides) != sides or sides < 3:
        raise MeshError(f"`sides` must be an integer >= 3 (got {sides!r})")
    if h <= 2.0 * r:
        raise MeshError(f"`height` ({h:g} m) must exceed twice the apex radius ({r:g} m) for a pyramid to show")
    sides = int(sides)
    # built in units of R, then scaled: trimesh's tolerances are absolute (merge 1e-8)
    hr = h / r
    apothem = (hr * math.sin(th) + 1.0) / math.cos(th)
    circum = apothem / math.cos(math.pi / sides)
    # faces centred on the +x, +y, ... directions: corners halfway between
    ang = (np.arange(sides) + 0.5) * 2.0 * math.pi / sides
    top = np.column_stack([circum * np.cos(ang), circum * np.sin(ang), np.full(sides, hr)])
    sphere = trimesh.creation.icosphere(subdivisions=int(cap_resolution), radius=1.0).vertices
    # only the lower cap can be on the hull: a point with normal m is on it when m_z < sin(theta)
    cap = sphere[sphere[:, 2] < math.sin(th) + 1e-9]
    # the exact tangent points n_k make every face the exact plane n_k . x = R (the inscribed
    # icosphere alone would tilt and split the faces)
    face_dir = np.arange(sides) * 2.0 * math.pi / sides
    tangent = np.column_stack([math.cos(th) * np.cos(face_dir), math.cos(th) * np.sin(face_dir),
                               np.full(sides, -math.sin(th))])
    mesh = trimesh.convex.convex_hull(np.vstack([cap, tangent, top]))
    mesh.fix_normals()
    return _nm(mesh, r)


def cantilever(length: float = CANTILEVER_LENGTH, width: float = CANTILEVER_WIDTH,
               thickness: float = CANTILEVER_THICKNESS, tip_height: float = TIP_HEIGHT,
               tip_setback: float = TIP_SETBACK):
    """The rectangular beam of the probe, placed over a tip whose apex-sphere centre is the origin.

    The beam spans x in [tip_setback - length, tip_setback] (free end at +x), y in ±width/2 and
    z in [tip_height, tip_height + thickness].

    Parameters
    ----------
    length, width, thickness : float, metres
        Beam dimensions (defaults from [Bolopion]).
    tip_height : float, metres
        Height of the underside of the beam above the apex-sphere centre (the tip height).
    tip_setback : float, metres
        Distance from the tip axis to the free end (0 <= setback < length).

    Returns
    -------
    trimesh.Trimesh, nanometres, a watertight box (12 triangles).

    Examples
    --------
    >>> b = cantilever(100e-6, 30e-6, 2e-6, tip_height=10e-6, tip_setback=5e-6)
    >>> [round(float(v), 6) for v in b.bounds[:, 0]]   # nm
    [-95000.0, 5000.0]
    """
    trimesh = _trimesh()
    L = _positive("length", length, "the cantilever length in metres")
    w = _positive("width", width, "the cantilever width in metres")
    t = _positive("thickness", thickness, "the cantilever thickness in metres")
    h = _positive("tip_height", tip_height, "the tip height in metres")
    try:
        s = float(tip_setback)
    except (TypeError, ValueError):
        raise MeshError(f"`tip_setback` must be a number (got {tip_setback!r})") from None
    if not (math.isfinite(s) and 0.0 <= s < L):
        raise MeshError(f"`tip_setback` must be in [0, length) = [0, {L:g}) m (got {tip_setback!r})")
    bounds = np.array([[s - L, -0.5 * w, h], [s, 0.5 * w, h + t]]) * MESH_SCALE
    mesh = trimesh.creation.box(bounds=bounds)
    mesh.units = MESH_UNITS
    return mesh


def nanotube(length: float = TUBE_LENGTH, radius: float = TUBE_RADIUS, sections: int = 32):
    """A nanotube as a capsule along x centred at the origin: a cylinder of the given length
    (axis end to end, caps excluded, as in :func:`arsurf.synthetic.nanotubes`) with hemispherical
    caps, total extent length + 2 radius.

    Parameters
    ----------
    length : float, metres
        Cylinder length (0 allowed: a sphere).
    radius : float, metres
    sections : int
        Facets around the axis.

    Returns
    -------
    trimesh.Trimesh, nanometres, watertight.

    Examples
    --------
    >>> t = nanotube(100e-9, 5e-9)
    >>> [round(float(v), 6) for v in t.bounds[:, 0]]
    [-55.0, 55.0]
    """
    trimesh = _trimesh()
    r = _positive("radius", radius, "the tube radius in metres")
    try:
        L = float(length)
    except (TypeError, ValueError):
        raise MeshError(f"`length` must be a number (got {length!r})") from None
    if not (math.isfinite(L) and L >= 0.0):
        raise MeshError(f"`length` must be >= 0 and finite (got {length!r}); it is the tube axis length in metres")
    if int(sections) != sections or sections < 6:
        raise MeshError(f"`sections` must be an integer >= 6 (got {sections!r})")
    # trimesh's capsule runs along z with `height` = distance between the cap centres
    to_x = np.array([[0, 0, 1, 0], [0, 1, 0, 0], [-1, 0, 0, 0], [0, 0, 0, 1]], dtype=float)
    mesh = trimesh.creation.capsule(height=L / r, radius=1.0, count=[int(sections), int(sections)], transform=to_x)
    return _nm(mesh, r)


def probe_meshes(apex_radius: float = TIP_RADIUS, tip_height: float = TIP_HEIGHT, **cantilever_kw) -> dict:
    """The default probe as {"tip_sphere", "tip_pyramid", "cantilever"} meshes in one frame."""
    return {
        "tip_sphere": spherical_tip(apex_radius),
        "tip_pyramid": pyramidal_tip(apex_radius, tip_height),
        "cantilever": cantilever(tip_height=tip_height, **cantilever_kw),
    }


def _default_meshes() -> dict:
    meshes = probe_meshes()
    meshes["nanotube"] = nanotube()
    return meshes


def write_meshes(folder: str | os.PathLike) -> list[Path]:
    """Write the default meshes as binary STL in nanometres (:data:`MESH_FILES`) into ``folder``.

    Files are written to a temporary name and renamed, so an interrupted run leaves no partial
    file. Returns the paths written.

    Examples
    --------
    >>> import tempfile
    >>> paths = write_meshes(tempfile.mkdtemp())
    >>> sorted(p.name for p in paths)
    ['cantilever.stl', 'nanotube.stl', 'tip_pyramid.stl', 'tip_sphere.stl']
    """
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, mesh in _default_meshes().items():
        path = out / MESH_FILES[name]
        write_bytes(path, mesh.export(file_type="stl"), what="mesh file", error=MeshError)
        paths.append(path)
    return paths


def load_mesh(path: str | os.PathLike):
    """Read a mesh file in nanometres (meshes/, :func:`arsurf.export.export_surface`) as a Trimesh
    with ``units = "nanometers"`` (``.convert_units("meters")`` for SI)."""
    trimesh = _trimesh()
    p = Path(path)
    if not p.is_file():
        raise MeshError(f"mesh file {str(p)!r} does not exist; regenerate meshes/ with `python -m arsurf.meshes meshes`")
    mesh = trimesh.load(p, force="mesh")
    mesh.units = MESH_UNITS
    return mesh


if __name__ == "__main__":  # python -m arsurf.meshes [folder]
    for written in write_meshes(sys.argv[1] if len(sys.argv) > 1 else "meshes"):
        print(written)
