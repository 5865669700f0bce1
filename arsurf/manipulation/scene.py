r"""Nanotubes in the live scene: pushed by the tip every tick, felt as a resistance, drawn where they are.

A :class:`TubeScene` holds the rigid tubes (:class:`~arsurf.manipulation.nanotube.Nanotube`)
lying on a sample. Every haptic tick (:meth:`TubeScene.tick`, called by
:class:`~arsurf.haptics.loop.HapticLoop` after its model tick) the tip sphere's move from the
previous to the current probe position pushes any tube it meets
(:func:`~arsurf.manipulation.nanotube.push_kernel`: rotation about the corrected Eq. 9 pivot,
translation near the middle, axial slide at a cap; the tube never passes through the tip), and
the scene returns the force the pushed tubes exert on the tip.

Object path, not the height map
-------------------------------
The tubes are collided and rendered as objects; the B-spline surface holds only the substrate.
For a synthetic scan the tube poses are known (:meth:`TubeScene.from_scan`); for a real scan
the user gives them (from the image) and :meth:`TubeScene.substrate` masks the tube pixels
(dilated by a margin for the imaging tip and the smoothing) and fills them by Laplace
inpainting (:func:`arsurf.inpaint`) *before* the fit, so that a tube is not present twice (once
in the spline, where it could not move, once as an object). Moving a tube then changes three
numbers, never the surface (nanotube.py, "Scene integration").

Force on the tip ([MWCNT], Sec. 3: uniform resistance)
-------------------------------------------------------
The substrate resists a sliding tube with a uniform force :math:`f` per unit length, opposite
to the local velocity ([MWCNT]'s model behind Eq. 9). The tip-tube contact is frictionless,
so the tube pushes the tip back along the contact normal :math:`\hat n` (from the tube axis
towards the tip centre). Its horizontal magnitude is the force that balances the distributed
friction of the motion the push produces:

.. math::

    F_h = f \left( |n_\perp|\, |L - 2 s(l)| + |n_\parallel|\, L \right),

with :math:`l` the contact arc-length, :math:`s(l)` the pivot of
:func:`~arsurf.manipulation.nanotube.rotation_centre` and :math:`n_\perp, n_\parallel` the
components of the horizontal contact normal across and along the axis. The first term is
Eq. 9's force balance, :math:`F = f (L - 2s)` (equal, through the moment balance, to the
power balance :math:`F\,\delta = f \int_0^L |\Delta r(x)|\,dx`: tested); it is :math:`f L` for a
push at the middle (translation) and :math:`f L (\sqrt2 - 1)` at an end. The second is the
resistance of the axial slide of a cap push (the whole tube slides: :math:`f L`); a
cap contact with an oblique normal interpolates linearly between the two exact cases (a
simple, documented law: [MWCNT] gives no model for oblique cap pushes). The vertical part
follows from the frictionless contact: the force is along the 3D normal, so
:math:`F_z = F_h\, \Delta z / d_h` (:math:`\Delta z` the tip centre's height above the axis,
:math:`d_h` its horizontal distance to the axis), with :math:`d_h` floored at 10 % of
:math:`R + r` (normals steeper than 84 deg: a tip on the crest would wedge the tube into the
substrate, which the rigid-sliding model does not describe; the floor keeps the force bounded).
This normal part is what a tip wider than the tube feels riding on its curved flank: with the
tip on the substrate, :math:`F_z = |F|\,n_z` is upward, about 0.44 :math:`F_h` for a 20 nm tip
against a 15 nm tube; [MWCNT] Fig. 10a's normal force (20-40 nN) is the total, substrate plus
tube (docs/design.rst, "The normal force of a tube push"; :mod:`arsurf.demo.tube_push`).

The tip-tube contact is compliant over a small depth, :data:`CONTACT_ALLOWANCE` of
:math:`R + r`: the tube slides only once the tip is that far into it (the push moves the tube
for a sphere shrunk by the allowance), and the reaction is :math:`F_h` scaled by the depth over
the allowance - full while the tube slides, fading to zero as the tip backs off, zero for a tip
resting against the tube without pressing. (With a purely kinetic resistance, felt only in the
ticks the tube slides, a slow push or a jittering hand made the force flicker between 0 and
:math:`F_h` every tick: the demo's buzz.)

The default :data:`FRICTION_PER_LENGTH` = 0.1 N/m (0.1 nN per nm of tube) is set against seed
000 Fig. 10: a lateral force of 0-30 nN (saw-toothed: stick-slip) in the first push of its "Z"
strategy, MWCNTs on polycarbonate, the tip pushing a tube **end** across the axis. In that
configuration the force above is :math:`f L(\sqrt2 - 1)`: 14 nN for the demo's 0.33 um tubes,
22 nN for its 0.52 um one, inside the figure's range (tested). The larger forces of the same
tubes, up to 52 nN, are :math:`f L`: a push at the middle (the tube translates) or along the axis,
a configuration Fig. 10 does not show. The seed gives neither *f* nor its tube's length, so
this is a calibration of *f* on the figure, not a reproduction of it; the stick-slip saw teeth
are not modelled (the resistance is uniform kinetic friction).

Limits: tubes do not collide with each other (a tube pushed onto another passes through it);
they slide, never roll ([MWCNT]: "it prefers sliding rather than rolling").

Determinism: :meth:`TubeScene.tick` is a compiled kernel of the previous and current tip
centres and the poses only; replaying the recorded probe positions reproduces the poses bit for
bit (:func:`arsurf.replay.replay.replay`).

Examples
--------
>>> from arsurf.manipulation.nanotube import Nanotube
>>> scene = TubeScene([Nanotube(300e-9, 15e-9, x=0.0, y=0.0, angle=0.0)])
>>> tip0 = (150e-9, -40e-9, 20e-9)                    # beside end B, at the substrate
>>> step = scene.step(tip0, (150e-9, 20e-9, 20e-9), tip_radius=20e-9)   # push 60 nm along +y
>>> step.touched.tolist(), bool(step.force[1] < 0)    # the tube turned and resisted the push
([True], True)
>>> round(float(step.poses[0, 2]), 3)    # end B moved ~44 nm (the tip ends 0.55 nm, its allowance, in): rad
0.206
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np
from numba import njit

from arsurf._layout import Layout
from arsurf._validation import real
from arsurf.errors import ManipulationError
from arsurf.manipulation.nanotube import Nanotube, _centre, _seg_dist, push_kernel
from arsurf.scan.scan import Scan
from arsurf.status import PUSH_NAMES

__all__ = ["TubeScene", "SceneStep", "TubeMotion", "FRICTION_PER_LENGTH", "tube_mask", "rigid_motion",
           "scene_step_kernel"]

#: Substrate resistance per unit tube length, N/m (= nN/nm). Chosen so that an end push of the
#: demo's 0.33-0.52 um tubes ([MWCNT] Fig. 10's configuration) takes 14-22 nN, within the figure's
#: 0-30 nN; middle or axial pushes take f L, up to 52 nN (module docstring).
FRICTION_PER_LENGTH = 0.1
#: Floor of the horizontal contact distance, as a fraction of R + r, in the vertical force.
_MIN_HORIZONTAL = 0.1
#: the tip may press this fraction of (R + r) into a tube before it slides: the tube's reaction
#: grows over that depth (contact compliance) instead of appearing only in the ticks it slides
CONTACT_ALLOWANCE = 0.02

#: columns of the per-tube geometry array: length, radius (m), height of the axis (m), friction per
#: length (N/m), the sub-step (m)
TUBE_GEOMETRY = Layout("tube geometry columns", [("length", 1), ("radius", 1), ("axis_z", 1),
                                                  ("friction_per_length", 1), ("substep", 1)])
#: columns of the per-tube info array (last tick): contacts, push status (:data:`arsurf.status.PUSH_NAMES`),
#: the last contact and pivot positions along the tube
TUBE_INFO = Layout("tube info columns", [("contacts", 1), ("status", 1), ("contact", 1), ("pivot", 1)])
G_LENGTH, G_RADIUS, G_AXIS_Z, G_FRICTION, G_SUBSTEP = (TUBE_GEOMETRY.offset(f) for f in TUBE_GEOMETRY.fields)
G_SIZE = TUBE_GEOMETRY.size
I_CONTACTS, I_STATUS, I_CONTACT, I_PIVOT = (TUBE_INFO.offset(f) for f in TUBE_INFO.fields)
I_SIZE = TUBE_INFO.size


@njit(cache=True)
def scene_step_kernel(poses, geom, band, max_substeps, prev, tip, tip_radius, force, info, add_to):
    """Push every tube the tip meets moving from ``prev`` to ``tip``; write the force on the tip.

    ``poses`` (k, 3) x, y, angle (updated in place); ``geom`` (k, G_SIZE); ``prev``, ``tip``
    (3,) metres (a non-finite ``prev`` means "no previous tick": no displacement); ``force``
    (3,) N written; ``info`` (k, I_SIZE) written; ``add_to`` (3,) receives ``+= force``.
    Returns the number of contact resolutions, or -1 (nothing done, zero force) if ``tip`` is
    not finite.
    """
    force[0] = 0.0
    force[1] = 0.0
    force[2] = 0.0
    k = poses.shape[0]
    for i in range(k):
        info[i, I_CONTACTS] = 0.0
        info[i, I_STATUS] = 0.0
        info[i, I_CONTACT] = math.nan
        info[i, I_PIVOT] = math.nan
    qx = tip[0]
    qy = tip[1]
    qz = tip[2]
    if not (math.isfinite(qx) and math.isfinite(qy) and math.isfinite(qz)):
        return -1
    if math.isfinite(prev[0]) and math.isfinite(prev[1]) and math.isfinite(prev[2]):
        px = prev[0]
        py = prev[1]
        pz = prev[2]
    else:
        px = qx
        py = qy
        pz = qz
    total = 0
    for i in range(k):
        L = geom[i, G_LENGTH]
        r = geom[i, G_RADIUS]
        za = geom[i, G_AXIS_Z]
        allowance = CONTACT_ALLOWANCE * (tip_radius + r)
        # the tube slides once the tip is `allowance` into it: push with the sphere shrunk by it
        cx, cy, th, st, nc, l, s, _n = push_kernel(poses[i, 0], poses[i, 1], poses[i, 2], L, r, za, px, py, pz,
                                                   qx - px, qy - py, qz - pz, tip_radius - allowance,
                                                   geom[i, G_SUBSTEP], band, max_substeps)
        info[i, I_STATUS] = st
        if nc > 0:
            info[i, I_CONTACTS] = nc
            info[i, I_CONTACT] = l
            info[i, I_PIVOT] = s
            poses[i, 0] = cx
            poses[i, 1] = cy
            poses[i, 2] = th
            total += nc
        # reaction of the tube on the tip (module docstring), from the final contact geometry,
        # in proportion to how far the tip is into the contact allowance (full while sliding)
        ux = math.cos(poses[i, 2])
        uy = math.sin(poses[i, 2])
        t, ax, ay, d = _seg_dist(qx, qy, poses[i, 0] - 0.5 * L * ux, poses[i, 1] - 0.5 * L * uy, ux, uy, L)
        if d <= 0.0:  # tip centre on the axis: only possible above the tube's reach, no contact
            continue
        depth = tip_radius + r - math.sqrt(d * d + (qz - za) * (qz - za))
        if not depth > 0.0:
            continue
        w = min(depth / allowance, 1.0)
        nx = (qx - ax) / d
        ny = (qy - ay) / d
        n_ax = abs(nx * ux + ny * uy)
        n_perp = abs(-nx * uy + ny * ux)
        if abs(t - 0.5 * L) <= band * L:
            lever = L
        else:
            lever = abs(L - 2.0 * _centre(t, L))
        fh = w * geom[i, G_FRICTION] * (n_perp * lever + n_ax * L)
        dh = max(d, _MIN_HORIZONTAL * (tip_radius + r))
        force[0] += fh * nx
        force[1] += fh * ny
        force[2] += fh * (qz - za) / dh
    add_to[0] += force[0]
    add_to[1] += force[1]
    add_to[2] += force[2]
    return total


# ------------------------------------------------------------------------------------------------
# helpers
# ------------------------------------------------------------------------------------------------


def _real(name: str, value, what: str, *, positive: bool = False, nonneg: bool = False) -> float:
    return real(value, name, what, ManipulationError, positive=positive, nonneg=nonneg)


def _point(name: str, value) -> np.ndarray:
    p = np.asarray(value, dtype=np.float64).reshape(-1)
    if p.shape != (3,) or not np.isfinite(p).all():
        raise ManipulationError(f"{name} must be 3 finite coordinates in metres (got {np.asarray(value).tolist()!r})")
    return p


def _smoothing_sigma(scan: Scan) -> float:
    """Largest Gaussian width (metres) in the scan's processing history (0 if never smoothed)."""
    sigma = 0.0
    for step in scan.metadata.get("history", ()):
        if isinstance(step, Mapping) and step.get("operation") == "smooth":
            for key in ("sigma_x", "sigma_y", "sigma"):
                v = step.get(key)
                if isinstance(v, (int, float)) and math.isfinite(v):
                    sigma = max(sigma, float(v))
    return sigma


def tube_mask(scan: Scan, tubes: Sequence[Nanotube], margin: float = 0.0) -> np.ndarray:
    """Pixels of ``scan`` within ``radius + margin`` (horizontally) of a tube's axis segment.

    Parameters
    ----------
    scan : Scan
        Pixel (ix, iy) sits at x = ix*dx, y = iy*dy (the Scan convention), like the tube poses.
    tubes : sequence of Nanotube
    margin : float, metres, >= 0
        Added to each tube's radius (the imaging tip widens a tube's image, smoothing blurs it).

    Returns
    -------
    (ny, nx) bool

    Examples
    --------
    >>> s = Scan(np.zeros((5, 9)), dx=10e-9, dy=10e-9)
    >>> tube_mask(s, [Nanotube(40e-9, 10e-9, x=40e-9, y=20e-9)]).sum(axis=1).tolist()
    [0, 0, 5, 0, 0]
    """
    if not isinstance(scan, Scan):
        raise ManipulationError(f"tube_mask needs an arsurf Scan (got {type(scan).__name__})")
    m = _real("margin", margin, "metres added to the tube radius", nonneg=True)
    ny, nx = scan.shape
    x = np.arange(nx)[None, :] * scan.dx
    y = np.arange(ny)[:, None] * scan.dy
    mask = np.zeros((ny, nx), dtype=bool)
    for tube in tubes:  # a handful of tubes; the pixels are vectorised
        if not isinstance(tube, Nanotube):
            raise ManipulationError(f"tubes must be Nanotube objects (got {type(tube).__name__})")
        a = tube.endpoints[0]
        u = tube.direction
        t = np.clip((x - a[0]) * u[0] + (y - a[1]) * u[1], 0.0, tube.length)
        d2 = (x - a[0] - t * u[0]) ** 2 + (y - a[1] - t * u[1]) ** 2
        mask |= d2 < (tube.radius + m) ** 2
    return mask


@dataclass(frozen=True)
class TubeMotion:
    """The rigid planar motion of a tube between two poses.

    Attributes
    ----------
    displacement : float, metres
        Distance the centre moved.
    rotation : float, radians
        Change of the axis angle, wrapped to (-pi, pi].
    pole : (2,) float, metres
        The fixed point of the motion (the finite rotation centre); NaN for a pure translation.
    pole_arc_length : float, metres
        The pole's position along the *initial* axis, from end A (``nan`` for a translation).
    pole_offset : float, metres
        The pole's distance from the initial axis line.
    """

    displacement: float
    rotation: float
    pole: np.ndarray
    pole_arc_length: float
    pole_offset: float


def rigid_motion(before: Nanotube, after: Nanotube) -> TubeMotion:
    r"""Displacement, rotation and rotation pole that take ``before`` to ``after``.

    The motion maps :math:`x \mapsto R(\varphi)(x - c_0) + c_1`; its fixed point (pole) is
    :math:`p = (I - R)^{-1}(c_1 - R c_0)`. A tube pushed at end B by a single Eq. 9 step turns
    about the pole at arc-length :math:`L (1 - 1/\sqrt2)`.

    Examples
    --------
    >>> a = Nanotube(1e-6, 1e-8)
    >>> b = a.with_pose(0.1e-6, 0.0, 0.0)
    >>> m = rigid_motion(a, b)
    >>> round(m.displacement * 1e6, 6), m.rotation, bool(np.isnan(m.pole_arc_length))
    (0.1, 0.0, True)
    """
    for name, t in (("before", before), ("after", after)):
        if not isinstance(t, Nanotube):
            raise ManipulationError(f"{name} must be a Nanotube (got {type(t).__name__})")
    c0 = np.array([before.x, before.y])
    c1 = np.array([after.x, after.y])
    phi = math.atan2(math.sin(after.angle - before.angle), math.cos(after.angle - before.angle))
    if abs(phi) < 1e-12:
        pole = np.full(2, np.nan)
        arc = offset = math.nan
    else:
        c, s = math.cos(phi), math.sin(phi)
        rot = np.array([[c, -s], [s, c]])
        pole = np.linalg.solve(np.eye(2) - rot, c1 - rot @ c0)
        u = before.direction
        a = before.endpoints[0, :2]
        arc = float((pole - a) @ u)
        offset = float(abs((pole - a) @ np.array([-u[1], u[0]])))
    return TubeMotion(float(np.hypot(*(c1 - c0))), phi, pole, arc, offset)


@dataclass(frozen=True)
class SceneStep:
    """What one :meth:`TubeScene.step` did.

    Attributes
    ----------
    force : (3,) float, newtons
        Force of the tubes on the tip (zero when none was pushed).
    poses : (k, 3) float
        Poses after the step: x, y (metres), angle (radians).
    touched : (k,) bool
        Tubes the tip pushed in this step.
    contacts : (k,) int
        Contact resolutions per tube.
    contact : (k,) float, metres
        Arc-length of each tube's last contact (NaN if not touched).
    pivot : (k,) float, metres
        Arc-length of each tube's last rotation centre (``inf``: translation; NaN: not touched).
    status : tuple of str
        Per tube: ``"ok"``, ``"substep_cap"`` or ``"fallback"`` (see :class:`~arsurf.manipulation.nanotube.PushResult`).
    """

    force: np.ndarray
    poses: np.ndarray
    touched: np.ndarray
    contacts: np.ndarray
    contact: np.ndarray
    pivot: np.ndarray
    status: tuple


class TubeScene:
    """Rigid nanotubes on the sample, pushed by the tip sphere (module docstring).

    Parameters
    ----------
    tubes : sequence of Nanotube
        The tubes at their initial poses (``base`` set: the substrate height they rest on).
    friction_per_length : float, N/m, >= 0
        Substrate resistance per unit length :math:`f` (default :data:`FRICTION_PER_LENGTH`).
    middle_band : float in [0, 0.5)
        Contacts within ``middle_band * L`` of the middle translate the tube
        (:func:`~arsurf.manipulation.nanotube.push`).
    max_substep : float, metres, optional
        Longest push sub-step; default L/50 per tube (the pivot follows the sliding contact).
    max_substeps : int
        Cap on the sub-steps of one tick (a tick moves the tip a fraction of a nanometre at
        1 kHz; the cap only matters for jumps, which stay overlap-free).
    substrate_margin : float, metres, optional
        Margin :meth:`substrate` adds to each tube radius; None: :meth:`substrate` returns the
        scan unchanged (the tubes are not in the scan, e.g. virtual tubes on a clean substrate).

    Attributes
    ----------
    poses : (k, 3) float
        Live poses (x, y in metres, angle in radians), updated in place every tick.
    force : (3,) float, newtons
        The force of the last tick.

    Examples
    --------
    >>> scene = TubeScene([Nanotube(200e-9, 10e-9, x=1e-7, y=1e-7)])
    >>> scene.tick(np.full(3, np.nan), np.array([0.0, 0.0, 1e-8]), 5e-9).tolist()   # far away
    [0.0, 0.0, 0.0]
    """

    def __init__(self, tubes: Sequence[Nanotube], *, friction_per_length: float = FRICTION_PER_LENGTH,
                 middle_band: float = 0.01, max_substep: float | None = None, max_substeps: int = 10_000,
                 substrate_margin: float | None = None):
        tubes = tuple(tubes)
        for t in tubes:
            if not isinstance(t, Nanotube):
                raise ManipulationError(f"a TubeScene holds Nanotube objects (got {type(t).__name__}); build them "
                                        "with arsurf.Nanotube(length, diameter, x, y, angle, base)")
        f = _real("friction_per_length", friction_per_length, "the substrate resistance in N/m", nonneg=True)
        band = _real("middle_band", middle_band, "a fraction of the tube length")
        if not 0.0 <= band < 0.5:
            raise ManipulationError(f"middle_band must be in [0, 0.5) (got {middle_band!r}); it is a fraction of L")
        if max_substep is not None:
            max_substep = _real("max_substep", max_substep, "metres", positive=True)
        if isinstance(max_substeps, bool) or int(max_substeps) != max_substeps or int(max_substeps) < 1:
            raise ManipulationError(f"max_substeps must be an integer >= 1 (got {max_substeps!r})")
        if substrate_margin is not None:
            substrate_margin = _real("substrate_margin", substrate_margin, "metres added to the radius", nonneg=True)
        self.initial = tubes
        self.friction_per_length = f
        self.middle_band = band
        self.max_substep = max_substep
        self.max_substeps = int(max_substeps)
        self.substrate_margin = substrate_margin
        k = len(tubes)
        geom = np.empty((k, G_SIZE))
        for i, t in enumerate(tubes):
            geom[i] = (t.length, t.radius, t.axis_height, f, t.length / 50.0 if max_substep is None else max_substep)
        self._geom = geom
        self.poses = np.array([t.pose for t in tubes], dtype=np.float64).reshape(k, 3)
        self.force = np.zeros(3)
        self.info = np.zeros((k, I_SIZE))
        self._sink = np.zeros(3)

    # -- construction -----------------------------------------------------------------------
    @classmethod
    def from_scan(cls, scan: Scan, *, margin: float | None = None, **kwargs) -> "TubeScene":
        """The tubes of a synthetic nanotubes scan (:func:`arsurf.scan.synthetic.nanotubes`).

        Poses come from ``scan.metadata["synthetic"]["tubes"]`` (end points and diameter, in the
        scan frame), or ``scan.metadata["measured_tubes"]["tubes"]`` (the same, measured on a scan
        by ``arsurf verify --reseed``); each tube rests on the highest point of the :meth:`substrate` under its axis
        (:meth:`Nanotube.resting_on`), so pass the scan as it will be fitted (levelled and
        smoothed, e.g. :func:`arsurf.scan.prepare.prepare_scan`).

        Parameters
        ----------
        scan : Scan
        margin : float, metres, optional
            Substrate margin (see :meth:`substrate`); default two pixels plus three times the
            Gaussian width of any smoothing in the scan's history.
        **kwargs
            Passed to :class:`TubeScene`.

        Raises
        ------
        ManipulationError
            The scan has no synthetic tube record (for a real scan, build the tubes from their
            measured poses: ``TubeScene([Nanotube(...), ...], substrate_margin=...)``).
        """
        if not isinstance(scan, Scan):
            raise ManipulationError(f"from_scan needs an arsurf Scan (got {type(scan).__name__})")
        rec = scan.metadata.get("synthetic")
        measured = scan.metadata.get("measured_tubes")  # a scan after, tubes at their measured poses (arsurf verify)
        if isinstance(measured, Mapping) and measured.get("tubes"):
            rec = {"generator": "nanotubes", "tubes": measured["tubes"]}
        if not isinstance(rec, Mapping) or rec.get("generator") != "nanotubes" or not rec.get("tubes"):
            raise ManipulationError(
                f"scan {scan.source or ''!r} has no synthetic nanotube record (metadata['synthetic']['tubes']); "
                "for a real scan build TubeScene([Nanotube(length, diameter, x, y, angle), ...], "
                "substrate_margin=...) from the tube poses measured on the image")
        if margin is None:
            margin = 2.0 * max(scan.dx, scan.dy) + 3.0 * _smoothing_sigma(scan)
        tubes = []
        for k, t in enumerate(rec["tubes"]):
            try:
                (x0, y0), (x1, y1), d = t["start"], t["end"], t["diameter"]
            except (KeyError, TypeError, ValueError):
                raise ManipulationError(f"synthetic tube record {k} must have start (x, y), end (x, y) and diameter "
                                        f"(got {t!r})") from None
            tubes.append(Nanotube(math.hypot(x1 - x0, y1 - y0), d, x=0.5 * (x0 + x1), y=0.5 * (y0 + y1),
                                  angle=math.atan2(y1 - y0, x1 - x0)))
        ground = cls(tubes, substrate_margin=margin).substrate(scan)
        return cls([t.resting_on(ground) for t in tubes], substrate_margin=margin, **kwargs)

    def to_metadata(self) -> dict:
        """The scene as JSON-ready data (the *initial* tubes and the settings), for session metadata.

        Examples
        --------
        >>> s = TubeScene([Nanotube(1e-7, 1e-8, x=1e-7)])
        >>> TubeScene.from_metadata(s.to_metadata()).initial == s.initial
        True
        """
        return {
            "tubes": [{"length": t.length, "diameter": t.diameter, "x": t.x, "y": t.y, "angle": t.angle,
                       "base": t.base} for t in self.initial],
            "friction_per_length": self.friction_per_length, "middle_band": self.middle_band,
            "max_substep": self.max_substep, "max_substeps": self.max_substeps,
            "substrate_margin": self.substrate_margin,
        }

    @classmethod
    def from_metadata(cls, meta: Mapping) -> "TubeScene":
        """Rebuild the scene :meth:`to_metadata` described (ManipulationError if it is malformed)."""
        if not isinstance(meta, Mapping) or not isinstance(meta.get("tubes"), (list, tuple)):
            raise ManipulationError(f"tube-scene metadata must be an object with a 'tubes' list (got {meta!r}); "
                                    "write it with TubeScene.to_metadata()")
        tubes = []
        for k, t in enumerate(meta["tubes"]):
            if not isinstance(t, Mapping):
                raise ManipulationError(f"tube {k} of the scene metadata must be an object (got {t!r})")
            try:
                tubes.append(Nanotube(t["length"], t["diameter"], x=t["x"], y=t["y"], angle=t["angle"],
                                      base=t.get("base", 0.0)))
            except KeyError as exc:
                raise ManipulationError(f"tube {k} of the scene metadata lacks {exc}; it needs length, diameter, "
                                        "x, y, angle (and base)") from None
        return cls(tubes, friction_per_length=meta.get("friction_per_length", FRICTION_PER_LENGTH),
                   middle_band=meta.get("middle_band", 0.01), max_substep=meta.get("max_substep"),
                   max_substeps=meta.get("max_substeps", 10_000), substrate_margin=meta.get("substrate_margin"))

    # -- the substrate --------------------------------------------------------------------------
    def substrate(self, scan: Scan, margin: float | None = None) -> Scan:
        """The scan without the tubes: their pixels masked and filled by Laplace inpainting.

        Fit *this* to the B-spline when the tubes are scene objects, so that the spline holds
        only the substrate. The tubes are masked at their **initial** poses (where the scan saw
        them), within ``radius + margin`` of the axis.

        Parameters
        ----------
        scan : Scan
            In the frame of the tube poses (pixel (ix, iy) at x = ix*dx, y = iy*dy).
        margin : float, metres, optional
            Default :attr:`substrate_margin`. For a real image use at least the imaging tip's
            half-width of a tube's image minus its radius (a tip of radius R images a tube of
            radius r about :math:`2\\sqrt{Rr}` wide), plus three Gaussian widths of any smoothing.

        Returns
        -------
        Scan
            With an ``inpaint`` history step; the scan itself if there is no margin (``None``)
            or no tube.
        """
        from arsurf.scan.inpaint import inpaint

        if not isinstance(scan, Scan):
            raise ManipulationError(f"substrate needs an arsurf Scan (got {type(scan).__name__})")
        m = self.substrate_margin if margin is None else margin
        if m is None or not self.initial:
            return scan
        mask = tube_mask(scan, self.initial, m)
        if mask.all():
            raise ManipulationError(f"the tubes cover the whole scan (margin {m!r} m): there is no substrate left to "
                                    "fit; use a smaller margin or a larger scan")
        return inpaint(scan, mask)

    # -- state ----------------------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self.initial)

    @property
    def tubes(self) -> tuple[Nanotube, ...]:
        """The tubes at their current poses (new objects)."""
        return tuple(t.with_pose(*map(float, p)) for t, p in zip(self.initial, self.poses))

    def reset(self) -> None:
        """Put every tube back at its initial pose."""
        self.poses[:] = np.array([t.pose for t in self.initial], dtype=np.float64).reshape(len(self), 3)
        self.force[:] = 0.0
        self.info[:] = 0.0

    def motion(self, i: int) -> TubeMotion:
        """How tube ``i`` moved from its initial pose (:func:`rigid_motion`)."""
        if not 0 <= int(i) < len(self):
            raise ManipulationError(f"tube index must be in [0, {len(self)}) (got {i!r})")
        return rigid_motion(self.initial[i], self.tubes[i])

    def viewer_tubes(self) -> list[tuple]:
        """The tubes as the viewer draws them: ``(centre (3,), axis (3,), length, radius)`` in
        metres (:class:`arsurf_viewer.SceneState` ``tubes``), at the current poses."""
        out = []
        for t, (x, y, a) in zip(self.initial, self.poses):
            out.append((np.array([x, y, t.axis_height]), np.array([math.cos(a), math.sin(a), 0.0]), t.length,
                        t.radius))
        return out

    # -- stepping -------------------------------------------------------------------------------
    def tick(self, prev: np.ndarray, tip: np.ndarray, tip_radius: float,
             add_to: np.ndarray | None = None) -> np.ndarray:
        """Unchecked fast path (the haptic loop's): push with the tip moving ``prev`` -> ``tip``.

        ``prev``, ``tip``: (3,) float64 arrays, metres (``prev`` NaN: first tick, no move);
        ``tip_radius`` metres; ``add_to``: optional (3,) float64 array that receives ``+= force``.
        Returns :attr:`force` (reused array, N). No validation, no allocation.
        """
        scene_step_kernel(self.poses, self._geom, self.middle_band, self.max_substeps, prev, tip, tip_radius,
                          self.force, self.info, self._sink if add_to is None else add_to)
        return self.force

    def step(self, prev_tip, tip, tip_radius: float) -> SceneStep:
        """Validated step: the tip sphere (radius ``tip_radius``) moves from ``prev_tip`` to ``tip``.

        Parameters
        ----------
        prev_tip : (3,) float, metres, or None
            Tip centre at the previous tick (None: no move, only overlaps are resolved).
        tip : (3,) float, metres
        tip_radius : float, metres, >= 0

        Returns
        -------
        SceneStep
        """
        q = _point("tip", tip)
        p = np.full(3, np.nan) if prev_tip is None else _point("prev_tip", prev_tip)
        r = _real("tip_radius", tip_radius, "the tip-sphere radius in metres", nonneg=True)
        self.tick(p, q, r)
        info = self.info
        contacts = info[:, I_CONTACTS].astype(np.int64)
        return SceneStep(force=self.force.copy(), poses=self.poses.copy(), touched=contacts > 0, contacts=contacts,
                         contact=info[:, I_CONTACT].copy(), pivot=info[:, I_PIVOT].copy(),
                         status=tuple(PUSH_NAMES[int(s)] for s in info[:, I_STATUS]))
