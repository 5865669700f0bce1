r"""The view's per-frame work on a patch of its sampled grid (numba kernels).

A dent moves a few control points; by the B-spline's local support it changes the sampled grid
only in a box of samples around them. These kernels do everything a frame needs on such a box,
in place in the arrays the VTK mesh reads, with no Python loop over samples:

* :func:`changed_box` - the box of control points that moved since the view last looked;
* :func:`sample_patch` - the surface points (nm), exact unit normals
  :math:`\mathbf n = S_u \times S_v / |S_u \times S_v|`, heights and deformation
  :math:`|S - S_{rest}|` of a box of grid samples;
* :func:`dent_boxes` - the boxes of deformed samples (deformation > 0) inside a box, one per
  dent apart from the others, and the deepest deformation in each (:func:`dent_extent`): a
  sample at rest is bitwise its rest point (same net, same kernel), so its deformation is
  exactly 0;
* :func:`contour_patch` - the dent's contour lines (marching squares on the box's cells, saddles
  resolved by the cell's mean), each end of a segment put on the sampled surface by linear
  interpolation along the cell's edge.

The arrays are the grid's, indexed [row = v sample, column = u sample]; boxes are half-open
(iu0, iu1, jv0, jv1) sample index ranges.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from arsurf.spline.basis import N_ROWS, S, SU, SV, surface_point

__all__ = ["changed_box", "sample_patch", "dent_extent", "dent_boxes", "contour_patch"]


@njit(cache=True)
def changed_box(ctrl, last):
    """Index box (i0, i1, j0, j1) of the control points where ``ctrl`` differs from ``last``
    (empty: i1 = i0 = 0), copied into ``last``: one pass, no temporaries."""
    nu, nv = ctrl.shape[0], ctrl.shape[1]
    i0, i1, j0, j1 = nu, -1, nv, -1
    for i in range(nu):
        for j in range(nv):
            if ctrl[i, j, 0] != last[i, j, 0] or ctrl[i, j, 1] != last[i, j, 1] or ctrl[i, j, 2] != last[i, j, 2]:
                i0 = min(i0, i)
                i1 = max(i1, i)
                j0 = min(j0, j)
                j1 = max(j1, j)
    if i1 < 0:
        return 0, 0, 0, 0
    for i in range(i0, i1 + 1):
        for j in range(j0, j1 + 1):
            for c in range(3):
                last[i, j, c] = ctrl[i, j, c]
    return i0, i1 + 1, j0, j1 + 1


@njit(cache=True)
def sample_patch(ctrl, ku, kv, us, vs, iu0, iu1, jv0, jv1, scale, rest, pts, normals, height, deform):
    """Re-sample the grid box [jv0, jv1) x [iu0, iu1) of the surface (``ctrl``, ``ku``, ``kv``,
    metres) at parameters ``us`` (columns) and ``vs`` (rows), in place.

    Writes ``pts`` (rows, cols, 3) = S * ``scale`` (nm with scale 1e9), ``normals`` (rows, cols, 3)
    the unit normal S_u x S_v / |S_u x S_v| (the norm floored at 1e-300), ``height`` (rows, cols)
    the z of ``pts`` and ``deform`` (rows, cols) = |pts - rest| with ``rest`` (rows, cols, 3) the
    rest surface's points in the same unit."""
    out = np.empty((N_ROWS, 3))
    first = np.int64(1)  # derivatives to first order, typed as the engine's calls type it (not a literal 1,
    for j in range(jv0, jv1):  # which would compile another specialisation of surface_point)
        v = vs[j]
        for i in range(iu0, iu1):
            surface_point(ctrl, ku, kv, us[i], v, first, out)
            x = out[S, 0] * scale
            y = out[S, 1] * scale
            z = out[S, 2] * scale
            pts[j, i, 0] = x
            pts[j, i, 1] = y
            pts[j, i, 2] = z
            nx = out[SU, 1] * out[SV, 2] - out[SU, 2] * out[SV, 1]
            ny = out[SU, 2] * out[SV, 0] - out[SU, 0] * out[SV, 2]
            nz = out[SU, 0] * out[SV, 1] - out[SU, 1] * out[SV, 0]
            nn = max(math.sqrt(nx * nx + ny * ny + nz * nz), 1e-300)
            normals[j, i, 0] = nx / nn
            normals[j, i, 1] = ny / nn
            normals[j, i, 2] = nz / nn
            height[j, i] = z
            dx = x - rest[j, i, 0]
            dy = y - rest[j, i, 1]
            dz = z - rest[j, i, 2]
            deform[j, i] = math.sqrt(dx * dx + dy * dy + dz * dz)


@njit(cache=True)
def dent_extent(deform, iu0, iu1, jv0, jv1):
    """(iu0, iu1, jv0, jv1, top): the box of samples with ``deform`` > 0 inside the given box
    (all zero when none) and the largest ``deform`` there (0 when none)."""
    a0, a1, b0, b1 = iu1, iu0 - 1, jv1, jv0 - 1
    top = 0.0
    for j in range(jv0, jv1):
        for i in range(iu0, iu1):
            d = deform[j, i]
            if d > 0.0:
                a0 = min(a0, i)
                a1 = max(a1, i)
                b0 = min(b0, j)
                b1 = max(b1, j)
                top = max(top, d)
    if a1 < a0:
        return 0, 0, 0, 0, 0.0
    return a0, a1 + 1, b0, b1 + 1, top


@njit(cache=True, inline="always")
def _next_run(flags, k, stop, first):
    """The next run of set flags at index k or after: (start, end) with ``flags[start - first:end -
    first]`` all set; start == stop when there is none."""
    while k < stop and not flags[k - first]:
        k += 1
    start = k
    while k < stop and flags[k - first]:
        k += 1
    return start, k


@njit(cache=True)
def dent_boxes(deform, iu0, iu1, jv0, jv1, out):
    """The deformed samples (``deform`` > 0) of the given box as separate boxes: the box is cut
    at its rows with no deformed sample, each band at its columns with none, and each piece
    shrunk to its deformed samples (:func:`dent_extent`), so dents apart (two contacts) keep a
    box each. Writes (iu0, iu1, jv0, jv1, top) of box k to ``out[k]`` (m, 5) while it fits;
    returns the number of boxes (call again with a larger ``out`` when it exceeds m)."""
    n = 0
    rows = np.zeros(max(jv1 - jv0, 0), np.bool_)
    for j in range(jv0, jv1):
        for i in range(iu0, iu1):
            if deform[j, i] > 0.0:
                rows[j - jv0] = True
                break
    cols = np.zeros(max(iu1 - iu0, 0), np.bool_)
    r0, j = _next_run(rows, jv0, jv1, jv0)
    while r0 < jv1:
        cols[:] = False
        for jj in range(r0, j):
            for i in range(iu0, iu1):
                if deform[jj, i] > 0.0:
                    cols[i - iu0] = True
        c0, i = _next_run(cols, iu0, iu1, iu0)
        while c0 < iu1:
            a0, a1, b0, b1, top = dent_extent(deform, c0, i, r0, j)
            if n < out.shape[0]:
                out[n, 0] = a0
                out[n, 1] = a1
                out[n, 2] = b0
                out[n, 3] = b1
                out[n, 4] = top
            n += 1
            c0, i = _next_run(cols, i, iu1, iu0)
        r0, j = _next_run(rows, j, jv1, jv0)
    return n


@njit(cache=True)
def contour_patch(f, pts, iu0, iu1, jv0, jv1, levels, out):
    """Contour lines of ``f`` (rows, cols) at each of ``levels`` over the cells of the sample box
    [jv0, jv1) x [iu0, iu1), as segments on the surface ``pts`` (rows, cols, 3).

    Marching squares: a corner is inside when f >= level; the two ambiguous cases (opposite
    corners inside) join the inside corners when the mean of the four values is inside. A
    segment's end is where f crosses the level on a cell edge, on the straight line between the
    edge's two samples' points (linear interpolation from the lower-index sample). Segment k's
    ends go to ``out[2k]`` and ``out[2k + 1]`` as long as they fit. Returns the number of
    segments (call again with a larger ``out`` when it exceeds ``out.shape[0] // 2``)."""
    n = 0
    cap = out.shape[0]
    for level in levels:
        for j in range(jv0, jv1 - 1):
            for i in range(iu0, iu1 - 1):
                fa = f[j, i]  # corners a = (j, i), b = (j, i + 1), c = (j + 1, i + 1), d = (j + 1, i)
                fb = f[j, i + 1]
                fc = f[j + 1, i + 1]
                fd = f[j + 1, i]
                case = ((fa >= level) * 1) | ((fb >= level) * 2) | ((fc >= level) * 4) | ((fd >= level) * 8)
                if case == 0 or case == 15:
                    continue
                row = case
                if case == 5 or case == 10:  # a saddle: which pair of corners does the mean join?
                    row = _B_D_CUT if (0.25 * (fa + fb + fc + fd) >= level) == (case == 5) else _A_C_CUT
                for s in range(_SEGMENTS[row, 0, 0]):
                    for end in range(2):
                        k = 2 * n + end
                        if k < cap:
                            e = _SEGMENTS[row, 1 + s, end]
                            j0 = j + _EDGES[e, 0]
                            i0 = i + _EDGES[e, 1]
                            j1 = j + _EDGES[e, 2]
                            i1 = i + _EDGES[e, 3]
                            t = (level - f[j0, i0]) / (f[j1, i1] - f[j0, i0])
                            for c in range(3):
                                out[k, c] = pts[j0, i0, c] + t * (pts[j1, i1, c] - pts[j0, i0, c])
                    n += 1
    return n


#: the cell's edges as (row, column) offsets of their two samples, lower index first: 0 = a-b
#: (bottom), 1 = b-c (right), 2 = d-c (top), 3 = a-d (left)
_EDGES = np.array([[0, 0, 0, 1], [0, 1, 1, 1], [1, 0, 1, 1], [0, 0, 1, 0]], dtype=np.int64)
#: per marching-squares case (bit 1: corner a inside, 2: b, 4: c, 8: d): [number of segments, 0],
#: then the (from, to) edges of each segment; rows 16 and 17 are the saddles' two resolutions
_B_D_CUT, _A_C_CUT = 16, 17
_SEGMENTS = np.array([
    [[0, 0], [0, 0], [0, 0]], [[1, 0], [3, 0], [0, 0]], [[1, 0], [0, 1], [0, 0]], [[1, 0], [3, 1], [0, 0]],
    [[1, 0], [1, 2], [0, 0]], [[0, 0], [0, 0], [0, 0]], [[1, 0], [0, 2], [0, 0]], [[1, 0], [3, 2], [0, 0]],
    [[1, 0], [2, 3], [0, 0]], [[1, 0], [0, 2], [0, 0]], [[0, 0], [0, 0], [0, 0]], [[1, 0], [1, 2], [0, 0]],
    [[1, 0], [1, 3], [0, 0]], [[1, 0], [0, 1], [0, 0]], [[1, 0], [3, 0], [0, 0]], [[0, 0], [0, 0], [0, 0]],
    [[2, 0], [0, 1], [2, 3]],  # b and d cut off
    [[2, 0], [3, 0], [1, 2]],  # a and c cut off
], dtype=np.int64)
