r"""Tip-surface collision from Python: the closest point of a B-spline surface to a point.

.. math:: (u^*, v^*) = \arg\min_{(u, v)} \tfrac12 |S(u, v) - C|^2, \qquad
          d = (C - S^*)\cdot n^*, \qquad \delta = R - d

:func:`project` and :func:`collide` (one query), :func:`project_many` and :func:`collide_many`
(batches) validate their inputs once, call the compiled global search of
:mod:`arsurf.contact.closest_point` with the surface's :class:`Projector` (its hull-box pyramid and
workspace, built at the first query and kept on the surface), and return small named records
carrying the answer and how it was obtained (status, iterations, cells searched).

Examples
--------
>>> import numpy as np
>>> from arsurf.spline.surface import BSplineSurface
>>> flat = BSplineSurface.from_heights(np.zeros((8, 8)), (0.0, 50e-9), (0.0, 50e-9))
>>> c = collide(flat, (20e-9, 30e-9, 8e-9), radius=10e-9)
>>> round(c.depth * 1e9, 9), c.in_contact, c.normal.tolist()
(2.0, True, [0.0, 0.0, 1.0])
"""
from __future__ import annotations

import functools
import math
from typing import NamedTuple

import numba
import numpy as np
from numba import njit, types
from numba.experimental import structref
from numba.extending import overload

from arsurf.contact.closest_point import (  # noqa: F401 (collide_any, collide_kernel: for numba callers)
    G_BUILDS, G_CLOCK, G_NCU, G_NCV, G_NTI, G_NTJ, G_SIZE, G_SLOTS, G_TILE, G_USED, SI_TI, SI_TJ, SI_USED, SLOT_INFO,
    collide_any, collide_kernel, project_any, project_batch_kernel, project_kernel, tiled_project_kernel,
)
from arsurf.contact.hull_tree import CURV_SIZE, NODE_SIZE, HullTree, bezier_matrices, pyramid_levels, refresh_region_kernel
from arsurf.contact.layout import (  # noqa: F401 (re-exported: callers read results by these names)
    OUT_U, OUT_V, OUT_PX, OUT_PY, OUT_PZ, OUT_NX, OUT_NY, OUT_NZ, OUT_DISTANCE, OUT_DEPTH, OUT_ITERATIONS,
    COLLISION_OUT, OUT_CELLS, OUT_CONVERGED, OUT_BOUNDARY, OUT_STATUS, OUT_CACHED, OUT_SIZE, MAX_SUBDIVISION,
    CACHE_MARGIN, CACHE_CAP, BEST_ROW, CACHE_ROW, NET_TMP, SUB_BASE, SUB_ENTRY, SUB_CAP, CACHE_LIST, STACK_ROWS,
)
from arsurf.status import BAD_INPUT, NON_FINITE, TEXT

#: the closest point and the normal, as they follow each other in the collision output: what the
#: single-query entries copy out (``point_normal``)
PN_SIZE = COLLISION_OUT.width("point") + COLLISION_OUT.width("normal")
_N = COLLISION_OUT.width("point")
from arsurf.errors import ContactError, PositionError, SurfaceError
from arsurf.spline.knots import greville
from arsurf.spline.surface import BSplineSurface

# --- the single-query entries of the Python API --------------------------------------------------
@structref.register
class _KernelArraysType(types.StructRef):
    def preprocess_fields(self, fields):
        return tuple((name, types.unliteral(t)) for name, t in fields)


class KernelArrays(structref.StructRefProxy):
    """The nine arrays of :meth:`Projector.kernel_args` and an ``out`` scratch as one numba struct:
    a Python call passes one reference instead of ten arrays (~85 ns of unboxing each)."""


structref.define_proxy(KernelArrays, _KernelArraysType,
                       ["ctrl", "ku", "kv", "mu", "mv", "nodes", "curv", "levels", "work", "out"])


@structref.register
class _TiledArraysType(types.StructRef):
    def preprocess_fields(self, fields):
        return tuple((name, types.unliteral(t)) for name, t in fields)


class TiledArrays(structref.StructRefProxy):
    """The arrays of :meth:`TiledProjector.kernel_args` and an ``out`` scratch as one numba struct."""


structref.define_proxy(TiledArrays, _TiledArraysType,
                       ["ctrl", "ku", "kv", "mu", "mv", "pnodes", "pcurv", "plevels", "pwork", "prows", "bez", "grid",
                        "slack", "tile_slot", "slot_info", "tmp", "out"])


@njit(cache=True)
def _new_kernel_arrays(args):
    """``KernelArrays(*args)`` by a cached kernel: the proxy's own constructor (numba's) is
    compiled anew in every process, ~0.5 s of CPU at each start even on a warm cache."""
    return KernelArrays(*args)


@njit(cache=True)
def _new_tiled_arrays(args):
    """``TiledArrays(*args)``, cached like :func:`_new_kernel_arrays`."""
    return TiledArrays(*args)


def _project_struct(a, cx, cy, cz, hint_u, hint_v, out):
    """:func:`project_kernel` or :func:`tiled_project_kernel` on a packed projector. Compiled
    callers get the overload below, which picks by the struct's type; from Python the call goes
    through that same compiled choice (struct fields are only readable in compiled code)."""
    return _project_struct_compiled(a, cx, cy, cz, hint_u, hint_v, out)


@overload(_project_struct, jit_options={"cache": True})
def _project_struct_impl(a, cx, cy, cz, hint_u, hint_v, out):
    if isinstance(a, _TiledArraysType):
        def tiled(a, cx, cy, cz, hint_u, hint_v, out):
            return tiled_project_kernel(a.ctrl, a.ku, a.kv, a.mu, a.mv, a.pnodes, a.pcurv, a.plevels, a.pwork,
                                        a.prows, a.bez, a.grid, a.slack, a.tile_slot, a.slot_info, a.tmp,
                                        cx, cy, cz, hint_u, hint_v, out)
        return tiled

    def one(a, cx, cy, cz, hint_u, hint_v, out):
        return project_kernel(a.ctrl, a.ku, a.kv, a.mu, a.mv, a.nodes, a.curv, a.levels, a.work,
                              cx, cy, cz, hint_u, hint_v, out)
    return one


@njit(cache=True)
def _project_struct_compiled(a, cx, cy, cz, hint_u, hint_v, out):
    return _project_struct(a, cx, cy, cz, hint_u, hint_v, out)


@njit(cache=True)
def _project_packed(a, cx, cy, cz, hint_u, hint_v, warm, point_normal):
    """:func:`project_kernel` for :func:`project`: ``point_normal`` (:data:`PN_SIZE`) gets S* and n*; returns
    ``((u, v), distance, converged, iterations, on_boundary, status, cells)``, the remaining
    fields of :class:`Projection` in order. ``warm``: a hint was given, and it must be finite."""
    out = a.out
    if warm and not (hint_u - hint_u == 0.0 and hint_v - hint_v == 0.0):
        status = BAD_INPUT
    else:
        status = _project_struct(a, cx, cy, cz, hint_u if warm else np.nan, hint_v if warm else np.nan, out)
    for k in range(PN_SIZE):
        point_normal[k] = out[OUT_PX + k]
    return ((out[OUT_U], out[OUT_V]), out[OUT_DISTANCE], out[OUT_CONVERGED] > 0.0, int(out[OUT_ITERATIONS]),
            out[OUT_BOUNDARY] > 0.0, status, int(out[OUT_CELLS]))


@njit(cache=True)
def _collide_packed(a, cx, cy, cz, radius, hint_u, hint_v, warm, point_normal):
    """:func:`collide_kernel` for :func:`collide`, like :func:`_project_packed`; returns
    ``((u, v), depth, in_contact, distance, radius, converged, iterations, on_boundary, status,
    cells)``, the fields of :class:`Contact` after ``point`` and ``normal``."""
    out = a.out
    if warm and not (hint_u - hint_u == 0.0 and hint_v - hint_v == 0.0):
        status = BAD_INPUT
    else:
        if radius > 0.0 and radius - radius == 0.0:
            status = _project_struct(a, cx, cy, cz, hint_u if warm else np.nan, hint_v if warm else np.nan, out)
            out[OUT_DEPTH] = radius - out[OUT_DISTANCE]
        else:
            status = BAD_INPUT
    for k in range(PN_SIZE):
        point_normal[k] = out[OUT_PX + k]
    depth = out[OUT_DEPTH]
    return ((out[OUT_U], out[OUT_V]), depth, depth > 0.0, out[OUT_DISTANCE], radius, out[OUT_CONVERGED] > 0.0,
            int(out[OUT_ITERATIONS]), out[OUT_BOUNDARY] > 0.0, status, int(out[OUT_CELLS]))


# --- Python side --------------------------------------------------------------------------------
class Projection(NamedTuple):
    """Closest point of a surface to a query point.

    Attributes
    ----------
    uv : (u, v) tuple of floats, metres — surface parameters of the closest point (the next
        query's ``hint``).
    point : (3,) float64, metres — the closest surface point S(u, v).
    normal : (3,) float64 — unit normal there, out of the sample (orientation of S_u x S_v).
    distance : float, metres — signed distance of the query point (> 0 above the surface).
    converged : bool — the Newton run that produced the answer met the step tolerance.
    iterations : int — Newton iterations over all runs of this query.
    on_boundary : bool — the closest point lies on the edge of the parameter domain.
    status : int — a code of :mod:`arsurf.status` (0 ok, 1 iteration limit, 2 degenerate normal).
    cells : int — knot cells whose hull box survived the distance bound.
    """

    uv: tuple
    point: np.ndarray
    normal: np.ndarray
    distance: float
    converged: bool
    iterations: int
    on_boundary: bool
    status: int
    cells: int


class Contact(NamedTuple):
    """Tip sphere against the surface.

    Attributes
    ----------
    point, normal, uv : as in :class:`Projection`.
    depth : float, metres — indentation R - distance (> 0: the sphere penetrates).
    in_contact : bool — depth > 0.
    distance : float, metres — signed distance of the centre.
    radius : float, metres — the tip radius used.
    converged, iterations, on_boundary, status, cells : as in :class:`Projection`.
    """

    point: np.ndarray
    normal: np.ndarray
    uv: tuple
    depth: float
    in_contact: bool
    distance: float
    radius: float
    converged: bool
    iterations: int
    on_boundary: bool
    status: int
    cells: int


class ProjectionBatch(NamedTuple):
    """Closest points of many query points (arrays over the n queries; fields of :class:`Projection`)."""

    uv: np.ndarray
    point: np.ndarray
    normal: np.ndarray
    distance: np.ndarray
    converged: np.ndarray
    iterations: np.ndarray
    on_boundary: np.ndarray
    status: np.ndarray
    cells: np.ndarray


class ContactBatch(NamedTuple):
    """Contacts of many tip positions (arrays over the n queries; fields of :class:`Contact`)."""

    point: np.ndarray
    normal: np.ndarray
    uv: np.ndarray
    depth: np.ndarray
    in_contact: np.ndarray
    distance: np.ndarray
    radius: float
    converged: np.ndarray
    iterations: np.ndarray
    on_boundary: np.ndarray
    status: np.ndarray
    cells: np.ndarray


class _Entries:
    """The compiled single-query entries of a projector, compiled (or loaded from the cache) at
    the first :func:`project` / :func:`collide` on it: a program that only runs the loop's
    kernels (the demo, a session) never compiles them."""

    @functools.cached_property
    def _project(self):
        return _entry_point(_project_packed, self._packed, 5)

    @functools.cached_property
    def _collide(self):
        return _entry_point(_collide_packed, self._packed, 6)


class Projector(_Entries):
    """Per-surface state of the projection: the hull-box pyramid and the kernel workspace.

    Created once per surface by :func:`projector` (kept on the surface as an instance attribute,
    built lazily at the first query, O(N)). When control points move, call :meth:`refresh_region` with the index range
    that moved (O(patch)); after :meth:`BSplineSurface.reset` call :meth:`refresh`.
    The workspace makes a projector single-threaded: use one per thread.

    Examples
    --------
    >>> import numpy as np
    >>> from arsurf.spline.surface import BSplineSurface
    >>> s = BSplineSurface.from_heights(np.zeros((8, 8)), (0.0, 50e-9), (0.0, 50e-9))
    >>> p = projector(s)
    >>> out = np.empty(OUT_SIZE)
    >>> collide_kernel(*p.kernel_args(), 25e-9, 25e-9, 5e-9, 10e-9, np.nan, np.nan, out)
    0
    >>> round(float(out[OUT_DEPTH]) * 1e9, 9)
    5.0
    """

    def __init__(self, surface):
        ctrl, _, ku, kv = surface.kernel_arrays()
        if not np.isfinite(ctrl).all():
            raise SurfaceError(
                f"the surface has {int((~np.isfinite(ctrl)).any(axis=2).sum())} non-finite (NaN/inf) control "
                "points; refit from a scan without NaN (arsurf.inpaint) or reset() the surface"
            )
        self.ctrl = ctrl
        self.ku = ku
        self.kv = kv
        self.tree = HullTree(ctrl, ku, kv)
        self.work = np.zeros((STACK_ROWS + 4 * self.tree.levels.shape[0] + 8, 3))
        self.work[CACHE_ROW, 0] = -1.0  # no candidate list yet
        self._args = (self.ctrl, self.ku, self.kv, self.tree.mu, self.tree.mv, self.tree.nodes, self.tree.curv,
                      self.tree.levels, self.work)
        self._packed = _new_kernel_arrays((*self._args, np.empty(OUT_SIZE)))

    def __reduce__(self):
        # a pickled or deep-copied surface drops its projector (compiled entry points do not
        # pickle): the copy builds its own at its first query
        return _no_projector, ()

    def kernel_args(self) -> tuple:
        """``(ctrl, ku, kv, mu, mv, nodes, curv, levels, work)``: the leading arguments of the kernels
        (:func:`collide_kernel`, :func:`project_kernel`, :func:`project_batch_kernel`)."""
        return self._args

    def refresh_region(self, iu0: int, iu1: int, iv0: int, iv1: int) -> None:
        """Update after control points ``ctrl[iu0:iu1, iv0:iv1]`` (half-open) moved; O(patch).

        Numba callers use :func:`arsurf.contact.hull_tree.refresh_region_kernel` with
        ``(ctrl, tree.mu, tree.mv, tree.boxes, tree.levels, tree.rows, iu0, iu1, iv0, iv1)``.
        """
        self.tree.refresh_region(iu0, iu1, iv0, iv1)

    def refresh(self) -> None:
        """Rebuild everything from the current net, O(N) (after ``surface.reset()``)."""
        self.tree.refresh()


#: surfaces with more knot cells than this get a :class:`TiledProjector` (the whole pyramid of
#: 256 x 256 cells builds in ~0.05 s and takes ~12 MB; beyond, build time and memory grow with N,
#: while the tiles stay at the cost of what the tip visits: bench/scale.py)
TILED_ABOVE = 256 * 256
#: cells per tile side: a tile builds in ~0.2 ms (256 cells), well inside one 1 kHz tick
TILE = 16
#: memory the tile pool may use at most, bytes
POOL_BYTES = 64 << 20


class TiledProjector(_Entries):
    """The projection state of a large surface: hull-box pyramids built per tile, on demand.

    The knot cells are cut into ``tile`` x ``tile`` tiles; a tile's pyramid is built the first
    time a query needs it (:func:`arsurf.contact.closest_point.tiled_project_kernel`: O(tile) in
    the query that needs it, plus at most one tile built ahead per query), kept in a pool of
    slots and evicted least-recently-used when the pool (``pool_bytes``) is full. Results equal
    those of :class:`Projector` (the same search runs in each tile; the tiles a query skips are
    farther than its answer). Memory: the pool, plus 8 bytes per tile.

    Parameters
    ----------
    surface : BSplineSurface
    tile : int
        Knot cells per tile side (>= 1).
    pool_bytes : int
        Memory budget of the tile pool (at least 4 slots are kept).

    Examples
    --------
    >>> import numpy as np
    >>> from arsurf.spline.surface import BSplineSurface
    >>> s = BSplineSurface.from_heights(np.zeros((40, 40)), (0.0, 39e-9), (0.0, 39e-9))
    >>> p = TiledProjector(s, tile=8)
    >>> out = np.empty(OUT_SIZE)
    >>> collide_any(p.kernel_args(), 20e-9, 20e-9, 5e-9, 10e-9, np.nan, np.nan, out), round(float(out[OUT_DEPTH]) * 1e9, 6)
    (0, 5.0)
    >>> p.tiles_built <= 9 < p.tile_count
    True
    """

    def __init__(self, surface, tile: int = TILE, pool_bytes: int = POOL_BYTES):
        ctrl, ku, kv = surface.net_arrays()
        tile = int(tile)
        if tile < 1:
            raise SurfaceError(f"tile must be >= 1 knot cells (got {tile})")
        nu, nv = ctrl.shape[0], ctrl.shape[1]
        ncu, ncv = nu - 3, nv - 3
        self.ctrl, self.ku, self.kv = ctrl, ku, kv
        self.tile = tile
        nti, ntj = -(-ncu // tile), -(-ncv // tile)
        levels = pyramid_levels(min(tile, ncu), min(tile, ncv))
        nlev = levels.shape[0]
        n_nodes = int(levels[-1, 0] + levels[-1, 1] * levels[-1, 2])
        work_rows = STACK_ROWS + 4 * nlev + 8
        slot_bytes = ((n_nodes + 1) * NODE_SIZE * 8 + tile * tile * CURV_SIZE * 4 + work_rows * 24
                      + 4 * (min(tile, ncv) + 3) * 24 + nlev * 24 + 32)
        slots = int(min(nti * ntj, max(4, int(pool_bytes) // slot_bytes)))
        self.pnodes = np.zeros((slots, n_nodes + 1, NODE_SIZE))
        self.pcurv = np.zeros((slots, min(tile, ncu) * min(tile, ncv), CURV_SIZE), dtype=np.float32)
        self.plevels = np.zeros((slots, nlev, 3), dtype=np.int64)
        self.pwork = np.zeros((slots, work_rows, 3))
        self.prows = np.zeros((slots, 4, min(tile, ncv) + 3, 3))
        self.bez = np.zeros((16, 3))
        self.grid = np.zeros(G_SIZE, dtype=np.int64)
        self.grid[[G_TILE, G_NTI, G_NTJ, G_NCU, G_NCV, G_SLOTS]] = (tile, nti, ntj, ncu, ncv, slots)
        self.tile_slot = np.full((nti, ntj), -1, dtype=np.int64)
        self.slot_info = np.zeros((slots, SLOT_INFO.size), dtype=np.int64)
        self.slot_info[:, SI_USED] = -1
        self.slack = np.zeros(1)
        self._greville = (greville(ku), greville(kv))
        self._surface_at_rest = surface.at_rest
        if not self._surface_at_rest:
            self._widen_slack(0, nu, 0, nv)
        self.mu = bezier_matrices(ku)
        self.mv = bezier_matrices(kv)
        self._args = (ctrl, ku, kv, self.mu, self.mv, self.pnodes, self.pcurv, self.plevels, self.pwork, self.prows,
                      self.bez, self.grid, self.slack, self.tile_slot, self.slot_info, np.empty(OUT_SIZE))
        self._packed = _new_tiled_arrays((*self._args, np.empty(OUT_SIZE)))

    def __reduce__(self):
        return _no_projector, ()

    @property
    def tile_count(self) -> int:
        return int(self.grid[G_NTI] * self.grid[G_NTJ])

    @property
    def tiles_built(self) -> int:
        """Tiles whose pyramid is in the pool now."""
        return int((self.tile_slot >= 0).sum())

    @property
    def builds(self) -> int:
        """Tile builds so far (evicted tiles built again count again)."""
        return int(self.grid[G_BUILDS])

    @property
    def nbytes(self) -> int:
        """Memory of the structure (pool, tile table, Bézier matrices), bytes."""
        return int(sum(a.nbytes for a in (self.pnodes, self.pcurv, self.plevels, self.pwork, self.prows,
                                          self.tile_slot, self.slot_info, self.mu, self.mv)))

    def kernel_args(self) -> tuple:
        """The leading arguments of :func:`arsurf.contact.closest_point.tiled_collide_kernel` (and of
        :func:`arsurf.contact.closest_point.collide_any`, which takes the tuple)."""
        return self._args

    def _widen_slack(self, iu0, iu1, iv0, iv1) -> None:
        """slack >= the horizontal displacement of control points [iu0:iu1, iv0:iv1] from their
        Greville positions (where x(u) = u puts them at rest)."""
        net = self.ctrl[iu0:iu1, iv0:iv1]
        if net.size == 0:
            return
        gu, gv = self._greville
        dev = max(float(np.max(np.abs(net[..., 0] - gu[iu0:iu1, None]))),
                  float(np.max(np.abs(net[..., 1] - gv[None, iv0:iv1]))))
        if not np.isfinite(dev):
            return  # NaN points: the tiles holding them refuse to build
        scale = max(float(np.max(np.abs(gu))), float(np.max(np.abs(gv))), 1e-300)
        self.slack[0] = max(self.slack[0], dev + 1e-12 * scale)

    def refresh_region(self, iu0: int, iu1: int, iv0: int, iv1: int) -> None:
        """Update after control points ``ctrl[iu0:iu1, iv0:iv1]`` (half-open) moved; O(patch)."""
        nu, nv = self.ctrl.shape[0], self.ctrl.shape[1]
        iu0, iu1, iv0, iv1 = int(iu0), int(iu1), int(iv0), int(iv1)
        if not (0 <= iu0 <= iu1 <= nu and 0 <= iv0 <= iv1 <= nv):
            raise SurfaceError(f"refresh region [{iu0}:{iu1}, {iv0}:{iv1}] is not inside the {nu}x{nv} control net; "
                               "pass half-open index ranges 0 <= i0 <= i1 <= n")
        self._widen_slack(iu0, iu1, iv0, iv1)
        t = self.tile
        ncu, ncv = nu - 3, nv - 3
        for ti in range(max(iu0 - 3, 0) // t, min(max(iu1 - 1, 0), ncu - 1) // t + 1):
            for tj in range(max(iv0 - 3, 0) // t, min(max(iv1 - 1, 0), ncv - 1) // t + 1):
                s = int(self.tile_slot[ti, tj])
                if s < 0:
                    continue
                i0, j0 = ti * t, tj * t
                ni, nj = min(t, ncu - i0), min(t, ncv - j0)
                nlev = int(self.slot_info[s, 2])
                nn = int(self.plevels[s, nlev - 1, 0]) + 1
                bad = refresh_region_kernel(
                    self.ctrl[i0:i0 + ni + 3, j0:j0 + nj + 3], self.ku[i0:i0 + ni + 7], self.kv[j0:j0 + nj + 7],
                    self.mu[i0:i0 + ni], self.mv[j0:j0 + nj], self.pnodes[s, :nn + 1], self.pcurv[s, :ni * nj],
                    self.plevels[s, :nlev], self.prows[s, :, :nj + 3], self.bez,
                    max(iu0 - i0, 0), min(iu1 - i0, ni + 3), max(iv0 - j0, 0), min(iv1 - j0, nj + 3))
                if bad:
                    raise SurfaceError(f"the control net has non-finite (NaN/inf) points in {bad} knot cells of the "
                                       f"region [{iu0}:{iu1}, {iv0}:{iv1}]; refit from a scan without NaN "
                                       "(arsurf.inpaint) or reset() the surface")

    def refresh(self) -> None:
        """Forget every tile (rebuilt on demand from the current net), O(tiles)."""
        self.tile_slot[:] = -1
        self.slot_info[:, SI_USED] = -1
        self.grid[G_USED] = 0
        self.slack[0] = 0.0
        nu, nv = self.ctrl.shape[0], self.ctrl.shape[1]
        self._widen_slack(0, nu, 0, nv)


def _entry_point(kernel, arrays, nscalars):
    """The compiled entry of ``kernel(arrays, *scalars, warm, point_normal)`` for exactly these
    argument types.

    Calling it skips the dispatcher's per-call type resolution (~0.3-1 us of a few-us call);
    the Python API always passes these same types. Falls back to the dispatcher."""
    args = (arrays, *(1.0,) * nscalars, False, np.empty(PN_SIZE))
    try:
        sig = tuple(numba.typeof(a) for a in args)
        kernel.compile(sig)  # compiles (or loads from the cache) this signature, without running it
        return kernel.overloads[sig].entry_point
    except (KeyError, AttributeError):  # pragma: no cover - numba internals changed
        return kernel


_ATTR = "_arsurf_projector"  # where a surface keeps its Projector (an instance attribute)


def _no_projector() -> None:
    """What an unpickled projector becomes (see :meth:`Projector.__reduce__`)."""
    return None


def projector(surface) -> Projector:
    """The :class:`Projector` of ``surface`` (built at the first call, then cached per surface)."""
    if not isinstance(surface, BSplineSurface):
        raise SurfaceError(f"expected an arsurf BSplineSurface (got {type(surface).__name__})")
    proj = surface.__dict__.get(_ATTR)
    if proj is None or proj.ctrl is not surface.net_arrays()[0]:
        nu, nv = surface.shape
        proj = TiledProjector(surface) if (nu - 3) * (nv - 3) > TILED_ABOVE else Projector(surface)
        setattr(surface, _ATTR, proj)
        surface.attach(proj)  # reset() refreshes the boxes
    return proj


def _lookup(surface) -> Projector:
    proj = getattr(surface, _ATTR, None)
    return proj if proj is not None else projector(surface)


def refresh_region(surface, iu0: int, iu1: int, iv0: int, iv1: int) -> None:
    """Tell the projection that control points ``[iu0:iu1, iv0:iv1]`` of ``surface`` moved (O(patch))."""
    if not isinstance(surface, BSplineSurface):
        raise SurfaceError(f"expected an arsurf BSplineSurface (got {type(surface).__name__})")
    proj = getattr(surface, _ATTR, None)
    if proj is not None:  # else no projector yet: it will be built from the current net
        proj.refresh_region(iu0, iu1, iv0, iv1)


_new_tuple = tuple.__new__  # builds a NamedTuple from a tuple without its keyword-parsing __new__


def _single(entry, packed, point_normal, point, hint, radius=None) -> tuple:
    """Run one query through ``entry`` (:func:`_project_packed` or :func:`_collide_packed`).

    The fast path hands the caller's numbers straight to the compiled entry (it converts them
    like ``float()``, and rejects a non-finite point, hint or radius with ``BAD_INPUT``).
    Anything unusual takes the slow path: the exact checks, with the precise error."""
    try:
        x, y, z = point
        if hint is None:
            res = (entry(packed, x, y, z, 0.0, 0.0, False, point_normal) if radius is None else
                   entry(packed, x, y, z, radius, 0.0, 0.0, False, point_normal))
        else:
            hu, hv = hint
            res = (entry(packed, x, y, z, hu, hv, True, point_normal) if radius is None else
                   entry(packed, x, y, z, radius, hu, hv, True, point_normal))
        if res[-2] >= 0:
            return res
    except (TypeError, ValueError):
        pass
    x, y, z = _xyz(point, "point" if radius is None else "center")
    hu, hv = _hint(hint)
    res = (entry(packed, x, y, z, hu, hv, hint is not None, point_normal) if radius is None else
           entry(packed, x, y, z, _radius(radius), hu, hv, hint is not None, point_normal))
    if res[-2] < 0:
        _raise_status(res[-2], "project" if radius is None else "collide")
    return res


def _xyz(point, what: str) -> tuple[float, float, float]:
    try:
        x, y, z = point
        x, y, z = float(x), float(y), float(z)
    except (TypeError, ValueError):
        raise PositionError(f"{what} must be 3 coordinates (x, y, z) in metres (got {point!r})") from None
    if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
        raise PositionError(f"{what} must be finite (got ({x!r}, {y!r}, {z!r})); check the tip position source")
    return x, y, z


def _hint(hint) -> tuple[float, float]:
    if hint is None:
        return math.nan, math.nan
    try:
        hu, hv = hint
        hu, hv = float(hu), float(hv)
    except (TypeError, ValueError):
        raise SurfaceError(f"hint must be None or (u, v) in metres (got {hint!r})") from None
    if not (math.isfinite(hu) and math.isfinite(hv)):
        raise SurfaceError(f"hint must be finite (got ({hu!r}, {hv!r})); pass None for a cold start")
    return hu, hv


def _radius(radius) -> float:
    try:
        r = float(radius)
    except (TypeError, ValueError):
        raise ContactError(f"radius must be a number in metres (got {radius!r})") from None
    if not (math.isfinite(r) and r > 0.0):
        raise ContactError(f"the tip radius must be positive and finite (got {r!r} m); it is the sphere radius R")
    return r


def _raise_status(status: int, where: str) -> None:
    if status == NON_FINITE:
        raise SurfaceError(
            f"{where}: the surface has non-finite (NaN/inf) control points; refit from a scan without "
            "NaN (arsurf.inpaint) or reset() the surface"
        )
    raise SurfaceError(f"{where}: {TEXT.get(status, 'unknown status')} (status {status})")


def project(surface, point, hint=None) -> Projection:
    """Global closest point of ``surface`` to ``point`` (safeguarded Newton, certified by hull bounds).

    .. math:: (u^*, v^*) = \\arg\\min_{(u, v)} \\tfrac12 |S(u, v) - C|^2

    Parameters
    ----------
    surface : BSplineSurface
    point : (3,) float, metres
        Query point C.
    hint : (u, v) float, metres, optional
        Warm start, e.g. the previous tick's ``uv``. It only speeds the search up: a closer
        basin elsewhere is still found.

    Returns
    -------
    Projection

    Raises
    ------
    SurfaceError
        Non-finite point or hint, or a surface with NaN/inf control points.

    Examples
    --------
    >>> import numpy as np
    >>> from arsurf.spline.surface import BSplineSurface
    >>> s = BSplineSurface.from_heights(np.zeros((8, 8)), (0.0, 50e-9), (0.0, 50e-9))
    >>> p = project(s, (10e-9, 20e-9, -3e-9))
    >>> round(p.distance * 1e9, 9), (p.point * 1e9).round(9).tolist()
    (-3.0, [10.0, 20.0, 0.0])
    """
    proj = getattr(surface, _ATTR, None) or _lookup(surface)
    pn = np.empty(PN_SIZE)  # S* and n*: two views of one fresh array (slicing one array is the cheapest)
    res = _single(proj._project, proj._packed, pn, point, hint)
    return _new_tuple(Projection, (res[0], pn[:_N], pn[_N:]) + res[1:])


def collide(surface, center, radius, hint=None) -> Contact:
    """Contact of a tip sphere (centre C, radius R) with ``surface``.

    .. math:: \\delta = R - d(C), \\qquad d(C) = (C - S^*)\\cdot n^*

    Parameters
    ----------
    surface : BSplineSurface
    center : (3,) float, metres
    radius : float, metres (> 0)
    hint : (u, v) float, metres, optional — warm start (previous ``uv``).

    Returns
    -------
    Contact

    Raises
    ------
    SurfaceError, ContactError
        Non-finite centre or hint, NaN control points (SurfaceError); radius <= 0 (ContactError).

    Examples
    --------
    >>> import numpy as np
    >>> from arsurf.spline.surface import BSplineSurface
    >>> s = BSplineSurface.from_heights(np.zeros((8, 8)), (0.0, 50e-9), (0.0, 50e-9))
    >>> c = collide(s, (10e-9, 20e-9, 4e-9), 5e-9)
    >>> c.in_contact, round(c.depth * 1e9, 9)
    (True, 1.0)
    """
    proj = getattr(surface, _ATTR, None) or _lookup(surface)
    pn = np.empty(PN_SIZE)  # S* and n*: two views of one fresh array (slicing one array is the cheapest)
    res = _single(proj._collide, proj._packed, pn, center, hint, radius)
    return _new_tuple(Contact, (pn[:_N], pn[_N:]) + res)


def _batch(surface, points, hints, chain, radius, where):
    proj = _lookup(surface)
    pts = np.ascontiguousarray(points, dtype=np.float64)
    if pts.ndim == 1 and pts.size == 3:
        pts = pts.reshape(1, 3)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise SurfaceError(f"points must have shape (n, 3) in metres (got {np.shape(points)})")
    if not np.isfinite(pts).all():
        bad = np.flatnonzero(~np.isfinite(pts).all(axis=1))
        raise PositionError(f"points must be finite: {bad.size} rows hold NaN/inf (first: row {bad[0]})")
    if hints is None:
        hts = np.empty((0, 2))
    else:
        hts = np.ascontiguousarray(hints, dtype=np.float64)
        if hts.shape != (pts.shape[0], 2):
            raise SurfaceError(f"hints must have shape ({pts.shape[0]}, 2) (got {hts.shape}); NaN rows mean cold")
    out = np.empty((pts.shape[0], OUT_SIZE))
    worst = project_batch_kernel(proj._args, pts, hts, bool(chain), radius, out)
    if worst < 0:
        _raise_status(int(worst), where)
    return out


def project_many(surface, points, hints=None, chain: bool = False) -> ProjectionBatch:
    """:func:`project` for an (n, 3) array of points, in one kernel call.

    Parameters
    ----------
    points : (n, 3) float, metres
    hints : (n, 2) float, metres, optional
        Per-query warm starts (NaN rows: cold).
    chain : bool
        Warm-start each query from the previous answer (a trajectory, as in replay).

    Examples
    --------
    >>> import numpy as np
    >>> from arsurf.spline.surface import BSplineSurface
    >>> s = BSplineSurface.from_heights(np.zeros((8, 8)), (0.0, 50e-9), (0.0, 50e-9))
    >>> b = project_many(s, [[10e-9, 10e-9, 1e-9], [20e-9, 20e-9, 2e-9]])
    >>> (b.distance * 1e9).round(9).tolist()
    [1.0, 2.0]
    """
    out = _batch(surface, points, hints, chain, 0.0, "project_many")
    return ProjectionBatch(out[:, 0:2], out[:, 2:5], out[:, 5:8], out[:, OUT_DISTANCE].copy(),
                           out[:, OUT_CONVERGED] > 0, out[:, OUT_ITERATIONS].astype(np.int64),
                           out[:, OUT_BOUNDARY] > 0, out[:, OUT_STATUS].astype(np.int64),
                           out[:, OUT_CELLS].astype(np.int64))


def collide_many(surface, centers, radius, hints=None, chain: bool = False) -> ContactBatch:
    """:func:`collide` for an (n, 3) array of tip centres with one radius, in one kernel call.

    Examples
    --------
    >>> import numpy as np
    >>> from arsurf.spline.surface import BSplineSurface
    >>> s = BSplineSurface.from_heights(np.zeros((8, 8)), (0.0, 50e-9), (0.0, 50e-9))
    >>> b = collide_many(s, [[10e-9, 10e-9, 1e-9], [20e-9, 20e-9, 9e-9]], radius=5e-9)
    >>> b.in_contact.tolist()
    [True, False]
    """
    r = _radius(radius)
    out = _batch(surface, centers, hints, chain, r, "collide_many")
    depth = out[:, OUT_DEPTH].copy()
    return ContactBatch(out[:, 2:5], out[:, 5:8], out[:, 0:2], depth, depth > 0.0, out[:, OUT_DISTANCE].copy(), r,
                        out[:, OUT_CONVERGED] > 0, out[:, OUT_ITERATIONS].astype(np.int64),
                        out[:, OUT_BOUNDARY] > 0, out[:, OUT_STATUS].astype(np.int64),
                        out[:, OUT_CELLS].astype(np.int64))
