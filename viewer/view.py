r"""The 3D view of the live model: deformed surface, tip, contact, force arrow and HUD (pyvista).

:class:`SurfaceView` builds every actor once and :meth:`SurfaceView.update` changes them in
place from a :class:`~arsurf_viewer.state.SceneState` (points and scalars written into the
existing VTK arrays, actors moved with their ``user_matrix``, text set), so a frame costs the
re-sampling of the changed part of the surface (:mod:`arsurf_viewer.patch`: the patch of
samples over the control points the dents moved, its deformed box and the dent's contour lines
there) plus one render.

**The scene is in nanometres**: the engine's metres are multiplied by 1e9 at this edge. VTK's
camera, clipping planes and picking use absolute tolerances tuned for coordinates of order
1-10⁴; a 500 nm scan in metres (5e-7) breaks them. :meth:`SurfaceView.world_to_pixel` takes
metres and does the conversion itself.

What is drawn
    * ``surface`` - S(u, v) sampled on a regular (u, v) grid (a ``pyvista.StructuredGrid``) with
      the exact normals :math:`\mathbf n = S_u \times S_v / |S_u \times S_v|` for smooth shading,
      coloured by height z (nm, in the 2D figures' colour map, :data:`arsurf._figure_style.HEIGHT_CMAP`,
      between the 1st and 99th percentiles of the rest surface, computed once per scan: a scratch
      does not wash the sample out) or by deformation :math:`|S(u, v) - S_{rest}(u, v)|` (nm, from
      a rest copy evaluated once; from 0 to a 1-2-5 value at or above the deepest dent seen, grown
      only when a dent goes deeper). Frames never recompute the limits:
      :meth:`SurfaceView.refresh_color_limits` does, on demand.
    * ``tip`` - the tip sphere (translucent, so the dent under it shows).
    * ``contact`` - the contact point and the normal there (green arrow, length 1.8 R).
    * ``force`` - the force on the tip, a magenta arrow from the tip surface along F, of length
      :math:`L = 2R \log_2(1 + |F| / F_0)` (F₀ = ``force_scale``, 1 nN by default: 1 nN → 2R,
      3 nN → 4R, 1 µN → 20R), hidden when :math:`|F| <` ``force_threshold``.
    * ``hud`` - F components in nN, :math:`|F|`, depth and contact radius in nm, λ, loop rate, device.
    * ``probe`` (off by default) - the pyramidal tip and the cantilever, drawn schematically:
      truncated at ``probe_height`` (default 1.5 × the scan size), since a real tip (10-15 µm) and
      cantilever (~200 µm) dwarf a sub-micron scan.
    * ``dent`` - the deformation as contour lines over the surface (every :math:`\Delta` nm of
      :math:`|S - S_{rest}|`, :math:`\Delta` = 1, 2 or 5 x 10^k, about a quarter of the deepest
      dent, named in the HUD), so the topography's colours stay visible under the dent.
    * ``tubes`` - nano-objects (capsules) from the state.
    * ``colorbar`` - the colour scale, its unit in the title, ticks at round values
      (:func:`arsurf._figure_style.round_ticks`).
    * ``scalebar`` - a bar of a round length (:func:`arsurf._figure_style.scale_bar_length` of the
      scan's width) along the scan's front edge, labelled in nm or µm, and a caption line
      (bottom left) saying the bar's length and the vertical exaggeration (none: z is drawn to scale).

Saved pictures (an off-screen view: :meth:`~SurfaceView.screenshot` to a file, the demo's views,
replay frames) leave the HUD out unless ``layers={"hud": True}``: its box would cover the scene.
``window_size`` sets the picture's pixels and ``screenshot(path, dpi=...)`` the resolution the
PNG states (e.g. 2100 x 1500 px at 300 dpi: 7 x 5 in).

Examples
--------
>>> import numpy as np
>>> from arsurf.spline.surface import BSplineSurface, merge_boxes
>>> from arsurf_viewer import SceneState, SurfaceView
>>> s = BSplineSurface.from_heights(np.zeros((8, 8)), (0.0, 100e-9), (0.0, 100e-9))
>>> view = SurfaceView(s, off_screen=True, window_size=(320, 240))
>>> view.update(SceneState(s, tip_center=(50e-9, 50e-9, 25e-9), tip_radius=20e-9))
>>> view.screenshot().shape
(240, 320, 3)
>>> view.close()
"""
from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from arsurf._figure_style import HEIGHT_CMAP, robust_limits, round_ticks, scale_bar_length
from arsurf._files import atomic_write
from arsurf.contact.mechanics import SMALL_CONTACT_LIMIT
from arsurf.errors import require
from arsurf.status import BEYOND_MODEL, flag_names
from arsurf.spline.surface import BSplineSurface, merge_boxes

from .backend import choose_backend
from .patch import changed_box, contour_patch, dent_boxes, sample_patch
from .state import SceneState
from arsurf.errors import ViewerError


__all__ = ["SurfaceView", "LAYERS", "COLORS", "SCENE_SCALE"]

#: Scene units per metre (the scene is in nanometres).
SCENE_SCALE = 1e9
#: Layers that :meth:`SurfaceView.set_layer` switches, and whether each is on by default.
LAYERS = {"surface": True, "tip": True, "contact": True, "force": True, "hud": True,
          "probe": False, "tubes": True, "colorbar": True, "dent": True, "scalebar": True}
#: Colours, chosen to be told apart from the 'magma' surface (black, purple, red, orange, cream: no
#: green, no blue brighter than its red by more than ~55 levels).
COLORS = {
    "tip": "#5aa9e6",  # steel blue, translucent
    "contact": "#fff275",
    "normal": "#2ecc40",  # green: g > r, b
    "force": "#1e6bff",  # blue: b >> r, g
    "probe": "#b8c4d0",
    "tubes": "#6b6b6b",
    "dent": "#00e5ff",  # cyan: b, g >> r
    "hud": "#f2f2f2",
    "background": "#202124",
    "background_top": "#4a4c50",
}
_SURFACE_CMAPS = {"height": HEIGHT_CMAP, "deformation": "YlOrBr", "modulus": "viridis", "adhesion": "plasma",
                  "sample_deformation": "cividis", "dissipation": "inferno"}
#: colour modes read from a material map (arsurf.contact.material_map): field, and the unit shown
#: for each unit the field may have (scale to the shown unit, title); a log colour scale for E*
_MATERIAL_MODES = {
    "modulus": ("reduced_modulus", {"Pa": (1e-9, "E* (GPa)")}, True),
    "adhesion": ("work_of_adhesion", {"J/m^2": (1e3, "w (mJ/m^2)")}, False),
    "sample_deformation": ("deformation", {"m": (1e9, "deformation (nm)")}, False),
    "dissipation": ("dissipation", {"J": (1.0 / 1.602176634e-19, "dissipation (eV)")}, False),
}


def _check_resolution(resolution) -> tuple[int, int]:
    vals = (resolution, resolution) if np.ndim(resolution) == 0 else tuple(np.ravel(resolution))
    try:
        nu, nv = (int(r) for r in vals)
    except (TypeError, ValueError):
        raise ViewerError(f"`resolution` must be an int or (nu, nv) samples (got {resolution!r})") from None
    if nu < 2 or nv < 2 or nu > 4096 or nv > 4096:
        raise ViewerError(f"`resolution` must be 2..4096 samples per axis (got {resolution!r})")
    return nu, nv


def _mono_font(name: str = "DejaVuSansMono.ttf") -> str | None:
    """A DejaVu font file from matplotlib (has λ, µ, ·, ±): Sans Mono by default, or None for VTK's
    built-in fonts."""
    try:
        import matplotlib

        path = os.path.join(matplotlib.get_data_path(), "fonts", "ttf", name)
        return path if os.path.isfile(path) else None
    except ImportError:
        return None


def _use_font(prop, name: str = "DejaVuSans.ttf") -> None:
    """Set a VTK text property to a DejaVu font file (µ renders), else VTK's Arial."""
    font = _mono_font(name)
    if font:
        prop.SetFontFamily(4)  # VTK_FONT_FILE
        prop.SetFontFile(font)
    else:
        prop.SetFontFamilyToArial()


def _length_label(nm: float) -> str:
    """A round length in nm as the 2D figures' scale bars write it: "200 nm", "1 µm"."""
    return f"{nm / 1000:g} µm" if nm >= 1000 else f"{nm:g} nm"


def _round_up(nm: float) -> float:
    """The smallest 1, 2 or 5 x 10^k nm at or above ``nm`` (at least 0.5 nm): a colour limit."""
    if nm <= 0.5:
        return 0.5
    k = math.floor(math.log10(nm))
    return min(m * 10.0 ** k for m in (1.0, 2.0, 5.0, 10.0) if m * 10.0 ** k >= nm * (1 - 1e-12))


def _frame(direction) -> np.ndarray:
    """3x3 rotation whose first column is the unit vector along ``direction`` (3,), in plain
    floats (numpy's cross product of two 3-vectors costs tens of µs: a frame places 3 frames)."""
    dx, dy, dz = (float(c) for c in direction)
    n = math.sqrt(dx * dx + dy * dy + dz * dz)
    dx, dy, dz = dx / n, dy / n, dz / n
    if abs(dz) < 0.9:  # a = d x (0, 0, 1)
        ax, ay, az = dy, -dx, 0.0
    else:  # a = d x (1, 0, 0)
        ax, ay, az = 0.0, dz, -dy
    n = math.sqrt(ax * ax + ay * ay + az * az)
    ax, ay, az = ax / n, ay / n, az / n
    bx, by, bz = dy * az - dz * ay, dz * ax - dx * az, dx * ay - dy * ax  # b = d x a
    return np.array(((dx, ax, bx), (dy, ay, by), (dz, az, bz)))


def _set_user_matrix(actor, m: np.ndarray) -> None:
    """Set an actor's user matrix to ``m`` (4, 4) by writing into its vtkMatrix4x4 (pyvista's
    ``user_matrix`` setter validates and builds a new matrix each time)."""
    mat = actor.GetUserMatrix()
    if mat is None:
        from vtkmodules.vtkCommonMath import vtkMatrix4x4

        mat = vtkMatrix4x4()
        actor.SetUserMatrix(mat)
    mat.DeepCopy(m.ravel().tolist())


class _Arrow:
    """An arrow as two actors (shaft cylinder, head cone) whose sizes are set independently,
    so long arrows keep a fixed head and thickness."""

    def __init__(self, plotter, pv, color: str):
        shaft = pv.Cylinder(center=(0.5, 0.0, 0.0), direction=(1.0, 0.0, 0.0), radius=1.0, height=1.0,
                            resolution=24, capping=True)
        head = pv.Cone(center=(0.5, 0.0, 0.0), direction=(1.0, 0.0, 0.0), height=1.0, radius=1.0,
                       resolution=24, capping=True)
        kw = dict(color=color, smooth_shading=True, specular=0.3, ambient=0.25, reset_camera=False,
                  pickable=False)
        self.shaft = plotter.add_mesh(shaft, **kw)
        self.head = plotter.add_mesh(head, **kw)
        self.actors = (self.shaft, self.head)

    def place(self, start: np.ndarray, direction: np.ndarray, length: float, width: float) -> None:
        rot = _frame(direction)
        head_len = min(0.45 * length, 3.5 * width)
        shaft_len = length - head_len
        m = np.eye(4)
        m[:3, :3] = rot * np.array([shaft_len, width, width])
        m[:3, 3] = start
        _set_user_matrix(self.shaft, m)
        m2 = np.eye(4)
        m2[:3, :3] = rot * np.array([head_len, 2.2 * width, 2.2 * width])
        m2[:3, 3] = start + rot[:, 0] * shaft_len
        _set_user_matrix(self.head, m2)

    def set_visible(self, on: bool) -> None:
        for a in self.actors:
            a.SetVisibility(bool(on))


class SurfaceView:
    """A pyvista scene of the model that updates in place (see the module notes).

    Parameters
    ----------
    surface : BSplineSurface
        The surface to show (the same object the loop deforms).
    resolution : int or (nu, nv)
        Samples of S(u, v) along u and v (default 128 per axis, capped by 4 per control point).
    color_by : {"height", "deformation", "modulus", "adhesion", "sample_deformation", "dissipation"}
        The last four need ``material``: E* (GPa, log scale), w (mJ/m^2), and the instrument's
        deformation and dissipation maps where measured (in their unit: nm, eV, or the channel's
        own when the file leaves it uncalibrated), each with its colour bar.
    material : MaterialMap, optional
        The sample's material map (:mod:`arsurf.contact.material_map`), in the surface's frame.
    off_screen : bool, optional
        Render without a window; default: True when there is no display.
    window_size : (width, height) pixels
    camera : {"oblique", "top"}
        Initial camera: a perspective view from the front-left, or a top-down parallel view.
    tip_opacity : float
        Opacity of the tip sphere (translucent by default so the dent shows through it).
    force_scale : float, newtons
        F₀ of the arrow length law (see the module notes).
    force_threshold : float, newtons
        Below this :math:`|F|` the arrow is hidden.
    probe_height : float, metres, optional
        Height at which the schematic pyramid/cantilever (layer ``probe``) are cut.
    layers : dict[str, bool], optional
        Initial visibility per layer (defaults: :data:`LAYERS`).
    anti_aliasing : {"auto", None, "fxaa", "msaa", "ssaa"}
        "auto": FXAA with a display (a GPU, cheap), none on the headless software backends
        (EGL/OSMesa with Mesa's llvmpipe, where SSAA multiplies the ~0.1 s frame by ~5); pass
        "ssaa" for the best still pictures.
    """

    def __init__(self, surface: BSplineSurface, *, resolution=128, color_by: str = "height", material=None,
                 off_screen: bool | None = None, window_size=(960, 720), camera: str = "oblique",
                 tip_opacity: float = 0.55, force_scale: float = 1e-9, force_threshold: float = 1e-12,
                 probe_height: float | None = None, layers: dict | None = None, anti_aliasing: str | None = "auto",
                 title: str = "arsurf"):
        if not isinstance(surface, BSplineSurface):
            raise ViewerError(f"`surface` must be a BSplineSurface (got {type(surface).__name__})")
        if color_by not in _SURFACE_CMAPS:
            raise ViewerError(f"`color_by` must be one of {sorted(_SURFACE_CMAPS)} (got {color_by!r})")
        if camera not in ("oblique", "top"):
            raise ViewerError(f"`camera` must be 'oblique' or 'top' (got {camera!r})")
        for name, val in (("force_scale", force_scale), ("force_threshold", force_threshold)):
            if not (isinstance(val, (int, float)) and math.isfinite(val) and val > 0):
                raise ViewerError(f"`{name}` must be a positive force in newtons (got {val!r})")
        if not (0.0 < float(tip_opacity) <= 1.0):
            raise ViewerError(f"`tip_opacity` must be in (0, 1] (got {tip_opacity!r})")
        if anti_aliasing not in ("auto", None, "fxaa", "msaa", "ssaa"):
            raise ViewerError(f"`anti_aliasing` must be 'auto', None, 'fxaa', 'msaa' or 'ssaa' (got {anti_aliasing!r})")
        w, h = (int(v) for v in window_size)
        if w < 16 or h < 16:
            raise ViewerError(f"`window_size` must be at least 16 x 16 pixels (got {window_size!r})")
        self.material = material
        if color_by in _MATERIAL_MODES:
            self._material_field(color_by)  # refuse now, before any window opens
        self._requested_resolution = _check_resolution(resolution)
        self.backend = choose_backend()
        pv = require("pyvista", "viewer", "the 3D viewer")
        self._pv = pv
        if off_screen is None:
            off_screen = not self.backend.interactive
        self.off_screen = bool(off_screen)
        self.color_by = color_by
        self.force_scale = float(force_scale)
        self.force_threshold = float(force_threshold)
        self._tip_opacity = float(tip_opacity)
        self._probe_height = probe_height
        self._layers = dict(LAYERS)
        if self.off_screen:  # a saved picture: the HUD's box would cover the scene (layers={"hud": True} keeps it)
            self._layers["hud"] = False
        for name, on in (layers or {}).items():
            self._check_layer(name)
            self._layers[name] = bool(on)
        self.plotter = pv.Plotter(off_screen=self.off_screen, window_size=(w, h), title=title)
        self.plotter.set_background(COLORS["background"], top=COLORS["background_top"])
        if anti_aliasing == "auto":
            anti_aliasing = "fxaa" if self.backend.name in ("native", "x11", "xvfb") else None
        if anti_aliasing is not None:
            self.plotter.enable_anti_aliasing(anti_aliasing)
        self._tubes: list = []
        self._probe_actors: tuple = ()
        self._probe_radius = None
        self._last_state: SceneState | None = None
        self._build_surface(surface)
        self._build_markers()
        self._build_hud()
        self.set_camera(camera)
        self._apply_layers()

    # -- construction -------------------------------------------------------------------------
    def _check_layer(self, name: str) -> None:
        if name not in LAYERS:
            raise ViewerError(f"unknown layer {name!r}; layers are {', '.join(LAYERS)}")

    def _build_surface(self, surface: BSplineSurface) -> None:
        pv = self._pv
        nu_c, nv_c = surface.shape
        nu, nv = self._requested_resolution
        nu, nv = min(nu, 4 * nu_c), min(nv, 4 * nv_c)
        self.surface = surface
        self.resolution = (nu, nv)
        (u0, u1), (v0, v1) = surface.domain
        self._u = np.linspace(u0, u1, nu)
        self._v = np.linspace(v0, v1, nv)
        self._watch = surface.watch()  # what the deformers move from now on (a new watch: compare all once)
        ctrl, rest, ku, kv = surface.kernel_arrays()
        self._ku, self._kv = ku, kv
        self._last_ctrl = np.array(ctrl, copy=True)
        uu, vv = np.meshgrid(self._u, self._v)
        # the rest grid (nv, nu, 3) nm, by the frames' own kernel: a sample whose control points are at
        # rest is then bitwise its rest point, its deformation exactly 0 (the dent box stays the dent's)
        self._rest_points = np.zeros((nv, nu, 3))
        normals, height = np.empty((nv, nu, 3)), np.empty((nv, nu))
        sample_patch(rest, ku, kv, self._u, self._v, 0, nu, 0, nv, SCENE_SCALE, self._rest_points,
                     self._rest_points, normals, height, height)
        del normals, height
        grid = pv.StructuredGrid()
        grid.points = np.zeros((nu * nv, 3))
        grid.dimensions = (nu, nv, 1)
        grid.point_data["height_nm"] = np.zeros(nu * nv)
        grid.point_data["deformation_nm"] = np.zeros(nu * nv)
        grid.point_data["Normals"] = np.zeros((nu * nv, 3))
        grid.point_data.active_normals_name = "Normals"
        self.grid = grid
        # views into the VTK arrays: written in place every frame
        self._pts = grid.points.reshape(nv, nu, 3)
        self._height = grid.point_data["height_nm"].reshape(nv, nu)
        self._deform = grid.point_data["deformation_nm"].reshape(nv, nu)
        self._normals = grid.point_data["Normals"].reshape(nv, nu, 3)
        self._resample(0, nu, 0, nv)
        self._dent_found = np.empty((16, 5))  # dent_boxes' output: (iu0, iu1, jv0, jv1, top) per box
        self._find_dent([(0, nu, 0, nv)])  # the grid boxes (iu0, iu1, jv0, jv1) of the deformed samples
        self._material_clim = {}
        if self.material is not None:  # the material fields on the rest grid (they move with the surface)
            for mode, (name, units, log) in _MATERIAL_MODES.items():
                if name not in self.material.fields:
                    continue
                scale, _ = self._material_unit(mode)
                vals = np.asarray(self.material.values(name, uu, vv), dtype=np.float64) * scale
                grid.point_data[mode] = vals.ravel()
                lo, hi = (float(vals.min()), float(vals.max())) if log else (
                    float(np.percentile(vals, 1.0)), float(np.percentile(vals, 99.0)))
                if not hi > lo:
                    lo, hi = lo - 0.5 * abs(lo) - 1e-12, hi + 0.5 * abs(hi) + 1e-12
                self._material_clim[mode] = (lo, hi)
        zr = self._rest_points[..., 2]
        # the 2D figures' limits, once per scan (not per frame): the 1st and 99th percentiles
        lo, hi = robust_limits(zr)
        if hi - lo < 1e-3:
            lo, hi = lo - 1.0, hi + 1.0
        self._height_clim = (lo, hi)
        self._deform_clim = _round_up(self._dent_top)  # nm; grows with a deeper dent (_follow_dent_clim)
        self._extent_nm = max(u1 - u0, v1 - v0) * SCENE_SCALE
        self.surface_actor = self.plotter.add_mesh(
            grid, scalars="height_nm", cmap=_SURFACE_CMAPS["height"], clim=self._height_clim,
            show_scalar_bar=False, specular=0.25, specular_power=20.0, ambient=0.12, diffuse=0.9,
            reset_camera=False, pickable=False,
        )
        # pyvista sets flat shading unless it computes normals itself (on a copy, which would
        # break the in-place updates): use ours, the exact S_u x S_v, with Phong interpolation
        self.surface_actor.prop.interpolation = "phong"
        self._mapper = self.surface_actor.mapper
        size = max(10, int(self.plotter.window_size[1] / 40))
        bar_args = dict(title="height (nm)", vertical=True, position_x=0.87, position_y=0.14, height=0.62,
                        width=0.11, color=COLORS["hud"], title_font_size=size, label_font_size=size,
                        n_labels=5, fmt="%.1f", font_family="arial")
        self.scalar_bar = self.plotter.add_scalar_bar(mapper=self._mapper, **bar_args)
        # the same dark, translucent box as the HUD, so the labels read on a pale surface too
        self.scalar_bar.DrawBackgroundOn()
        self.scalar_bar.GetBackgroundProperty().SetColor(0.0, 0.0, 0.0)
        self.scalar_bar.GetBackgroundProperty().SetOpacity(0.45)
        self.scalar_bar.SetBarRatio(0.4)
        for prop in (self.scalar_bar.GetTitleTextProperty(), self.scalar_bar.GetLabelTextProperty()):
            prop.ShadowOn()
            _use_font(prop)
        self._bar_ticks = None
        self._build_legend()
        self._build_scale_bar()
        self.set_color_by(self.color_by)
        from vtkmodules.vtkCommonCore import vtkDoubleArray, vtkIdTypeArray, vtkPoints
        from vtkmodules.vtkCommonDataModel import vtkCellArray

        # the dent's lines: segments by marching squares on the deformed samples, their ends on
        # the surface, written into buffers the VTK arrays view (grown when a dent needs more);
        # the actor sits 0.1 nm above the surface
        self._dent_xyz = np.zeros((4096, 3))
        self._dent_ids = np.arange(4096, dtype=np.int64)  # a segment's two points, in order
        self._dent_starts = np.arange(0, 4097, 2, dtype=np.int64)  # where segment k's points start
        self._dent_coords = vtkDoubleArray()
        self._dent_coords.SetNumberOfComponents(3)
        self._dent_offsets, self._dent_connectivity = vtkIdTypeArray(), vtkIdTypeArray()
        self._dent_points, self._dent_cells = vtkPoints(), vtkCellArray()
        self._dent_points.SetData(self._dent_coords)
        self._dent_lines = pv.PolyData()
        self._dent_lines.SetPoints(self._dent_points)
        self._dent_lines.SetLines(self._dent_cells)
        self._set_dent_segments(0)
        self.dent_actor = self.plotter.add_mesh(self._dent_lines, color=COLORS["dent"], line_width=2.0, lighting=False,
                                                reset_camera=False, pickable=False)
        self.dent_actor.SetPosition(0.0, 0.0, 0.1)
        self.dent_step_nm = 0.0
        self._update_dent()

    def _find_dent(self, boxes) -> None:
        """Shrink :attr:`_dent_boxes` to the deformed samples inside ``boxes`` (disjoint grid boxes
        holding them all) and note their largest deformation: O(boxes), not O(grid)."""
        found, top = [], 0.0
        for box in boxes:
            n = dent_boxes(self._deform, *box, self._dent_found)
            if n > self._dent_found.shape[0]:
                self._dent_found = np.empty((2 * n, 5))
                n = dent_boxes(self._deform, *box, self._dent_found)
            for a0, a1, b0, b1, t in self._dent_found[:n].tolist():
                found.append((int(a0), int(a1), int(b0), int(b1)))
                top = max(top, t)
        self._dent_boxes, self._dent_top = found, top

    @property
    def _dent_box(self) -> tuple:
        """The bounding box (iu0, iu1, jv0, jv1) of the deformed samples ((0, 0, 0, 0): none)."""
        b = self._dent_boxes
        if not b:
            return (0, 0, 0, 0)
        return (min(x[0] for x in b), max(x[1] for x in b), min(x[2] for x in b), max(x[3] for x in b))

    def _update_dent(self) -> None:
        """Contour lines of the deformation (every :attr:`dent_step_nm` nm) on the surface, lifted
        0.1 nm off it; computed on the deformed samples (:attr:`_dent_boxes`) only, written in place
        into the lines' VTK arrays (:func:`~arsurf_viewer.patch.contour_patch`)."""
        top = self._dent_top
        if top < 0.02:  # nothing a reader could see: no lines
            self.dent_step_nm = 0.0
            if self._dent_segments:
                self._set_dent_segments(0)
            return
        k = math.floor(math.log10(top / 4.0))
        step = max(m * 10.0 ** k for m in (1.0, 2.0, 5.0) if m * 10.0 ** k <= top / 4.0 * (1 + 1e-12))
        self.dent_step_nm = step
        # one sample of margin each side: the lines close where the deformation falls to 0; boxes
        # whose margins meet are contoured as one (no cell twice)
        nu, nv = self.resolution
        boxes = merge_boxes([(max(a0 - 1, 0), min(a1 + 1, nu), max(b0 - 1, 0), min(b1 + 1, nv))
                             for a0, a1, b0, b1 in self._dent_boxes])
        levels = np.arange(1, int(top / step) + 1) * step
        n = self._contour(boxes, levels)
        if 2 * n > self._dent_xyz.shape[0]:  # more segments than ever before: room for twice as many
            self._dent_xyz = np.empty((4 * n, 3))
            self._dent_ids = np.arange(4 * n, dtype=np.int64)
            self._dent_starts = np.arange(0, 4 * n + 1, 2, dtype=np.int64)
            n = self._contour(boxes, levels)
        self._set_dent_segments(n)

    def _contour(self, boxes, levels) -> int:
        """Segments of the deformation's ``levels`` in each grid box, one after another into
        :attr:`_dent_xyz` (as far as it holds them); returns how many there are."""
        n = 0
        for a0, a1, b0, b1 in boxes:
            n += contour_patch(self._deform, self._pts, a0, a1, b0, b1, levels, self._dent_xyz[2 * n:])
        return n

    def _set_dent_segments(self, n: int) -> None:
        """Show the first ``n`` segments of :attr:`_dent_xyz` as the dent's lines: the VTK arrays
        point into the buffers (``SetVoidArray``, no copy), which the view keeps alive."""
        self._dent_segments = n
        xyz, ids = self._dent_xyz, self._dent_ids
        self._dent_coords.SetVoidArray(xyz, 3 * max(2 * n, 1), 1)  # a point even without lines (VTK needs one)
        self._dent_offsets.SetVoidArray(self._dent_starts, n + 1, 1)
        self._dent_connectivity.SetVoidArray(ids, 2 * n, 1)
        self._dent_points.Modified()
        self._dent_cells.SetData(self._dent_offsets, self._dent_connectivity)
        self._dent_lines.Modified()

    def _build_scale_bar(self, width: float | None = None, origin=None) -> None:
        """The ``scalebar`` layer: a white bar of :func:`~arsurf._figure_style.scale_bar_length` of
        ``width`` (nm) from ``origin`` (x, y, z nm) along x, its length written above it; by default
        the scan's width, just in front of its front edge on its lowest rest height, the length
        written under it; and the
        caption line (bottom left) with the bar's length and the vertical exaggeration."""
        from vtkmodules.vtkRenderingCore import vtkBillboardTextActor3D, vtkTextActor

        for actor in getattr(self, "_scale_actors", ()):
            self.plotter.remove_actor(actor, render=False)
        (u0, u1), (v0, _) = self.surface.domain
        on_surface = origin is not None  # a close-up's bar: its length above it, clear of the heights
        if width is None or origin is None:
            width = (u1 - u0) * SCENE_SCALE
            origin = (u0 * SCENE_SCALE + 0.04 * width, v0 * SCENE_SCALE - 0.04 * width,
                      float(self._rest_points[..., 2].min()))
        length = scale_bar_length(width)
        self.scale_bar_nm = length
        x0, y, z = (float(v) for v in origin)
        t = 0.004 * width
        bar = self.plotter.add_mesh(self._pv.Box(bounds=(x0, x0 + length, y - t, y + t, z - 0.5 * t, z + 0.5 * t)),
                                    color="white", lighting=False, reset_camera=False, pickable=False)
        h = self.plotter.window_size[1]
        label = vtkBillboardTextActor3D()
        label.SetInput(_length_label(length))
        if on_surface:
            label.SetPosition(x0 + 0.5 * length, y, z + 0.06 * width)
        else:  # in front of the scan: the length under the bar
            label.SetPosition(x0 + 0.5 * length, y - 5.0 * t, z)
        prop = label.GetTextProperty()
        _use_font(prop)
        prop.SetFontSize(max(10, int(h / 36)))
        prop.BoldOn()
        prop.SetColor(1.0, 1.0, 1.0)
        prop.ShadowOn()
        prop.SetJustificationToCentered()
        if on_surface:
            prop.SetVerticalJustificationToBottom()
        else:
            prop.SetVerticalJustificationToTop()
        self.plotter.add_actor(label, reset_camera=False, pickable=False)
        caption = vtkTextActor()
        caption.SetInput(self.caption)
        cprop = caption.GetTextProperty()
        _use_font(cprop)
        cprop.SetFontSize(max(9, int(h / 52)))
        cprop.SetColor(*self._pv.Color(COLORS["hud"]).float_rgb)
        cprop.SetVerticalJustificationToBottom()
        caption.GetPositionCoordinate().SetCoordinateSystemToNormalizedViewport()
        caption.GetPositionCoordinate().SetValue(0.015, 0.015)
        self.plotter.add_actor(caption, reset_camera=False, pickable=False)
        self._scale_actors = (bar, label, caption)
        self.caption_actor = caption
        for a in self._scale_actors:
            a.SetVisibility(self._layers["scalebar"])

    @property
    def caption(self) -> str:
        """The caption line of a picture: the scale bar's length and the vertical exaggeration."""
        return f"scale bar {_length_label(self.scale_bar_nm)}; vertical exaggeration 1x (heights drawn to scale)"

    def _build_markers(self) -> None:
        pv = self._pv
        sphere = pv.Sphere(radius=1.0, theta_resolution=64, phi_resolution=48)
        self.tip_actor = self.plotter.add_mesh(
            sphere, color=COLORS["tip"], opacity=self._tip_opacity, smooth_shading=True, specular=0.6,
            specular_power=40.0, reset_camera=False, pickable=False,
        )
        self.contact_actor = self.plotter.add_mesh(
            pv.Sphere(radius=1.0, theta_resolution=24, phi_resolution=16), color=COLORS["contact"],
            smooth_shading=True, ambient=0.4, reset_camera=False, pickable=False,
        )
        self.normal_arrow = _Arrow(self.plotter, pv, COLORS["normal"])
        self.force_arrow = _Arrow(self.plotter, pv, COLORS["force"])
        for a in (self.tip_actor, self.contact_actor, *self.normal_arrow.actors, *self.force_arrow.actors):
            a.SetVisibility(False)
        self._tip_on = self._contact_on = self._force_on = False

    def _build_legend(self) -> None:
        """The colour legend's text under the bar: what a material map means (its convention, the
        Poisson ratio and its source, the channel cross-check, the masked fractions by reason;
        :meth:`arsurf.contact.material_map.MaterialMap.describe`), shown with a material colouring."""
        from vtkmodules.vtkRenderingCore import vtkTextActor

        actor = vtkTextActor()
        prop = actor.GetTextProperty()
        prop.SetFontFamilyToCourier()
        prop.SetFontSize(max(10, int(self.plotter.window_size[1] / 56)))
        prop.SetColor(*self._pv.Color(COLORS["hud"]).float_rgb)
        prop.SetBackgroundColor(0.0, 0.0, 0.0)
        prop.SetBackgroundOpacity(0.45)
        prop.SetJustificationToRight()
        prop.SetVerticalJustificationToBottom()
        actor.GetPositionCoordinate().SetCoordinateSystemToNormalizedViewport()
        actor.GetPositionCoordinate().SetValue(0.985, 0.015)
        actor.SetInput("\n".join(self.material.describe()) if self.material is not None else "")
        actor.SetVisibility(False)
        self.plotter.add_actor(actor, reset_camera=False, pickable=False)
        self.legend_actor = actor

    def _build_hud(self) -> None:
        import vtkmodules.vtkRenderingFreeType  # noqa: F401  (registers the FreeType text renderer)
        from vtkmodules.vtkRenderingCore import vtkTextActor, vtkTextRenderer

        # VTK's default text backend hands strings to matplotlib's mathtext when it is present,
        # which drops "|" and ignores the font file; plain FreeType is exact and faster per frame
        renderer = vtkTextRenderer.GetInstance()
        if renderer is not None:
            renderer.SetDefaultBackend(1)  # vtkTextRenderer::FreeType
        actor = vtkTextActor()
        prop = actor.GetTextProperty()
        font = _mono_font()
        if font:
            prop.SetFontFamily(4)  # VTK_FONT_FILE
            prop.SetFontFile(font)
        else:
            prop.SetFontFamilyToCourier()
        prop.SetFontSize(max(11, int(self.plotter.window_size[1] / 44)))
        prop.SetColor(*self._pv.Color(COLORS["hud"]).float_rgb)
        prop.SetBackgroundColor(0.0, 0.0, 0.0)
        prop.SetBackgroundOpacity(0.45)
        prop.SetFrameWidth(0)
        prop.SetVerticalJustificationToTop()
        prop.SetLineSpacing(1.15)
        actor.GetPositionCoordinate().SetCoordinateSystemToNormalizedViewport()
        actor.GetPositionCoordinate().SetValue(0.015, 0.985)
        self.plotter.add_actor(actor, reset_camera=False, pickable=False)
        self.hud_actor = actor
        self._lambda_glyph = "λ" if font else "lambda"
        actor.SetInput(self._hud_text(None))

    # -- public API ---------------------------------------------------------------------------
    @property
    def layers(self) -> dict:
        """Current visibility of each layer (a copy)."""
        return dict(self._layers)

    def set_layer(self, name: str, visible: bool) -> None:
        """Show or hide one layer (see :data:`LAYERS`)."""
        self._check_layer(name)
        self._layers[name] = bool(visible)
        if name == "probe" and visible and self._last_state is not None:
            self._update_probe(self._last_state)
        self._apply_layers()

    def toggle_layer(self, name: str) -> bool:
        """Flip one layer; returns its new visibility."""
        self._check_layer(name)
        self.set_layer(name, not self._layers[name])
        return self._layers[name]

    @property
    def color_modes(self) -> list[str]:
        """The colourings this view offers: height, deformation and the material map's fields."""
        fields = self.material.fields if self.material is not None else {}
        return ["height", "deformation"] + [m for m, (name, _, _) in _MATERIAL_MODES.items() if name in fields]

    def _material_field(self, mode: str):
        """The material map's field behind a colour mode (refused without a map or the field)."""
        name = _MATERIAL_MODES[mode][0]
        if self.material is None:
            raise ViewerError(f"colouring by {mode} needs the sample's material map: SurfaceView(..., material=map) "
                              "(arsurf.contact.material_map)")
        if name not in self.material.fields:
            raise ViewerError(f"this material map has no {name} field (the file has no such channel); it has "
                              f"{sorted(self.material.fields)}")
        return self.material.fields[name]

    def _material_unit(self, mode: str) -> tuple[float, str]:
        """(scale to the shown unit, colour bar title) of a material mode."""
        field = self._material_field(mode)
        shown = _MATERIAL_MODES[mode][1].get(field.unit)
        if shown is None:  # a viewer map the file left uncalibrated: its own unit
            return 1.0, f"{mode.replace('_', ' ')} ({field.unit})"
        return shown

    def set_color_by(self, mode: str) -> None:
        """Colour the surface by ``"height"`` (nm), ``"deformation"`` (:math:`|S - S_{rest}|`, nm), or a
        field of the material map: ``"modulus"`` (E*, GPa, log scale), ``"adhesion"`` (w, mJ/m^2),
        ``"sample_deformation"``, ``"dissipation"`` (the instrument's maps, in their unit)."""
        if mode not in _SURFACE_CMAPS:
            raise ViewerError(f"`color_by` must be one of {sorted(_SURFACE_CMAPS)} (got {mode!r})")
        if mode in _MATERIAL_MODES:
            self._material_field(mode)
        self.color_by = mode
        name = {"height": "height_nm", "deformation": "deformation_nm"}.get(mode, mode)
        self.grid.point_data.active_scalars_name = name
        self._mapper.SetScalarModeToUsePointFieldData()
        self._mapper.SelectColorArray(name)
        lut = self._mapper.lookup_table
        lut.cmap = _SURFACE_CMAPS[mode]
        log = bool(mode in _MATERIAL_MODES and _MATERIAL_MODES[mode][2])
        if not log:
            lut.log_scale = False
        self._update_clim()  # a positive range before a log scale is switched on
        lut.log_scale = log
        if mode in _MATERIAL_MODES:
            title = self._material_unit(mode)[1]
        else:
            title = "height (nm)" if mode == "height" else "dent (nm)"
        self.scalar_bar.SetTitle(title)
        self._bar_ticks = None
        self._set_bar_ticks()
        self.legend_actor.SetVisibility(self._layers["colorbar"] and self._layers["surface"]
                                        and mode in _MATERIAL_MODES)

    def _update_clim(self) -> None:
        if self.color_by == "height":
            self._mapper.scalar_range = self._height_clim
        elif self.color_by in _MATERIAL_MODES:
            self._mapper.scalar_range = self._material_clim[self.color_by]
        else:
            self._mapper.scalar_range = (0.0, self._deform_clim)
        self._set_bar_ticks()

    def _follow_dent_clim(self) -> None:
        """Per frame: the deformation colours' upper limit grows (to the next 1-2-5 value) only when
        the dent goes deeper than it; every other limit is fixed (:meth:`refresh_color_limits`)."""
        if self._dent_top > self._deform_clim:
            self._deform_clim = _round_up(self._dent_top)
            if self.color_by == "deformation":
                self._update_clim()

    def refresh_color_limits(self) -> None:
        """Recompute the colour limits from the surface as shown now (on demand, O(grid)): the
        heights' 1st and 99th percentiles, and the deepest dent rounded up to a 1-2-5 value (at
        least 0.5 nm). Frames never do this: the limits are the rest surface's (heights), and
        the deformation's grow only when a dent goes deeper than them."""
        lo, hi = robust_limits(self._height)
        self._height_clim = (lo - 1.0, hi + 1.0) if hi - lo < 1e-3 else (lo, hi)
        self._deform_clim = _round_up(self._dent_top)
        self._update_clim()

    def _set_bar_ticks(self) -> None:
        """Colour-bar labels at round values (:func:`~arsurf._figure_style.round_ticks`), with the
        decimals their step needs; re-made only when the colour range changes (a log scale keeps
        VTK's labels, 3 significant digits)."""
        lo, hi = (float(v) for v in self._mapper.scalar_range)
        log = bool(self._mapper.lookup_table.log_scale)
        key = (lo, hi, log)
        if key == self._bar_ticks:
            return
        self._bar_ticks = key
        bar = self.scalar_bar
        if log or not hi > lo:
            bar.SetUseCustomLabels(False)
            bar.SetLabelFormat("%.3g")
            return
        from vtkmodules.vtkCommonCore import vtkDoubleArray

        values, labels = round_ticks(lo, hi)
        ticks = vtkDoubleArray()
        for v in values:
            ticks.InsertNextValue(v)
        self._bar_labels = labels
        bar.SetCustomLabels(ticks)
        bar.SetUseCustomLabels(True)
        decimals = len(labels[0].partition(".")[2])
        bar.SetLabelFormat(f"%.{decimals}f")

    def set_camera(self, mode: str = "oblique") -> None:
        """Frame the surface: ``"oblique"`` (perspective from the front-left, 35° elevation) or
        ``"top"`` (parallel projection looking down -z, x to the right, y up)."""
        if getattr(self, "camera_mode", None) == "close-up":  # the scale bar of the whole scan again
            self._build_scale_bar()
        cam = self.plotter.camera
        pts = self._rest_points
        lo = pts.reshape(-1, 3).min(axis=0)
        hi = pts.reshape(-1, 3).max(axis=0)
        centre = 0.5 * (lo + hi)
        ext = float(max(hi[0] - lo[0], hi[1] - lo[1], 1e-6))
        w, h = self.plotter.window_size
        cam.SetWindowCenter(0.0, 0.0)
        if mode == "top":
            cam.parallel_projection = True
            cam.focal_point = tuple(centre)
            cam.position = (centre[0], centre[1], centre[2] + 4.0 * ext)
            cam.up = (0.0, 1.0, 0.0)
            half_h = 0.5 * (hi[1] - lo[1])
            half_w = 0.5 * (hi[0] - lo[0])
            cam.parallel_scale = 1.06 * max(half_h, half_w * h / w, 1e-6)
        elif mode == "oblique":
            cam.parallel_projection = False
            cam.view_angle = 30.0
            direction = np.array([-0.45, -1.0, 0.85])
            direction /= np.linalg.norm(direction)
            cam.focal_point = tuple(centre)
            cam.position = tuple(centre + ext * direction)
            cam.up = (0.0, 0.0, 1.0)
            # the whole scan and the scale bar in front of it in the picture (VTK fits their bounding
            # sphere), a little closer than the sphere, the scene left of the colour bar
            self.plotter.renderer.ResetCamera(lo[0], hi[0], lo[1] - 0.12 * ext, hi[1], lo[2], hi[2])
            cam.zoom(1.25)
            cam.SetWindowCenter(0.12 if self._layers["colorbar"] else 0.0, 0.0)
        else:
            raise ViewerError(f"camera must be 'oblique' or 'top' (got {mode!r})")
        cam.is_set = True  # keep pyvista from resetting it at the first render
        self.camera_mode = mode
        self.plotter.renderer.ResetCameraClippingRange()

    def close_up(self, center, width: float) -> None:
        """Oblique camera on ``center`` (3,) m showing about ``width`` m of the scene (e.g. the
        tip and its dent); sample the surface finely enough (``resolution``) for that width."""
        c = np.asarray(center, dtype=np.float64).reshape(3) * 1e9  # the scene is in nm
        w = float(width) * 1e9
        if not (np.isfinite(c).all() and math.isfinite(w) and w > 0):
            raise ViewerError(f"close_up needs a finite centre and a positive width in metres (got {center!r}, {width!r})")
        cam = self.plotter.camera
        cam.parallel_projection = False
        cam.view_angle = 30.0
        cam.SetWindowCenter(0.0, 0.0)
        direction = np.array([-0.45, -1.0, 0.85])
        direction /= np.linalg.norm(direction)
        cam.focal_point = tuple(c)
        cam.position = tuple(c + w / (2.0 * math.tan(math.radians(15.0))) * direction)
        cam.up = (0.0, 0.0, 1.0)
        cam.is_set = True
        self.camera_mode = "close-up"
        # a scale bar for this width, on the surface in front of the centre
        (u0, u1), (v0, v1) = self.surface.domain
        y = c[1] - 0.3 * w
        z = float(self.surface.evaluate(min(max(c[0] * 1e-9, u0), u1), min(max(y * 1e-9, v0), v1))[2]) * SCENE_SCALE
        self._build_scale_bar(w, (c[0] - 0.5 * scale_bar_length(w), y, z + 0.2))
        self.plotter.renderer.ResetCameraClippingRange()

    def update(self, state: SceneState, render: bool = True) -> None:
        """Show ``state``: move what moved, re-sample what the deformation changed, set the HUD.

        Nothing is re-created per frame. If ``state.surface`` is a different surface object
        the surface actor is rebuilt once.
        """
        if not isinstance(state, SceneState):
            raise ViewerError(f"update() takes a SceneState (got {type(state).__name__})")
        if state.surface is not self.surface:
            self.plotter.remove_actor(self.surface_actor, render=False)
            self.plotter.remove_actor(self.dent_actor, render=False)
            self.plotter.remove_scalar_bar()
            self._build_surface(state.surface)
        self._sync_surface()
        s = SCENE_SCALE
        r = state.tip_radius * s
        c = state.tip_center * s
        m = np.diag([r, r, r, 1.0])
        m[:3, 3] = c
        _set_user_matrix(self.tip_actor, m)
        self._tip_on = True
        if state.contact_point is not None:
            p = state.contact_point * s
            rc = 0.09 * r
            mc = np.diag([rc, rc, rc, 1.0])
            mc[:3, 3] = p
            _set_user_matrix(self.contact_actor, mc)
            if state.contact_normal is not None:
                self.normal_arrow.place(p, state.contact_normal, 1.8 * r, 0.06 * r)
            self._contact_on = True
            self._normal_on = state.contact_normal is not None
        else:
            self._contact_on = self._normal_on = False
        fmag = state.force_magnitude
        if fmag >= self.force_threshold:
            d = state.force / fmag
            length = min(2.0 * r * math.log2(1.0 + fmag / self.force_scale), 0.4 * self._extent_nm)
            length = max(length, 0.5 * r)
            self.force_arrow.place(c + d * r, d, length, 0.07 * r)
            self._force_on = True
        else:
            self._force_on = False
        self._update_tubes(state.tubes)
        if self._layers["probe"]:
            self._update_probe(state)
        self.hud_actor.SetInput(self._hud_text(state))
        self._last_state = state
        self._apply_layers()
        if render:
            self.render()

    def render(self) -> None:
        """Render the current scene (clipping planes follow the moving actors)."""
        self.plotter.renderer.ResetCameraClippingRange()
        self.plotter.render()

    def screenshot(self, path: str | os.PathLike | None = None, dpi: int | None = None) -> np.ndarray:
        """Render and return the picture (height, width, 3) uint8; also write a PNG to ``path``.

        ``dpi`` (50-1200): the resolution the PNG states, so that it prints at ``window_size / dpi``
        inches (e.g. 2100 x 1500 px at 300 dpi: 7 x 5 in, a two-column figure); the pixels are
        ``window_size``'s."""
        if dpi is not None and (isinstance(dpi, bool) or not isinstance(dpi, (int, np.integer)) or not 50 <= dpi <= 1200):
            raise ViewerError(f"`dpi` must be a whole number of dots per inch in [50, 1200] (got {dpi!r})")
        self.render()
        img = self.plotter.screenshot(None, return_img=True)
        if path is not None:
            p = Path(path)
            if p.suffix.lower() != ".png":
                raise ViewerError(f"screenshots are PNG files (got {p.name!r}); use a .png name")
            image = require("PIL.Image", "viewer", "writing PNG screenshots")
            with atomic_write(p, what="screenshot", error=ViewerError) as fh:  # no text chunks: same bytes each run
                image.fromarray(np.ascontiguousarray(img)).save(fh, format="PNG",
                                                                **({"dpi": (dpi, dpi)} if dpi else {}))
        return img

    def world_to_pixel(self, points) -> np.ndarray:
        """Pixel positions (row, col) in :meth:`screenshot` images of world points in **metres**.

        Parameters
        ----------
        points : (3,) or (n, 3) float, metres

        Returns
        -------
        (2,) or (n, 2) float: row from the top, column from the left (pixel centres at integers).
        """
        p = np.asarray(points, dtype=np.float64)
        single = p.ndim == 1
        p = np.atleast_2d(p) * SCENE_SCALE
        ren = self.plotter.renderer
        h = self.plotter.window_size[1]
        out = np.empty((p.shape[0], 2))
        for k, q in enumerate(p):  # a handful of points (tests, picking): not a hot path
            ren.SetWorldPoint(q[0], q[1], q[2], 1.0)
            ren.WorldToDisplay()
            x, y, _ = ren.GetDisplayPoint()
            out[k] = (h - y - 0.5, x - 0.5)
        return out[0] if single else out

    def close(self) -> None:
        """Release the render window."""
        self.plotter.close()

    # -- per-frame work -----------------------------------------------------------------------
    def _sync_surface(self) -> None:
        """Re-sample the parts of the grid whose control points changed since the last frame (one
        patch per box the deformers moved), find the deformed samples there and contour them."""
        ctrl, ku, kv = self.surface.net_arrays()  # (moves the net to the loop's last dents first)
        anything, boxes = self._watch.take()
        if anything:  # written from outside the deformers: compare the whole net
            boxes = [(0, ctrl.shape[0], 0, ctrl.shape[1])]
        patches = []
        for b0, b1, c0, c1 in boxes:  # only the deformers' boxes can differ
            i0, i1, j0, j1 = changed_box(ctrl[b0:b1, c0:c1], self._last_ctrl[b0:b1, c0:c1])
            if i1 <= i0:
                continue
            i0, i1, j0, j1 = i0 + b0, i1 + b0, j0 + c0, j1 + c0
            # control point i moves S only for u in [knots[i], knots[i + 4]] (local support)
            patch = (int(np.searchsorted(self._u, ku[i0], side="left")),
                     int(np.searchsorted(self._u, ku[i1 - 1 + 4], side="right")),
                     int(np.searchsorted(self._v, kv[j0], side="left")),
                     int(np.searchsorted(self._v, kv[j1 - 1 + 4], side="right")))
            self._resample(*patch)
            patches.append(patch)
        if not patches:
            return
        # the deformed samples are in the old dent boxes or the re-sampled patches
        self._find_dent(merge_boxes([*self._dent_boxes, *patches]))
        self._follow_dent_clim()
        self._update_dent()

    def _resample(self, iu0: int, iu1: int, jv0: int, jv1: int) -> None:
        """Re-sample the grid box [jv0, jv1) x [iu0, iu1) in place (points, normals, height,
        deformation: :func:`~arsurf_viewer.patch.sample_patch`), O(box)."""
        if iu1 <= iu0 or jv1 <= jv0:
            return
        ctrl, ku, kv = self.surface.net_arrays()
        sample_patch(ctrl, ku, kv, self._u, self._v, iu0, iu1, jv0, jv1, SCENE_SCALE, self._rest_points,
                     self._pts, self._normals, self._height, self._deform)
        g = self.grid
        g.GetPoints().GetData().Modified()
        g.GetPoints().Modified()
        pd = g.GetPointData()
        for name in ("height_nm", "deformation_nm", "Normals"):
            pd.GetArray(name).Modified()
        g.Modified()

    def _update_tubes(self, tubes) -> None:
        pv = self._pv
        s = SCENE_SCALE
        while len(self._tubes) > len(tubes):
            actor, _ = self._tubes.pop()
            self.plotter.remove_actor(actor, render=False)
        for k, tube in enumerate(tubes):
            key = (tube.length, tube.radius)
            if k >= len(self._tubes) or self._tubes[k][1] != key:
                mesh = pv.Capsule(center=(0.0, 0.0, 0.0), direction=(1.0, 0.0, 0.0), radius=tube.radius * s,
                                  cylinder_length=tube.length * s, resolution=32)
                actor = self.plotter.add_mesh(mesh, color=COLORS["tubes"], smooth_shading=True, specular=0.4,
                                              reset_camera=False, pickable=False)
                if k < len(self._tubes):
                    self.plotter.remove_actor(self._tubes[k][0], render=False)
                    self._tubes[k] = (actor, key)
                else:
                    self._tubes.append((actor, key))
            m = np.eye(4)
            m[:3, :3] = _frame(tube.axis)
            m[:3, 3] = tube.centre * s
            _set_user_matrix(self._tubes[k][0], m)

    def _update_probe(self, state: SceneState) -> None:
        if self._probe_radius != state.tip_radius:
            self._build_probe(state.tip_radius)
        m = np.eye(4)
        m[:3, 3] = state.tip_center * SCENE_SCALE
        for a in self._probe_actors:
            _set_user_matrix(a, m)

    def _build_probe(self, tip_radius: float) -> None:
        from arsurf import meshes

        for a in self._probe_actors:
            self.plotter.remove_actor(a, render=False)
        height = self._probe_height or max(1.5 * self._extent_nm / SCENE_SCALE, 6.0 * tip_radius)
        tip = meshes.pyramidal_tip(apex_radius=tip_radius, height=height)
        beam = meshes.cantilever(length=3.0 * height, width=0.9 * height, thickness=0.08 * height,
                                 tip_height=height, tip_setback=0.25 * height)
        actors = []
        for mesh in (tip, beam):
            poly = self._pv.PolyData.from_regular_faces(np.asarray(mesh.vertices), mesh.faces)  # nm already
            actors.append(self.plotter.add_mesh(poly, color=COLORS["probe"], specular=0.5, ambient=0.3,
                                                smooth_shading=False, reset_camera=False, pickable=False))
        self._probe_actors = tuple(actors)
        self._probe_radius = tip_radius

    def _apply_layers(self) -> None:
        L = self._layers
        self.surface_actor.SetVisibility(L["surface"])
        self.scalar_bar.SetVisibility(L["colorbar"] and L["surface"])
        self.legend_actor.SetVisibility(L["colorbar"] and L["surface"] and self.color_by in _MATERIAL_MODES)
        self.dent_actor.SetVisibility(L["dent"] and L["surface"] and self.dent_step_nm > 0.0)
        self.tip_actor.SetVisibility(L["tip"] and self._tip_on)
        self.contact_actor.SetVisibility(L["contact"] and self._contact_on)
        self.normal_arrow.set_visible(L["contact"] and self._contact_on and getattr(self, "_normal_on", False))
        self.force_arrow.set_visible(L["force"] and self._force_on)
        self.hud_actor.SetVisibility(L["hud"])
        for a in self._scale_actors:
            a.SetVisibility(L["scalebar"])
        for actor, _ in self._tubes:
            actor.SetVisibility(L["tubes"])
        for a in self._probe_actors:
            a.SetVisibility(L["probe"])

    def _hud_text(self, st: SceneState | None) -> str:
        if st is None:
            return "no state yet"
        f = st.force * 1e9

        def num(x, fmt):
            return "   -" if math.isnan(x) else format(x, fmt)

        lines = [
            f"F  [nN]  x {f[0]:+8.3f}  y {f[1]:+8.3f}  z {f[2]:+8.3f}   |F| {np.linalg.norm(f):7.3f}",
            f"depth {st.depth * 1e9:+7.2f} nm    contact radius {st.contact_radius * 1e9:6.2f} nm",
            f"{self._lambda_glyph} {num(st.maugis_lambda, '6.3f')}    loop {num(st.loop_rate_hz, '7.0f')} Hz"
            + ("" if math.isnan(st.time) else f"    t {st.time:8.3f} s"),
        ]
        if st.device_status:
            lines.append(f"device: {st.device_status}")
        if st.flags & BEYOND_MODEL:
            lines.append(f"BEYOND MODEL: contact radius {st.contact_radius / st.tip_radius:.2f} R > "
                         f"{SMALL_CONTACT_LIMIT:g} R, the contact law assumes a << R")
        others = flag_names(st.flags & ~BEYOND_MODEL)
        if others:
            lines.append("flags: " + " ".join(others))
        if self.dent_step_nm > 0.0 and self._layers["dent"]:
            lines.append(f"dent contours every {self.dent_step_nm:g} nm")
        return "\n".join(lines)
