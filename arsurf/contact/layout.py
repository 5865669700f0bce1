"""Layouts of the closest-point kernels: the output vector, the status codes, the work array.

Shared by :mod:`arsurf.contact.closest_point` (the kernels that write them) and
:mod:`arsurf.contact.projection` (the Python API that reads them).
"""
from __future__ import annotations

from arsurf import status

# --- kernel constants ---------------------------------------------------------------------------
# layout of the output vector written by the kernels (float64, OUT_SIZE)
OUT_U, OUT_V = 0, 1
OUT_PX, OUT_PY, OUT_PZ = 2, 3, 4
OUT_NX, OUT_NY, OUT_NZ = 5, 6, 7
OUT_DISTANCE = 8      # signed distance of C, metres (> 0 above)
OUT_DEPTH = 9         # R - distance (collide only), metres
OUT_ITERATIONS = 10   # Newton iterations summed over all runs of the query
OUT_CELLS = 11        # knot cells whose hull box survived the bound (Newton-checked or skipped)
OUT_CONVERGED = 12    # 1.0 if the Newton run that produced the answer converged
OUT_BOUNDARY = 13     # 1.0 if the closest point lies on the domain boundary
OUT_STATUS = 14
OUT_CACHED = 15       # 1.0 if the warm-start candidate list was used instead of the pyramid
OUT_WARM_U, OUT_WARM_V = 16, 17  # where Newton from the hint converged, over the whole domain (NaN: not known)
OUT_SIZE = 18

# status codes (returned by the kernels and stored at OUT_STATUS; the table is arsurf.status)
STATUS_OK = status.OK
STATUS_NOT_CONVERGED = status.ITERATION_LIMIT  # iteration limit hit: the answer is the best point found
STATUS_DEGENERATE = status.DEGENERATE  # S_u x S_v vanishes at the answer: normal taken along C - S (or +z)
STATUS_NON_FINITE = status.NON_FINITE  # NaN/inf met in the control net: no answer
STATUS_BAD_INPUT = status.BAD_INPUT  # non-finite query point or radius <= 0 (kernel-level check)

STATUS_TEXT = {
    STATUS_OK: "converged",
    STATUS_NOT_CONVERGED: "iteration limit reached; best point found returned",
    STATUS_DEGENERATE: "surface normal undefined (S_u x S_v = 0) at the closest point",
    STATUS_NON_FINITE: "the control net holds NaN/inf",
    STATUS_BAD_INPUT: "non-finite query point or non-positive radius",
}

# Cells whose convexity certificate fails (C farther from them than their convexity radius) are
# split into Bézier quarters, each pruned by its own box and certificate, down to this depth.
MAX_SUBDIVISION = 3
# work array rows: 0..5 the (6, 3) evaluation block; 6..8 S, S_u, S_v of the best point; 9..11
# the cache header; 12..27 a Bézier net being split; the subdivision stack (16 net rows + 2 rows
# (u0, u1, v0), (v1, depth, -) per entry); the cache list; the pyramid search stack.
# Warm queries keep the cells within d* + CACHE_MARGIN h of the tip centre in a list (at most
# CACHE_CAP cells) and reuse it while the tip stays inside that margin (project_kernel, Notes).
CACHE_MARGIN = 0.5
CACHE_CAP = 512
BEST_ROW = 6
CACHE_ROW = 9     # (version, tree id, count), (C0), (R0, -, -)
NET_TMP = 12
SUB_BASE = NET_TMP + 16
SUB_ENTRY = 18
SUB_CAP = 3 * MAX_SUBDIVISION + 1
CACHE_LIST = SUB_BASE + SUB_ENTRY * SUB_CAP   # rows (cell, distance from C0, -)
STACK_ROWS = CACHE_LIST + CACHE_CAP           # then the pyramid stack, one (level, i, j) per row
