"""Layouts of the closest-point kernels: the output vector and the rows of the work array.

Shared by :mod:`arsurf.contact.closest_point` (the kernels that write them) and
:mod:`arsurf.contact.projection` (the Python API that reads them). The status a kernel returns
(and stores at ``OUT_STATUS``) is a code of :mod:`arsurf.status`: ``OK``; ``ITERATION_LIMIT`` (the
best point found is returned); ``DEGENERATE`` (S_u x S_v vanishes at the answer: the normal is taken
along C - S, or +z); ``NON_FINITE`` (NaN/inf met in the control net: no answer); ``BAD_INPUT``
(a non-finite query point or a radius <= 0, checked in the kernel).
"""
from __future__ import annotations

from arsurf._layout import Layout
from arsurf.contact.newton import EVALUATION_ROWS

#: the output vector the kernels write (float64): parameters (u, v); the closest point and the unit
#: normal; the signed distance of C (m, > 0 above); R - distance (collide only, m); Newton iterations
#: summed over all runs of the query; knot cells whose hull box survived the bound (Newton-checked or
#: skipped); 1.0 if the Newton run that produced the answer converged; 1.0 if the closest point lies
#: on the domain boundary; the status; 1.0 if the warm-start candidate list was used instead of the
#: pyramid; where Newton from the hint converged, over the whole domain (NaN: not known)
COLLISION_OUT = Layout("collision output", [
    ("uv", 2), ("point", 3), ("normal", 3), ("distance", 1), ("depth", 1), ("iterations", 1), ("cells", 1),
    ("converged", 1), ("boundary", 1), ("status", 1), ("cached", 1), ("warm_uv", 2)])
# the offsets as the kernels use them
OUT_U = COLLISION_OUT.offset("uv")
OUT_V = OUT_U + 1
OUT_PX = COLLISION_OUT.offset("point")
OUT_PY, OUT_PZ = OUT_PX + 1, OUT_PX + 2
OUT_NX = COLLISION_OUT.offset("normal")
OUT_NY, OUT_NZ = OUT_NX + 1, OUT_NX + 2
OUT_DISTANCE = COLLISION_OUT.offset("distance")
OUT_DEPTH = COLLISION_OUT.offset("depth")
OUT_ITERATIONS = COLLISION_OUT.offset("iterations")
OUT_CELLS = COLLISION_OUT.offset("cells")
OUT_CONVERGED = COLLISION_OUT.offset("converged")
OUT_BOUNDARY = COLLISION_OUT.offset("boundary")
OUT_STATUS = COLLISION_OUT.offset("status")
OUT_CACHED = COLLISION_OUT.offset("cached")
OUT_WARM_U = COLLISION_OUT.offset("warm_uv")
OUT_WARM_V = OUT_WARM_U + 1
OUT_SIZE = COLLISION_OUT.size

# Cells whose convexity certificate fails (C farther from them than their convexity radius) are
# split into Bézier quarters, each pruned by its own box and certificate, down to this depth.
MAX_SUBDIVISION = 3
# Warm queries keep the cells within d* + CACHE_MARGIN h of the tip centre in a list (at most
# CACHE_CAP cells) and reuse it while the tip stays inside that margin (project_kernel, Notes).
CACHE_MARGIN = 0.5
CACHE_CAP = 512
# The subdivided search keeps what it learnt of a Bézier piece that does not depend on the tip
# centre (the piece's curvature bounds, |S_u| and |S_v| bounds, and the surface at its centre) in a
# direct-mapped memo of PIECE_MEMO entries of MEMO_ROWS rows: (key, version, tree id); the 10
# numbers of net_curvature and the two speeds (4 rows); the evaluation at the centre (6 rows).
PIECE_MEMO = 256
MEMO_ROWS = 11
#: rows of a subdivision stack entry: the 16 net rows and (u0, u1, v0), (v1, depth, piece id)
SUB_ENTRY = 18
SUB_CAP = 3 * MAX_SUBDIVISION + 1
#: the rows (of 3 floats) of the work array: Newton's evaluation block; S, S_u, S_v of the best
#: point; the cache header (version, tree id, count), (C0), (R0, -, -); a Bézier net being split;
#: the subdivision stack; the cache list, one (cell, distance from C0, -) per row; scratch of its sort
#: (closest_point.sort_candidates); the piece memo; then the pyramid search stack, one (level, i, j) per row
COLLISION_WORK = Layout("collision work rows", [
    ("evaluation", EVALUATION_ROWS), ("best", 3), ("cache_header", 3), ("net", 16),
    ("subdivision", SUB_ENTRY * SUB_CAP), ("cache_list", CACHE_CAP), ("cache_sort", CACHE_CAP),
    ("piece_memo", PIECE_MEMO * MEMO_ROWS)])
BEST_ROW = COLLISION_WORK.offset("best")
CACHE_ROW = COLLISION_WORK.offset("cache_header")
NET_TMP = COLLISION_WORK.offset("net")
SUB_BASE = COLLISION_WORK.offset("subdivision")
CACHE_LIST = COLLISION_WORK.offset("cache_list")
CACHE_SORT = COLLISION_WORK.offset("cache_sort")
MEMO_BASE = COLLISION_WORK.offset("piece_memo")
STACK_ROWS = COLLISION_WORK.size
