"""The :class:`BSplineSurface`: a bicubic tensor-product B-spline S(u, v) in R^3.

Built by :func:`arsurf.fit_surface` (or directly from a control net); evaluation never refits.
On the undeformed surface the control points sit on the Greville abscissae so x(u) = u and
y(v) = v (metres); after a deformation (:mod:`arsurf.contact.deformation`) the net moves and
S is a general parametric surface. :meth:`BSplineSurface.reset` restores the rest shape exactly.
"""
from __future__ import annotations

import math
import weakref

import numpy as np
from numba import njit

from arsurf.errors import SurfaceError
from arsurf.spline import basis
from arsurf.spline.knots import check_clamped_uniform, clamped_uniform_knots, greville


@njit(cache=True)
def _fill_height_net(gu, gv, z, ctrl):
    """ctrl[i, j] = (gu[i], gv[j], z[i, j]) in one pass."""
    for i in range(gu.size):
        for j in range(gv.size):
            ctrl[i, j, 0] = gu[i]
            ctrl[i, j, 1] = gv[j]
            ctrl[i, j, 2] = z[i, j]


def merge_boxes(boxes) -> list:
    """Disjoint index boxes covering ``boxes`` (each (i0, i1, j0, j1), half-open): boxes that
    overlap or touch are replaced by their bounding box, until none do. For a handful of boxes
    (one per contact): O(n^2)."""
    out: list = []
    for box in boxes:
        b = tuple(int(k) for k in box)
        k = 0
        while k < len(out):
            o = out[k]
            if b[0] <= o[1] and o[0] <= b[1] and b[2] <= o[3] and o[2] <= b[3]:
                b = (min(b[0], o[0]), max(b[1], o[1]), min(b[2], o[2]), max(b[3], o[3]))
                out.pop(k)
                k = 0  # the grown box may now meet one it missed
            else:
                k += 1
        out.append(b)
    return out


class NetWatch:
    """What changed in a surface's net since its watcher last looked (:meth:`BSplineSurface.watch`).

    ``boxes`` are disjoint index boxes (i0, i1, j0, j1) covering what the deformers moved (two
    contacts far apart stay two small boxes: :func:`merge_boxes`); ``anything`` is True when the
    net may have changed anywhere (it was handed out writable by
    :meth:`BSplineSurface.kernel_arrays`, or reset), so the watcher must compare it all.
    """

    def __init__(self):
        self.boxes: list = []
        self.anything = True  # a new watcher has seen nothing yet

    def touch(self, i0: int, i1: int, j0: int, j1: int) -> None:
        """Add the index box [i0, i1) x [j0, j1) to what changed."""
        self.boxes = merge_boxes([*self.boxes, (i0, i1, j0, j1)])

    def take(self) -> tuple[bool, list]:
        """(anything, boxes) since the last take, and start afresh."""
        out = (self.anything, self.boxes)
        self.anything, self.boxes = False, []
        return out


class BSplineSurface:
    """Bicubic B-spline surface on clamped uniform knots.

    .. math:: S(u, v) = \\sum_{i=0}^{n_u-1}\\sum_{j=0}^{n_v-1} N_i(u) N_j(v) P_{ij}

    Parameters
    ----------
    control_points : (nu, nv, 3) float, metres
        Control net; axis 0 runs along u (x), axis 1 along v (y).
    knots_u, knots_v : (nu + 4,), (nv + 4,) float, metres
        Clamped uniform cubic knot vectors.

    Attributes
    ----------
    control_points : (nu, nv, 3) read-only view of the current net.
    rest_control_points : (nu, nv, 3) read-only view of the rest net (as fitted).
    domain : ((u0, u1), (v0, v1)) parameter domain, metres.

    Examples
    --------
    >>> import numpy as np
    >>> s = BSplineSurface.from_heights(np.zeros((4, 5)), (0.0, 3e-9), (0.0, 4e-9))
    >>> s.evaluate(1e-9, 2e-9)
    array([1.e-09, 2.e-09, 0.e+00])
    """

    def __init__(self, control_points, knots_u, knots_v):
        ctrl = np.array(control_points, dtype=np.float64, order="C", copy=True)
        if ctrl.ndim != 3 or ctrl.shape[2] != 3:
            raise SurfaceError(f"control_points must have shape (nu, nv, 3) (got {ctrl.shape})")
        if not np.isfinite(ctrl).all():
            bad = int((~np.isfinite(ctrl)).any(axis=2).sum())
            raise SurfaceError(
                f"control_points has {bad} non-finite (NaN/inf) points; fit from a scan without NaN "
                "(see arsurf.inpaint) or repair the net"
            )
        ku = check_clamped_uniform(knots_u, "knots_u")
        kv = check_clamped_uniform(knots_v, "knots_v")
        if ku.size != ctrl.shape[0] + 4 or kv.size != ctrl.shape[1] + 4:
            raise SurfaceError(
                f"knot vectors of length {ku.size}, {kv.size} do not match a {ctrl.shape[0]}x{ctrl.shape[1]} "
                "net (need nu + 4 and nv + 4)"
            )
        self._adopt(ctrl, ku, kv)

    def _adopt(self, ctrl: np.ndarray, ku: np.ndarray, kv: np.ndarray, rest: np.ndarray | None = None) -> None:
        self._ctrl = ctrl
        self._rest_net = rest  # None: the net is at rest; the snapshot is taken at first need
        self._ku = ku
        self._kv = kv
        self._derived = []  # structures built from the net (e.g. the projection's boxes)
        self._height_field = None  # unknown until asked (is_height_field_net), True from from_heights
        self._dents = []  # deformers whose recorded dent is moved onto the net when it is read (sync)
        self._watches = weakref.WeakSet()  # NetWatch of the readers that re-draw what changed (the viewer)

    @classmethod
    def construct_fast(cls, ctrl: np.ndarray, ku: np.ndarray, kv: np.ndarray,
                       rest: np.ndarray | None = None) -> "BSplineSurface":
        """Build without validation or copy (scipy's ``construct_fast`` pattern): the caller
        guarantees a finite (nu, nv, 3) float64 C array (and rest net) and matching knots."""
        self = object.__new__(cls)
        self._adopt(ctrl, ku, kv, rest)
        return self

    # -- construction -------------------------------------------------------------------------
    @classmethod
    def from_heights(cls, z_net, u_range, v_range) -> "BSplineSurface":
        """Height-field net: z control values (nu, nv) on Greville x, y over the given domain."""
        z = np.asarray(z_net, dtype=np.float64)
        if z.ndim != 2:
            raise SurfaceError(f"z_net must be 2-D (nu, nv) (got shape {z.shape})")
        if not np.isfinite(z).all():
            raise SurfaceError(f"z_net has {int((~np.isfinite(z)).sum())} non-finite values")
        ku = clamped_uniform_knots(z.shape[0], *u_range)
        kv = clamped_uniform_knots(z.shape[1], *v_range)
        ctrl = np.empty(z.shape + (3,))
        _fill_height_net(greville(ku), greville(kv), z, ctrl)
        surface = cls.construct_fast(ctrl, ku, kv)
        surface._height_field = True  # x on the Greville abscissae of u, y of v: by construction
        return surface

    def __getstate__(self) -> dict:
        """Pickle or deep-copy the net as it reads now (any recorded dent applied), with its
        deformers (a deep-copied model keeps denting its own copy) but not the watching readers
        (a view watches the surface it draws, not a copy)."""
        self.sync()
        state = self.__dict__.copy()
        state["_watches"] = None
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._watches = weakref.WeakSet()

    def copy(self) -> "BSplineSurface":
        """An independent copy with the same current and rest nets."""
        self.sync()
        twin = BSplineSurface.construct_fast(self._ctrl.copy(), self._ku, self._kv, self._rest.copy())
        twin._height_field = self._height_field
        return twin

    @property
    def is_height_field_net(self) -> bool:
        """True if x of the rest net depends on i only and y on j only (the nets of
        :func:`arsurf.fit_surface` and :meth:`from_heights`: known without looking; others are
        checked once, O(N))."""
        if self._height_field is None:
            rest = self._rest
            self._height_field = bool(np.ptp(rest[:, :, 0], axis=1).max() == 0.0
                                      and np.ptp(rest[:, :, 1], axis=0).max() == 0.0)
        return self._height_field

    @property
    def _rest(self) -> np.ndarray:
        """The rest net, copied from the net the first time anything may move it (kernel_arrays,
        reset...): fitting a surface does not pay for a snapshot nobody needs yet."""
        if self._rest_net is None:
            self._rest_net = self._ctrl.copy()
        return self._rest_net

    def reset(self) -> None:
        """Restore the rest shape exactly (undo every deformation, recorded dents included) and
        refresh what was derived from the net (:meth:`attach`)."""
        self._ctrl[...] = self._rest
        for dent in self._dents:
            dent.forget()
        for watch in self._watches:
            watch.anything = True
        for derived in self._derived:
            derived.refresh()

    def attach(self, derived) -> None:
        """Register a structure built from the control net (an object with ``refresh()``, e.g.
        the projection's hull boxes): :meth:`reset` refreshes it. Local edits (deformation)
        refresh their own patch instead."""
        if derived not in self._derived:
            self._derived.append(derived)

    def attach_dent(self, deformer) -> None:
        """Register a deformer (:class:`arsurf.contact.deformation.Deformer`) whose dent the
        compiled tick records without touching the net: :meth:`sync` moves the net to it."""
        if deformer not in self._dents:
            self._dents.append(deformer)

    def watch(self) -> NetWatch:
        """A :class:`NetWatch` told of every change of the net from now on (kept while referenced)."""
        w = NetWatch()
        self._watches.add(w)
        return w

    def touched(self, i0: int, i1: int, j0: int, j1: int) -> None:
        """Control points [i0, i1) x [j0, j1) moved (the deformer says so): tell the watchers."""
        for watch in self._watches:
            watch.touch(i0, i1, j0, j1)

    def sync(self) -> None:
        """Move the net to the dents recorded since it was last read (O(dent box) each; nothing
        when none is pending). Every reader of the net below calls it first, so the net a
        reader sees is the full dent of the last tick."""
        for dent in self._dents:
            dent.sync()

    # -- properties ---------------------------------------------------------------------------
    @property
    def control_points(self) -> np.ndarray:
        self.sync()
        view = self._ctrl.view()
        view.flags.writeable = False
        return view

    @property
    def rest_control_points(self) -> np.ndarray:
        view = self._rest.view()
        view.flags.writeable = False
        return view

    @property
    def knots_u(self) -> np.ndarray:
        return self._ku.copy()

    @property
    def knots_v(self) -> np.ndarray:
        return self._kv.copy()

    @property
    def shape(self) -> tuple[int, int]:
        """(nu, nv) control points."""
        return self._ctrl.shape[0], self._ctrl.shape[1]

    @property
    def domain(self) -> tuple[tuple[float, float], tuple[float, float]]:
        return (float(self._ku[0]), float(self._ku[-1])), (float(self._kv[0]), float(self._kv[-1]))

    @property
    def spacing(self) -> tuple[float, float]:
        """Knot spacing (h_u, h_v), metres."""
        (u0, u1), (v0, v1) = self.domain
        return (u1 - u0) / (self.shape[0] - 3), (v1 - v0) / (self.shape[1] - 3)

    @property
    def is_deformed(self) -> bool:
        self.sync()
        return not np.array_equal(self._ctrl, self._rest)

    def net_arrays(self):
        """(ctrl, knots_u, knots_v): the live net and knots, without taking the rest snapshot
        (for structures that only read the current net)."""
        self.sync()
        return self._ctrl, self._ku, self._kv

    @property
    def at_rest(self) -> bool:
        """True when the net was never handed out for deformation (no rest snapshot yet): then it
        is exactly the fitted net, checked in O(1) (:attr:`is_deformed` compares the nets, O(N))."""
        return self._rest_net is None

    def kernel_arrays(self):
        """(ctrl, rest, knots_u, knots_v) as the float64 C arrays the numba kernels take.

        ``ctrl`` is the live, writable net: only :mod:`arsurf.contact.deformation` writes to it.
        Recorded dents are moved onto it first (:meth:`sync`). Watchers (:meth:`watch`) are told
        that the net may change anywhere: to read only, use :meth:`net_arrays`.
        """
        self.sync()
        for watch in self._watches:
            watch.anything = True
        return self._ctrl, self._rest, self._ku, self._kv

    def raw_arrays(self):
        """:meth:`kernel_arrays` without :meth:`sync` (for the deformer that does the syncing)."""
        return self._ctrl, self._rest, self._ku, self._kv

    # -- evaluation ---------------------------------------------------------------------------
    def evaluate(self, u, v, derivatives: int = 0):
        """Point and derivatives of the surface.

        Parameters
        ----------
        u, v : float or array_like (same shape), metres
            Parameters; values outside :attr:`domain` are clamped to it.
        derivatives : {0, 1, 2}
            0 returns S; 1 returns (S, S_u, S_v); 2 returns (S, S_u, S_v, S_uu, S_uv, S_vv).

        Returns
        -------
        ndarray
            derivatives = 0: S, shape (..., 3), metres. Otherwise one array of shape
            (3 or 6, ..., 3) whose leading axis is (S, S_u, S_v[, S_uu, S_uv, S_vv]), so it unpacks
            as a tuple: ``S, Su, Sv = surface.evaluate(u, v, 1)`` (S_u, S_v dimensionless; second
            derivatives in 1/m). Returning one array keeps the single-point call at ~1 µs.
        """
        if derivatives not in (0, 1, 2):
            raise SurfaceError(f"derivatives must be 0, 1 or 2 (got {derivatives!r})")
        if self._dents:
            self.sync()
        if isinstance(u, (float, int)) and isinstance(v, (float, int)):  # the lean single-point path
            if not (math.isfinite(u) and math.isfinite(v)):
                raise SurfaceError(f"u and v must be finite (got u={u!r}, v={v!r})")
            out = np.empty((basis.N_ROWS, 3))
            basis.surface_point(self._ctrl, self._ku, self._kv, float(u), float(v), derivatives, out)
            return out[0] if derivatives == 0 else out[: (1, 3, 6)[derivatives]]
        uu, vv = np.broadcast_arrays(np.asarray(u, dtype=np.float64), np.asarray(v, dtype=np.float64))
        if not (np.isfinite(uu).all() and np.isfinite(vv).all()):
            raise SurfaceError("u and v must be finite (got NaN or inf in the parameter arrays)")
        shape = uu.shape
        us = np.ascontiguousarray(uu.ravel())
        vs = np.ascontiguousarray(vv.ravel())
        nout = (1, 3, 6)[derivatives]
        out = np.empty((nout, us.size, 3))
        batch = basis.surface_points if us.size >= basis.PARALLEL_MIN else basis.surface_points_serial
        batch(self._ctrl, self._ku, self._kv, us, vs, derivatives, out)
        res = out.reshape((nout,) + shape + (3,))
        return res[0] if derivatives == 0 else res

    def evaluate_grid(self, nu_samples: int, nv_samples: int) -> np.ndarray:
        """Surface points on a regular (u, v) grid: (nv_samples, nu_samples, 3), row = v."""
        (u0, u1), (v0, v1) = self.domain
        u = np.linspace(u0, u1, int(nu_samples))
        v = np.linspace(v0, v1, int(nv_samples))
        uu, vv = np.meshgrid(u, v)
        return self.evaluate(uu, vv)

    # -- notebook display (IPython) ----------------------------------------------------------
    def _thumbnail_grid(self):
        """(z, dent, extent): heights on a grid of at most THUMB_PIXELS a side over the domain, the
        dent (current minus rest z; None at rest) and the grid's (u0, u1, v0, v1)."""
        from arsurf._display import THUMB_PIXELS

        (u0, u1), (v0, v1) = self.domain
        ratio = (v1 - v0) / (u1 - u0)
        nu = THUMB_PIXELS if ratio <= 1 else max(2, int(round(THUMB_PIXELS / ratio)))
        nv = THUMB_PIXELS if ratio >= 1 else max(2, int(round(THUMB_PIXELS * ratio)))
        z = self.evaluate_grid(nu, nv)[..., 2]
        dent = None
        if not self.at_rest and self.is_deformed:
            rest = BSplineSurface.construct_fast(self._rest, self._ku, self._kv)
            dent = z - rest.evaluate_grid(nu, nv)[..., 2]
        return z, dent, (u0, u1, v0, v1)

    def _repr_png_(self) -> bytes:
        """A thumbnail of z over (u, v) (IPython); a dent is outlined in white over the topography."""
        from arsurf._display import map_png

        z, dent, extent = self._thumbnail_grid()
        return map_png(z, extent, "m", "height", contours=dent)

    def _repr_html_(self) -> str:
        """Control net, domain, knot spacing, z range and the dent, with units, and the thumbnail."""
        from arsurf._display import card, map_png, quantity

        (u0, u1), (v0, v1) = self.domain
        hu, hv = self.spacing
        z, dent, extent = self._thumbnail_grid()
        rows = [("control points", f"{self.shape[0]} x {self.shape[1]}"),
                ("domain (x, y)", f"{quantity(u1 - u0, 'm')} x {quantity(v1 - v0, 'm')}"),
                ("knot spacing", f"{quantity(hu, 'm')} x {quantity(hv, 'm')}"),
                ("z range", f"{quantity(float(np.ptp(z)), 'm')} (sampled on {z.shape[1]} x {z.shape[0]} points)")]
        if self.at_rest or not self.is_deformed:
            rows.append(("deformed", "no"))
        else:
            moved = np.linalg.norm(self._ctrl - self._rest, axis=2)
            rows.append(("deformed", f"{int(np.count_nonzero(moved))} control points moved, "
                                     f"at most {quantity(float(moved.max()), 'm')}"))
        return card("BSplineSurface", rows, map_png(z, extent, "m", "height", contours=dent))

    def __repr__(self) -> str:
        (u0, u1), (v0, v1) = self.domain
        return (
            f"BSplineSurface({self.shape[0]}x{self.shape[1]} control points, "
            f"u in [{u0:.4g}, {u1:.4g}] m, v in [{v0:.4g}, {v1:.4g}] m, deformed={self.is_deformed})"
        )
