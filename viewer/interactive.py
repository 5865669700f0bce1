"""Driving the tip by hand: keyboard and mouse as a stand-in for a stylus, or a pose callable.

:func:`run_interactive` opens a window on the surface. Each timer tick (``fps``) it takes the
tip pose - from ``pose_source()`` when given (the haptic loop or the UDP bridge: a callable
returning the tip centre (3,) in metres, or None to keep the keyboard pose), else from the
keys - runs ``physics(tip_center, dt) -> SceneState`` and updates the view in place.

Keys (:class:`StylusController`)
    ←/→ move x, ↑/↓ move y, Page Up/Page Down move z (by R/10; Page Down stops at the depth where
    the contact reaches the law's a << R bound); ``[`` / ``]`` halve/double the step;
    ``r`` resets the surface, ``p`` pauses/resumes, ``t`` cycles layer sets, ``1``-``8`` toggle
    single layers (surface, tip, contact, force, hud, probe, tubes, colorbar), ``c`` switches the
    colouring (height/deformation), ``v`` the camera (oblique/top), ``q`` quits.
    Right-click on the surface puts the tip there, just touching.

The default physics, :class:`ContactPhysics`, is the model without a cantilever: the tip sphere
is collided with the *rest* surface (so the dent it makes does not hide the indentation),
Maugis-Dugdale gives the contact radius and the load P, the force shown is P·n, and the net
is dented with :class:`arsurf.contact.deformation.Deformer`. The live loop replaces it with its
own ``physics`` (decoupled, measured force). With a tube scene (:mod:`arsurf.manipulation.scene`;
``view_scan(..., tubes=True)`` on a synthetic nanotubes scan) the tip's moves push the tubes,
their resistance is added to the force and the tubes are drawn where they are, frame by frame.

Without a display (Linux with no reachable X server) the same scene is rendered offscreen
along the pose source, or along a scripted approach-indent-slide-retract path, into PNG frames
and a movie, and a message says so.
"""
from __future__ import annotations

import logging
import math
import time
from pathlib import Path
from typing import Callable

import numpy as np

from arsurf._logging import progress
from arsurf.contact.mechanics import SMALL_CONTACT_LIMIT
from arsurf.spline.surface import BSplineSurface

from .backend import choose_backend, has_display
from .state import SceneState
from arsurf.errors import ViewerError, rendering_failed

log = logging.getLogger("arsurf.viewer")  # the viewer's logger: a child of arsurf's (arsurf._logging)

__all__ = ["StylusController", "ContactPhysics", "scripted_path", "run_interactive", "view_scan", "LAYER_SETS"]

#: Layer sets that the ``t`` key cycles through (name -> visible layers).
LAYER_SETS = (
    ("all", {"surface", "tip", "contact", "force", "hud", "tubes", "colorbar"}),
    ("surface only", {"surface", "colorbar"}),
    ("no arrows", {"surface", "tip", "hud", "tubes", "colorbar"}),
    ("with probe", {"surface", "tip", "contact", "force", "hud", "tubes", "colorbar", "probe"}),
)
_LAYER_KEYS = ("surface", "tip", "contact", "force", "hud", "probe", "tubes", "colorbar")


class StylusController:
    """Keyboard state of the stand-in stylus: the tip centre, step sizes, pause and layers.

    Pure logic (no window): :meth:`handle_key` takes VTK key symbols, so tests drive it directly.

    Parameters
    ----------
    surface : BSplineSurface
        Reset by ``r``.
    tip_center : (3,) float, metres
        Start position.
    tip_radius : float, metres
        The tip's radius R: the vertical step and the depth limit scale with it.
    step : float, metres, optional
        Lateral step per key press (default: 1/50 of the scan size).
    z_step : float, metres, optional
        Vertical step (default: R / 10, so that the depth limit is a few presses deep).
    max_depth : float, metres, optional
        Deepest indentation Page Down drives the tip to: the depth at which the contact radius
        reaches the contact law's bound, :data:`arsurf.contact.mechanics.SMALL_CONTACT_LIMIT` R
        (:attr:`ContactPhysics.max_depth` for the law in use; default the Hertz depth
        ``SMALL_CONTACT_LIMIT**2 R`` = 0.16 R, where a = sqrt(R d) reaches it). The depth is the last one the
        physics reported (:attr:`depth`, set by the viewer each frame), plus the presses since:
        a vertical press deepens the contact by at most its own length.
    view : SurfaceView, optional
        Receives the layer, colouring and camera keys.
    on_reset : callable, optional
        Called after ``r`` (e.g. to release a deformer).
    """

    def __init__(self, surface: BSplineSurface, tip_center, tip_radius: float = 20e-9, *, step: float | None = None,
                 z_step: float | None = None, max_depth: float | None = None, view=None,
                 on_reset: Callable[[], None] | None = None):
        self.surface = surface
        self.tip_center = np.asarray(tip_center, dtype=np.float64).reshape(3).copy()
        (u0, u1), (v0, v1) = surface.domain
        r = float(tip_radius)
        if not (math.isfinite(r) and r > 0):
            raise ViewerError(f"`tip_radius` must be a positive length in metres (got {tip_radius!r})")
        self.step = float(step) if step is not None else max(u1 - u0, v1 - v0) / 50.0
        self.z_step = float(z_step) if z_step is not None else r / 10.0
        self.max_depth = float(max_depth) if max_depth is not None else SMALL_CONTACT_LIMIT ** 2 * r
        if not (self.step > 0 and self.z_step > 0 and math.isfinite(self.step) and math.isfinite(self.z_step)):
            raise ViewerError(f"steps must be positive lengths in metres (got step={step!r}, z_step={z_step!r})")
        if not (math.isfinite(self.max_depth) and self.max_depth >= 0):
            raise ViewerError(f"`max_depth` must be a length >= 0 in metres (got {max_depth!r})")
        #: the indentation depth the physics last reported, m (< 0: a gap), plus the presses since
        self.depth = -math.inf
        self.view = view
        self.on_reset = on_reset
        self.paused = False
        self.quit = False
        self.layer_set = 0

    def handle_key(self, key: str) -> str:
        """Apply one key (a VTK keysym: "Left", "Prior", "r", "bracketleft", "3"...); returns what it did."""
        moves = {"Left": (0, -1.0), "Right": (0, 1.0), "Down": (1, -1.0), "Up": (1, 1.0),
                 "Next": (2, -1.0), "Prior": (2, 1.0)}
        if key in moves:
            axis, sign = moves[key]
            move = sign * (self.z_step if axis == 2 else self.step)
            note = ""
            if key == "Next":
                room = self.max_depth - self.depth
                if room <= 0.0:
                    return (f"depth limit {self.max_depth * 1e9:.3g} nm reached (the contact law holds for a << R); "
                            "Page Up lifts the tip")
                if -move > room:
                    move, note = -room, f" (held at the depth limit {self.max_depth * 1e9:.3g} nm)"
                self.depth += -move
            self.tip_center[axis] += move
            return f"tip at ({', '.join(f'{c * 1e9:.1f}' for c in self.tip_center)}) nm" + note
        if key == "bracketleft":
            self.step /= 2.0
            self.z_step /= 2.0
            return f"step {self.step * 1e9:.3g} nm, z step {self.z_step * 1e9:.3g} nm"
        if key == "bracketright":
            self.step *= 2.0
            self.z_step *= 2.0
            return f"step {self.step * 1e9:.3g} nm, z step {self.z_step * 1e9:.3g} nm"
        if key == "r":
            self.surface.reset()
            if self.on_reset is not None:
                self.on_reset()
            return "surface reset"
        if key == "p":
            self.paused = not self.paused
            return "paused" if self.paused else "running"
        if key == "q":
            self.quit = True
            return "quit"
        if self.view is None:
            return ""
        if key == "t":
            self.layer_set = (self.layer_set + 1) % len(LAYER_SETS)
            name, on = LAYER_SETS[self.layer_set]
            for layer in _LAYER_KEYS:
                self.view.set_layer(layer, layer in on)
            return f"layers: {name}"
        if key in "12345678" and len(key) == 1:
            layer = _LAYER_KEYS[int(key) - 1]
            return f"{layer} {'on' if self.view.toggle_layer(layer) else 'off'}"
        if key == "c":
            modes = self.view.color_modes
            self.view.set_color_by(modes[(modes.index(self.view.color_by) + 1) % len(modes)])
            return f"colour by {self.view.color_by}"
        if key == "v":
            self.view.set_camera("top" if self.view.camera_mode == "oblique" else "oblique")
            return f"camera {self.view.camera_mode}"
        return ""


class ContactPhysics:
    """The model driven by hand: an :class:`arsurf.model.ARModel` (collision on the rest surface,
    Maugis-Dugdale with hysteresis, dent of the live net) turned into :class:`SceneState` frames.

    Parameters
    ----------
    surface : BSplineSurface
        The live surface (dented in place).
    tip_radius : float, metres
    tip_material, sample_material : str or Material
        Names in :data:`arsurf.MATERIALS` (default Si tip on polystyrene, soft enough to dent).
    deform : bool
        Dent the net (``False``: a rigid sample).
    scene : TubeScene, optional
        Nano-objects pushed by the tip (:class:`arsurf.manipulation.scene.TubeScene`): each call
        pushes them with the tip moving from the previous call's centre to this one, adds their
        force to the shown force and draws them at their poses; ``release`` puts them back.
    material : MaterialMap, optional
        The sample's material map (:mod:`arsurf.contact.material_map`): E* and w where the tip
        touches, instead of the two materials.
    """

    def __init__(self, surface: BSplineSurface, tip_radius: float, *, tip_material="Si",
                 sample_material="polystyrene", deform: bool = True, scene=None, material=None):
        from arsurf.assembly import make_model
        from arsurf.contact.materials import effective_modulus, work_of_adhesion

        self.surface = surface
        self.tip_radius = float(tip_radius)
        if material is None:
            e, w, s0 = effective_modulus(tip_material, sample_material), work_of_adhesion(tip_material,
                                                                                           sample_material), None
            self.status = f"keyboard · {tip_material} on {sample_material}"
        else:
            law = material.contact_law()
            e, w, s0 = law.effective_modulus, law.work_of_adhesion, law.dugdale_stress
            self.status = f"keyboard · material map {material.sha256[:8]}"
        self.model = make_model(surface, tip_radius=self.tip_radius, effective_modulus=e, work_of_adhesion=w,
                                dugdale_stress=s0, deform=deform, material=material)
        self.contact = self.model.contact
        #: the indentation depth (m) at which the reference law's contact radius is 1 % inside the bound
        #: it holds to, :data:`~arsurf.contact.mechanics.SMALL_CONTACT_LIMIT` R: the keyboard's depth limit
        self.max_depth = float(self.contact.at_radius(0.99 * SMALL_CONTACT_LIMIT * self.tip_radius).depth)
        if scene is not None and not (callable(getattr(scene, "tick", None)) and hasattr(scene, "viewer_tubes")):
            raise ViewerError(f"`scene` must be an arsurf.manipulation.scene.TubeScene (got {type(scene).__name__})")
        self.scene = scene
        self._prev = np.full(3, np.nan)

    def release(self) -> None:
        """Forget the dent and the contact history (after ``surface.reset()``); tubes back home."""
        self.model.reset()
        if self.scene is not None:
            self.scene.reset()
            self._prev[:] = np.nan

    def __call__(self, tip_center, dt: float) -> SceneState:
        c = np.array(tip_center, dtype=np.float64).reshape(3)
        t = self.model.step(c)
        rate = 1.0 / dt if dt > 0 else math.nan
        force, tubes = t.simulated_force, ()
        if self.scene is not None:
            force = force + self.scene.tick(self._prev, c, self.tip_radius)
            self._prev[:] = c
            tubes = self.scene.viewer_tubes()
        return SceneState(self.surface, c, self.tip_radius, contact_point=t.point, contact_normal=t.normal,
                          depth=t.depth, contact_radius=t.contact_radius, force=force,
                          maugis_lambda=self.contact.maugis_parameter, loop_rate_hz=rate,
                          device_status=self.status, tubes=tubes, flags=t.model_flags)


def scripted_path(surface: BSplineSurface, tip_radius: float, frames: int = 60, indent: float | None = None) -> np.ndarray:
    """Tip centres (frames, 3) m: approach above the centre, indent, slide 20 % of the scan, retract.

    ``indent`` (default R/4) is the depth below the rest surface reached at the bottom.
    """
    if frames < 4:
        raise ViewerError(f"`frames` must be at least 4 (got {frames!r})")
    (u0, u1), (v0, v1) = surface.domain
    d = 0.25 * tip_radius if indent is None else float(indent)
    n1 = frames // 4
    n3 = frames // 4
    n2 = frames - n1 - n3
    x0, y = u0 + 0.4 * (u1 - u0), v0 + 0.5 * (v1 - v0)
    xs = np.concatenate([np.full(n1, x0), np.linspace(x0, x0 + 0.2 * (u1 - u0), n2), np.full(n3, x0 + 0.2 * (u1 - u0))])
    ys = np.full(frames, y)
    zs_surf = surface.evaluate(xs, ys)[:, 2]
    lift = np.concatenate([np.linspace(1.5 * tip_radius, -d, n1), np.full(n2, -d), np.linspace(-d, 1.5 * tip_radius, n3)])
    return np.column_stack([xs, ys, zs_surf + tip_radius + lift])


def run_interactive(surface: BSplineSurface, *, tip_radius: float = 20e-9, physics=None,
                    pose_source: Callable[[], object] | None = None, fps: float = 30.0, start=None,
                    out_dir: str | Path = "out/view", frames: int = 90, **view_kwargs):
    """Open the interactive viewer (or render offscreen when there is no display).

    Parameters
    ----------
    surface : BSplineSurface
    tip_radius : float, metres
    physics : callable (tip_center (3,) m, dt s) -> SceneState, optional
        One tick of the model; default :class:`ContactPhysics`. The haptic loop passes its own.
    pose_source : callable () -> (3,) metres or None, optional
        Polled every frame; a pose overrides the keyboard (stylus, UDP bridge, replay).
    fps : float
        View refresh rate (30-60 Hz; the haptic loop runs separately at its own rate).
    start : (3,) metres, optional
        Initial tip centre (default: above the middle of the surface, 1.5 R clear of it).
    out_dir, frames
        Headless fallback: where to write PNG frames and the movie, and how many frames.
    view_kwargs
        Passed to :class:`SurfaceView`.

    Returns
    -------
    None after the window closes, or the :class:`~arsurf_viewer.frames.Frames` written headless.
    """
    from .frames import render_frames
    from .view import SurfaceView

    if not isinstance(surface, BSplineSurface):
        raise ViewerError(f"`surface` must be a BSplineSurface (got {type(surface).__name__})")
    if not (isinstance(fps, (int, float)) and 1 <= fps <= 240):
        raise ViewerError(f"`fps` must be between 1 and 240 (got {fps!r})")
    physics = physics if physics is not None else ContactPhysics(surface, tip_radius)
    (u0, u1), (v0, v1) = surface.domain
    if start is None:
        cx, cy = 0.5 * (u0 + u1), 0.5 * (v0 + v1)
        start = (cx, cy, float(surface.evaluate(cx, cy)[2]) + 2.5 * tip_radius)
    dt = 1.0 / fps
    choose_backend()
    if not has_display():
        out = Path(out_dir)
        log.info("arsurf view: no display (DISPLAY is unset or unreachable), so no window can open; rendering "
                 "%d frames offscreen to %s/ instead (%s).", frames, out,
                 "following the pose source" if pose_source else "along a scripted approach-indent-slide-retract path")
        # pressed as deep as the keyboard may go (the law's a << R bound), not deeper
        poses = scripted_path(surface, tip_radius, frames, getattr(physics, "max_depth", None)) \
            if pose_source is None else None

        failure = {}

        def states():  # one at a time: each state shows the live surface as dented at that tick
            last = np.asarray(start, dtype=np.float64)
            try:
                for k in progress(range(frames), desc="frames", unit="frame"):
                    pose = poses[k] if poses is not None else pose_source()
                    last = last if pose is None else np.asarray(pose, dtype=np.float64).reshape(3)
                    yield physics(last, dt)
            except Exception as exc:
                failure["exc"] = exc
                raise

        view_kwargs.setdefault("off_screen", True)
        try:
            return render_frames(states(), out, fps=fps, **view_kwargs)
        except Exception as exc:
            if failure.get("exc") is exc or isinstance(exc, ViewerError):  # the model or the arguments, not OpenGL
                raise
            raise rendering_failed("arsurf view (offscreen frames)", exc) from exc

    view = SurfaceView(surface, off_screen=False, **view_kwargs)
    ctl = StylusController(surface, start, tip_radius, view=view, max_depth=getattr(physics, "max_depth", None),
                           on_reset=getattr(physics, "release", None))
    plotter = view.plotter
    state = physics(ctl.tip_center, dt)
    ctl.depth = state.depth
    view.update(state, render=False)
    last_tick = [time.perf_counter()]

    def tick(_step=None):
        now = time.perf_counter()
        elapsed, last_tick[0] = now - last_tick[0], now
        if ctl.quit:
            plotter.close()
            return
        if ctl.paused:
            return
        if pose_source is not None:
            pose = pose_source()
            if pose is not None:
                ctl.tip_center[:] = np.asarray(pose, dtype=np.float64).reshape(3)
        state = physics(ctl.tip_center, elapsed if elapsed > 0 else dt)
        ctl.depth = state.depth  # the depth limit of Page Down follows the model's own depth
        view.update(state)

    keys = ("Left", "Right", "Up", "Down", "Prior", "Next", "bracketleft", "bracketright",
            "r", "p", "t", "c", "v", *"12345678")
    for key in keys:
        plotter.clear_events_for_key(key, raise_on_missing=False)
        plotter.add_key_event(key, lambda k=key: _announce(ctl.handle_key(k)))
    # VTK's own one-letter shortcuts (r: reset camera, p: pick, t: trackball...) would fire too
    style = plotter.iren.interactor.GetInteractorStyle()
    if style is not None:
        style.AddObserver("CharEvent", lambda *_: None)

    def clicked(point):
        if point is None:
            return
        x, y = float(point[0]) * 1e-9, float(point[1]) * 1e-9
        z = float(surface.evaluate(x, y)[2])
        ctl.tip_center[:] = (x, y, z + tip_radius)
        ctl.depth = 0.0  # just touching, until the next frame measures it

    plotter.track_click_position(clicked, side="right")
    plotter.iren.add_timer_event(max_steps=2**31 - 1, duration=max(1, int(round(1000 * dt))), callback=tick)
    log.info("arsurf view: arrows move x/y, PgUp/PgDn z, [ ] step, r reset, p pause, t layers, "
             "1-8 layer, c colours, v camera, right-click place, q quit")
    plotter.show()
    return None


def _announce(message: str) -> None:
    if message:
        log.info("arsurf view: %s", message)


def view_scan(scan, *, tip_radius: float = 20e-9, level_method: str | None = "plane", sigma: float | None = None,
              control_shape=None, smoothing: float = 0.0, tubes: bool = False, **kwargs):
    """What ``arsurf view [SCAN]`` runs: load (a path or a Scan), level, smooth, fit, open the viewer.

    Parameters
    ----------
    scan : path-like or Scan
    tip_radius : float, metres
    level_method : str or None
        :func:`arsurf.level` method (None: use the heights as they are).
    sigma : float, metres, optional
        Gaussian smoothing width (:func:`arsurf.smooth`) before the fit; None: no smoothing.
    control_shape, smoothing
        Passed to :func:`arsurf.fit_surface`.
    tubes : bool
        Make the tubes of a synthetic nanotubes scan pushable objects
        (:meth:`arsurf.manipulation.scene.TubeScene.from_scan`): the surface is fitted to the
        substrate (tube pixels inpainted) and the tip pushes the tubes live.
    kwargs
        Passed to :func:`run_interactive` (and a ``material`` map to the physics too: the tip
        feels the map's E* and w, the view colours by it).
    """
    import arsurf

    if not isinstance(scan, arsurf.Scan):
        scan = arsurf.load_scan(scan)
    if level_method is not None:
        scan = arsurf.level(scan, level_method)
    if sigma is not None:
        scan = arsurf.smooth(scan, sigma)
    scene = None
    if tubes:
        from arsurf.manipulation.scene import TubeScene

        scene = TubeScene.from_scan(scan)
        scan = scene.substrate(scan)
    surface = arsurf.fit_surface(scan, control_shape=control_shape, smoothing=smoothing)
    material = kwargs.get("material")
    if (scene is not None or material is not None) and kwargs.get("physics") is None:
        kwargs["physics"] = ContactPhysics(surface, tip_radius, scene=scene, material=material)
    return run_interactive(surface, tip_radius=tip_radius, **kwargs)
