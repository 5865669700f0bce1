"""Closest point / collision (arsurf.contact.projection, arsurf.contact.hull_tree).

References that live here: analytic closest points (plane, paraboloid: both reproduced exactly
by the bicubic fit), bounded linear least squares (plane with a boundary), the cubic equation of
the paraboloid, and a brute force: the surface sampled densely, the k nearest samples (KD-tree)
polished by plain projected Newton, the best kept (:func:`brute_force`, also used by
tests/contact/test_projection_sweep.py).
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from numba import njit
from scipy.optimize import lsq_linear

from tests.support.projection_surfaces import (H, SCANS, TOL, check_against, grid, perturbed, queries,
                                               ridges_scan, rough_scan, steps_scan, trench_scan)

from arsurf.contact import closest_point as cp
from arsurf.contact import hull_tree as cd
from arsurf import status
from arsurf.contact import projection as pj
from arsurf.contact.newton import newton_box
from arsurf.contact.projection import collide, collide_many, project, project_many, projector, refresh_region
from arsurf.errors import ContactError, SurfaceError
from arsurf.scan.scan import Scan
from arsurf.spline.fit import fit_surface
from arsurf.spline.surface import BSplineSurface

# analytic closest points
def test_tilted_plane_is_exact_inside_and_at_the_boundary(rng):
    a, b, c = 0.3, -0.2, 2e-9
    x, y = grid(24)
    s = fit_surface(Scan(a * x + b * y + c, H, H))
    (u0, u1), (v0, v1) = s.domain
    pts = np.column_stack([rng.uniform(u0 - 5e-9, u1 + 5e-9, 400), rng.uniform(v0 - 5e-9, v1 + 5e-9, 400),
                           rng.uniform(-15e-9, 15e-9, 400)])
    res = project_many(s, pts)
    # the closest point of the planar rectangle: bounded linear least squares in (x, y)
    A = np.array([[1.0, 0.0], [0.0, 1.0], [a, b]])
    for k, p in enumerate(pts):
        ref = lsq_linear(A, (p - [0, 0, c]) / H, bounds=([u0 / H, v0 / H], [u1 / H, v1 / H]), tol=1e-15,
                         lsmr_tol="auto").x * H
        foot = np.array([ref[0], ref[1], a * ref[0] + b * ref[1] + c])
        assert np.linalg.norm(res.point[k] - foot) < 1e-17
        assert abs(abs(res.distance[k]) - np.linalg.norm(p - foot)) < 1e-18
        edge = 1e-18  # lsq_linear lands within a few ulps of an active bound
        inside = u0 + edge < ref[0] < u1 - edge and v0 + edge < ref[1] < v1 - edge
        assert res.on_boundary[k] == (not inside)
    n = np.array([-a, -b, 1.0]) / math.sqrt(1 + a * a + b * b)
    np.testing.assert_allclose(res.normal, np.broadcast_to(n, res.normal.shape), atol=1e-14)
    interior = ~res.on_boundary
    signed = (pts - [0, 0, c]) @ n - 0.0  # plane through (0, 0, c): n . (C - (0, 0, c))
    np.testing.assert_allclose(res.distance[interior], signed[interior], rtol=0, atol=1e-18)
    assert np.all(res.converged) and np.all(res.status == status.OK)


K_PARABOLA = 1.0 / (2 * 12e-9)  # apex curvature radius 12 nm


@pytest.fixture(scope="module")
def paraboloid():
    x, y = grid(48)
    return fit_surface(Scan(K_PARABOLA * ((x - 24e-9) ** 2 + (y - 23.5e-9) ** 2), H, H))


def test_paraboloid_fit_is_exact(paraboloid):
    uu, vv = np.meshgrid(np.linspace(0, 47e-9, 37), np.linspace(0, 47e-9, 41))
    z = paraboloid.evaluate(uu, vv)[..., 2]
    np.testing.assert_allclose(z, K_PARABOLA * ((uu - 24e-9) ** 2 + (vv - 23.5e-9) ** 2), rtol=0, atol=1e-21)


@pytest.mark.parametrize("h", [3e-9, 11.9e-9, 12.1e-9, 20e-9, 40e-9])
def test_paraboloid_on_axis_apex_or_ring(paraboloid, h):
    """z = k r^2, C on the axis at height h: below the apex curvature radius 1/(2k) the apex is
    closest (d = h); above it every point of the ring r^2 = h/k - 1/(2k^2) is, at
    d = sqrt(h/k - 1/(4k^2)) - a continuum of equally good candidates."""
    k = K_PARABOLA
    c = np.array([24e-9, 23.5e-9, h])
    p = project(paraboloid, c)
    if h < 1 / (2 * k):
        expect, ring = h, 0.0
    else:
        expect, ring = math.sqrt(h / k - 1 / (4 * k * k)), math.sqrt(h / k - 1 / (2 * k * k))
    assert abs(p.distance - expect) < TOL * 1e-3
    assert abs(math.hypot(p.point[0] - c[0], p.point[1] - c[1]) - ring) < 1e-15
    assert p.converged and not p.on_boundary


def test_paraboloid_off_axis_matches_the_cubic(paraboloid, rng):
    """Off the axis the closest point lies in the azimuthal plane of C at the root of
    2k^2 r^3 + (1 - 2kh) r - rho = 0 that minimises (r - rho)^2 + (k r^2 - h)^2."""
    k = K_PARABOLA
    tested = 0
    while tested < 200:
        rho, phi, h = rng.uniform(0, 12e-9), rng.uniform(0, 2 * np.pi), rng.uniform(-2e-9, 40e-9)
        # in units of 1 nm, the cubic's real roots
        roots = np.roots([2 * (k * 1e-9) ** 2, 0.0, 1 - 2 * k * h, -rho / 1e-9])
        r = roots[np.abs(roots.imag) < 1e-9].real * 1e-9
        f = (r - rho) ** 2 + (k * r * r - h) ** 2
        expect = math.sqrt(f.min())
        foot = r[np.argmin(f)]
        fx, fy = 24e-9 + foot * math.cos(phi), 23.5e-9 + foot * math.sin(phi)
        if not (0.5e-9 < fx < 46.5e-9 and 0.5e-9 < fy < 46.5e-9):
            continue  # the paraboloid's foot lies beyond the fitted domain
        tested += 1
        c = np.array([24e-9 + rho * math.cos(phi), 23.5e-9 + rho * math.sin(phi), h])
        p = project(paraboloid, c)
        assert abs(abs(p.distance) - expect) < TOL * 1e-3, (rho, h)
        # the normal of z = k r^2 at the foot, and the residual along it
        fx, fy = p.point[0] - 24e-9, p.point[1] - 23.5e-9
        n = np.array([-2 * k * fx, -2 * k * fy, 1.0])
        np.testing.assert_allclose(p.normal, n / np.linalg.norm(n), atol=1e-9)


def test_signed_distance_normal_and_depth_on_a_height_field():
    s = fit_surface(Scan(np.zeros((10, 10)), H, H))
    above = collide(s, (4e-9, 5e-9, 3e-9), radius=5e-9)
    below = collide(s, (4e-9, 5e-9, -3e-9), radius=5e-9)
    assert above.distance == pytest.approx(3e-9, abs=1e-22) and below.distance == pytest.approx(-3e-9, abs=1e-22)
    np.testing.assert_array_equal(above.normal, [0.0, 0.0, 1.0])
    np.testing.assert_array_equal(below.normal, [0.0, 0.0, 1.0])
    assert above.depth == pytest.approx(2e-9, abs=1e-22) and above.in_contact
    assert below.depth == pytest.approx(8e-9, abs=1e-22) and below.in_contact
    far = collide(s, (4e-9, 5e-9, 6e-9), radius=5e-9)
    assert far.depth == pytest.approx(-1e-9, abs=1e-22) and not far.in_contact


# --------------------------------------------------------------------------------------------
# hard surfaces against the brute force
@pytest.mark.parametrize("name", sorted(SCANS))
def test_hard_surfaces_match_the_brute_force(name, rng):
    s = fit_surface(SCANS[name]())
    pts = queries(s, rng, 1500)
    err, lower, ties = check_against(s, pts, project_many(s, pts))
    assert err <= TOL


def test_trench_narrower_than_the_tip_touches_both_rims():
    """A 10 nm tip centred over a 5 nm trench rests on its two rims: two mirror candidates at
    equal distance; moving the tip sideways picks the nearer rim."""
    s = fit_surface(trench_scan())
    centre = np.array([20e-9, 20e-9, 4e-9])
    p = collide(s, centre, radius=10e-9)
    assert p.in_contact and 1.5e-9 < abs(p.point[0] - 20e-9) < 4e-9  # on a rim, not in the trench
    mirror = s.evaluate(40e-9 - float(p.uv[0]), float(p.uv[1]))      # the other rim's point
    assert abs(np.linalg.norm(centre - mirror) - p.distance) < TOL
    assert collide(s, centre, 10e-9, hint=(40e-9 - p.uv[0], p.uv[1])).distance == pytest.approx(p.distance, abs=TOL)
    for shift in (-0.2e-9, 0.2e-9):
        q = collide(s, centre + [shift, 0, 0], radius=10e-9)
        assert np.sign(q.point[0] - 20e-9) == np.sign(shift)
        check_against(s, (centre + [shift, 0, 0])[None], _batch_of(q))


def _batch_of(p):
    """A one-row batch record from a single Projection/Contact (for check_against)."""
    return pj.ProjectionBatch(np.array(p.uv)[None], p.point[None], p.normal[None], np.array([p.distance]), None, None,
                              None, None, None)


def test_twin_ridges_near_equal_candidates_pick_the_nearer():
    s = fit_surface(ridges_scan())
    mid = np.array([20e-9, 20e-9, 9e-9])
    for dx in (-1e-11, 1e-11, -1e-10, 1e-10, 0.0):
        c = mid + [dx, 0, 0]
        cold = project(s, c)
        check_against(s, c[None], _batch_of(cold))
        for hint in ((14e-9, 20e-9), (26e-9, 20e-9)):  # a hint on either ridge
            warm = project(s, c, hint=hint)
            assert abs(warm.distance - cold.distance) < TOL
            if dx != 0.0:
                assert np.sign(warm.point[0] - 20e-9) == np.sign(dx)


@pytest.mark.parametrize("name", ["steps", "rough"])
def test_domain_edges_and_corners(name, rng):
    """C beyond every edge and corner, at heights from below to far above."""
    s = fit_surface(SCANS[name]())
    (u0, u1), (v0, v1) = s.domain
    pts = []
    for x in (u0 - 3e-9, u0, 0.5 * (u0 + u1), u1, u1 + 3e-9):
        for y in (v0 - 3e-9, v0, 0.5 * (v0 + v1), v1, v1 + 3e-9):
            for z in (-3e-9, 2e-9, 8e-9):
                pts.append((x, y, z))
    pts = np.array(pts) + rng.normal(scale=0.2e-9, size=(len(pts), 3))
    res = project_many(s, pts)
    check_against(s, pts, res)
    outside = (pts[:, 0] < u0) | (pts[:, 0] > u1) | (pts[:, 1] < v0) | (pts[:, 1] > v1)
    assert res.on_boundary[outside].mean() > 0.5
    on = res.on_boundary
    assert np.all((res.uv[on, 0] == u0) | (res.uv[on, 0] == u1) | (res.uv[on, 1] == v0) | (res.uv[on, 1] == v1))


def test_knot_lines_and_exact_surface_points():
    s = fit_surface(rough_scan())
    for u, v in [(10e-9, 12e-9), (10e-9, 12.5e-9), (0.0, 0.0), (39e-9, 20e-9)]:
        p0 = s.evaluate(u, v)
        p = project(s, p0)
        assert abs(p.distance) < 1e-20
        np.testing.assert_allclose(p.point, p0, atol=1e-20)


def test_far_above_stays_correct_and_reports_the_cost(rng):
    """The admissible region grows with the height of C: the answer stays exact, the number of
    searched cells grows (smooth surface: slowly; it is bounded by the cells of the disc)."""
    s = fit_surface(rough_scan())
    for height in (2e-9, 20e-9, 200e-9, 2e-6):
        pts = queries(s, rng, 50, margin=0.0, above=0.0, below=0.0)
        pts[:, 2] = s.control_points[..., 2].max() + height
        res = project_many(s, pts)
        check_against(s, pts, res)


def test_smallest_surface_and_non_square_pixels(rng):
    """A 4 x 4 scan (3 x 3 knot cells, the pyramid is 3 levels deep) and 1 nm x 4 nm pixels."""
    tiny = fit_surface(Scan(rng.normal(size=(4, 4)) * 1e-9, H, H))
    pts = queries(tiny, rng, 400)
    check_against(tiny, pts, project_many(tiny, pts))
    y, x = np.mgrid[0:12, 0:40]
    wide = fit_surface(Scan(2e-9 * np.sin(x / 3.0) * np.cos(y / 2.0), 1e-9, 4e-9))
    assert wide.spacing == pytest.approx((1e-9, 4e-9))
    pts = queries(wide, rng, 1500)
    err, _, _ = check_against(wide, pts, project_many(wide, pts))
    assert err <= TOL


def test_degenerate_normal_is_flagged():
    """A net whose first control row collapses to one point (an apex: S_v = 0 there). A point
    beyond the apex projects onto it; the normal is undefined and taken along C - S."""
    s = fit_surface(rough_scan(10))
    ctrl = s.control_points.copy()
    apex = np.array([-2e-9, 4.5e-9, 0.0])
    ctrl[0, :, :] = apex
    cone = BSplineSurface(ctrl, s.knots_u, s.knots_v)
    c = apex + [-3e-9, 0.0, 0.5e-9]
    p = project(cone, c)
    np.testing.assert_allclose(p.point, apex, atol=1e-18)
    assert p.status == status.DEGENERATE and p.on_boundary
    np.testing.assert_allclose(p.normal, (c - apex) / np.linalg.norm(c - apex), atol=1e-9)
    assert p.distance == pytest.approx(np.linalg.norm(c - apex), rel=1e-12)


# --------------------------------------------------------------------------------------------
# warm start
def test_warm_start_never_hides_a_closer_basin():
    """The tip slides across the twin ridges: at every tick the hint is the last answer, on the
    ridge it is leaving; once the other ridge is closer the answer must jump there."""
    s = fit_surface(ridges_scan())
    path = np.column_stack([np.linspace(10e-9, 30e-9, 401), np.full(401, 20e-9), np.full(401, 9e-9)])
    hint = None
    jumped = 0
    for c in path:
        warm = collide(s, c, 8e-9, hint=hint)
        cold = collide(s, c, 8e-9)
        assert abs(warm.distance - cold.distance) < TOL
        if hint is not None and abs(warm.uv[0] - hint[0]) > 5e-9:
            jumped += 1
        hint = tuple(warm.uv)
    assert jumped >= 1


def test_a_hint_in_a_far_wrong_basin_is_harmless(rng):
    s = fit_surface(rough_scan())
    pts = queries(s, rng, 300)
    hints = rng.uniform(0, 39e-9, size=(300, 2))
    cold = project_many(s, pts)
    warm = project_many(s, pts, hints=hints)
    np.testing.assert_allclose(np.abs(warm.distance), np.abs(cold.distance), rtol=0, atol=TOL)


def test_trajectory_with_the_candidate_cache_matches_cold_queries(rng):
    """Chained warm queries reuse a candidate list (work array) while the tip stays within its
    margin; every answer must equal the cold one."""
    s = fit_surface(rough_scan())
    steps = rng.normal(scale=0.15e-9, size=(3000, 3))
    c = np.array([20e-9, 20e-9, 5e-9]) + np.cumsum(steps, axis=0)
    c[:, :2] = np.clip(c[:, :2], -2e-9, 41e-9)
    cold = project_many(s, c)
    warm = project_many(s, c, chain=True)
    np.testing.assert_allclose(np.abs(warm.distance), np.abs(cold.distance), rtol=0, atol=TOL)
    out = np.empty(pj.OUT_SIZE)
    proj = projector(s)
    cached = 0
    hu = hv = math.nan
    for q in c[:500]:
        pj.project_kernel(*proj.kernel_args(), q[0], q[1], q[2], hu, hv, out)
        hu, hv = out[pj.OUT_U], out[pj.OUT_V]
        cached += out[pj.OUT_CACHED] > 0
    assert cached > 250  # the cache is in use on a slow trajectory


@pytest.mark.parametrize("n", [0, 1, 2, 7, 480, pj.CACHE_CAP])
def test_candidate_sort_is_the_stable_sort_by_distance(n, rng):
    """The candidate list's bucket sort gives exactly the stable sort by distance (ties keep the
    walk's order), with spread, clustered, tied and all-equal distances."""
    first, scratch = 5, 5 + pj.CACHE_CAP + 3
    for dist in (rng.uniform(19e-9, 19.05e-9, n), 19e-9 + 1e-12 * rng.integers(0, 4, n),
                 np.full(n, 2e-8), np.concatenate([np.full(n // 2, 1e-9), rng.uniform(1e-9, 5e-8, n - n // 2)])):
        rows = np.column_stack([rng.permutation(n).astype(float), dist, np.zeros(n)])
        work = np.full((scratch + pj.CACHE_CAP + 2, 3), -7.0)
        work[first:first + n] = rows
        cp.sort_candidates(work, first, n, scratch)
        np.testing.assert_array_equal(work[first:first + n, :2], rows[np.argsort(dist, kind="stable"), :2])
        assert (work[:first] == -7.0).all() and (work[first + n:scratch] == -7.0).all()  # only its own rows


def _memo_rows(work):
    return work[cp.MEMO_BASE:cp.MEMO_BASE + cp.PIECE_MEMO * cp.MEMO_ROWS]


def _trajectory(surface, centres, radius, forget_memo):
    """Chained collide_kernel answers along ``centres`` on a fresh projector's work array,
    forgetting the piece memo before every query or not."""
    proj = projector(surface)
    work = proj.kernel_args()[8]
    work[:] = 0.0
    work[pj.CACHE_ROW, 0] = -1.0
    out = np.empty((len(centres), pj.OUT_SIZE))
    hu = hv = math.nan
    for k, c in enumerate(centres):
        if forget_memo:
            _memo_rows(work)[:] = 0.0
        cp.collide_kernel(*proj.kernel_args(), *c, radius, hu, hv, out[k])
        hu, hv = out[k, pj.OUT_U], out[k, pj.OUT_V]
    return out, int((_memo_rows(work)[::cp.MEMO_ROWS, 0] > 0).sum())


def test_piece_memo_changes_no_answer_bit_for_bit(rng):
    """The subdivided search reads a piece's curvature bounds, speeds and centre evaluation back
    from the memo: a slow slide of a 20 nm tip over rough valleys (most cells near it not
    certified convex, so subdivided) gives the same output vector - answer, iterations, cells -
    with the memo kept as with it forgotten before every query, and the memo is in use."""
    s = fit_surface(rough_scan(48, seed=3))
    z0 = float(s.evaluate(24e-9, 24e-9)[2])
    t = np.linspace(0.0, 1.0, 400)[:, None]
    centres = np.array([14e-9, 18e-9, z0 + 19e-9]) + t * [20e-9, 8e-9, -2e-9] + rng.normal(scale=2e-11, size=(400, 3))
    kept, used = _trajectory(s, centres, 20e-9, False)
    fresh, _ = _trajectory(s, centres, 20e-9, True)
    np.testing.assert_array_equal(kept, fresh)
    assert used > 10 and kept[:, pj.OUT_CELLS].max() > 1
    check_against(s, centres[::40], project_many(s, centres[::40]))


def test_piece_memo_is_not_read_after_the_net_moved(rng):
    """Memo entries carry the pyramid's version: after control points move and refresh_region,
    the same queries on the same work array equal those of a projector built on the moved net."""
    s = fit_surface(rough_scan(48, seed=3))
    z0 = float(s.evaluate(24e-9, 24e-9)[2])
    centres = np.array([20e-9, 22e-9, z0 + 19e-9]) + rng.normal(scale=1e-9, size=(60, 3))
    _trajectory(s, centres, 20e-9, False)  # fills the memo for the rest net
    ctrl = s.kernel_arrays()[0]
    ctrl[16:30, 16:30, 2] += 0.8e-9 * rng.standard_normal((14, 14))  # valleys change their curvature
    refresh_region(s, 16, 30, 16, 30)
    proj = projector(s)
    out = np.empty((len(centres), pj.OUT_SIZE))
    hu = hv = math.nan
    for k, c in enumerate(centres):
        cp.collide_kernel(*proj.kernel_args(), *c, 20e-9, hu, hv, out[k])
        hu, hv = out[k, pj.OUT_U], out[k, pj.OUT_V]
    moved = BSplineSurface.construct_fast(ctrl.copy(), *s.kernel_arrays()[2:])
    ref, _ = _trajectory(moved, centres, 20e-9, True)
    np.testing.assert_array_equal(out, ref)


def test_candidate_list_holds_every_cell_within_its_reach_sorted():
    """After a warm query the list is every knot cell whose box is nearer than its reach R0 to the
    query point, in increasing distance (the cells a later query may need: project_kernel, Notes)."""
    s = fit_surface(rough_scan())
    proj = projector(s)
    ctrl, ku, kv, mu, mv, nodes, curv, levels, work = proj.kernel_args()
    out = np.empty(pj.OUT_SIZE)
    q = (20e-9, 21e-9, 4e-9)
    pj.project_kernel(*proj.kernel_args(), *q, math.nan, math.nan, out)
    pj.project_kernel(*proj.kernel_args(), *q, out[pj.OUT_U], out[pj.OUT_V], out)  # warm: builds the list
    pj.project_kernel(*proj.kernel_args(), q[0] + 1e-12, *q[1:], out[pj.OUT_U], out[pj.OUT_V], out)
    assert out[pj.OUT_CACHED] == 1.0
    count, reach = int(work[pj.CACHE_ROW, 2]), work[pj.CACHE_ROW + 2, 0]
    rows = work[pj.CACHE_LIST:pj.CACHE_LIST + count]
    assert count > 1 and np.all(np.diff(rows[:, 1]) >= 0.0)
    ncell = levels[0, 1] * levels[0, 2]
    near2 = np.array([cd.node_bounds2(nodes, k, *q)[0] for k in range(ncell)])
    assert set(rows[:, 0].astype(int)) == set(np.flatnonzero(near2 < reach * reach))
    np.testing.assert_array_equal(rows[:, 1], np.sqrt(near2[rows[:, 0].astype(int)]))


# --------------------------------------------------------------------------------------------
# deformed surfaces and local refresh


@pytest.mark.parametrize("name", ["ridges", "rough"])
def test_deformed_nets_match_the_brute_force(name, rng):
    s = perturbed(fit_surface(SCANS[name]()), rng)
    pts = queries(s, rng, 1500)
    err, _, _ = check_against(s, pts, project_many(s, pts))
    assert err <= TOL


def test_refresh_region_is_local_and_equals_a_rebuild(rng):
    s = fit_surface(rough_scan())
    proj = projector(s)
    before = proj.tree.nodes.copy()
    ctrl = s.kernel_arrays()[0]
    ctrl[12:16, 20:23] += rng.normal(size=(4, 3, 3)) * 0.6e-9   # what the deformation does
    refresh_region(s, 12, 16, 20, 23)
    rebuilt = cd.HullTree(ctrl, s.knots_u, s.knots_v)
    np.testing.assert_array_equal(proj.tree.nodes[:-1], rebuilt.nodes[:-1])
    changed = np.flatnonzero((proj.tree.nodes[:-1] != before[:-1]).any(axis=1))
    lev = proj.tree.levels
    leaves = changed[changed < lev[0, 1] * lev[0, 2]]
    i, j = np.divmod(leaves, lev[0, 2])
    assert i.min() >= 12 - 3 and i.max() < 16 and j.min() >= 20 - 3 and j.max() < 23
    assert changed.size <= 7 * 6 + 4 * (lev.shape[0] - 1) * 4   # the patch's cells and their ancestors
    assert proj.tree.nodes[-1, cd.VERSION] == before[-1, cd.VERSION] + 1


def test_deformation_invalidates_the_candidate_cache(rng):
    """A warm query builds a candidate list; a dent that makes a closer point then moves the
    net: after refresh_region the next warm query must see it."""
    s = fit_surface(Scan(np.zeros((30, 30)), H, H))
    c = np.array([15e-9, 15e-9, 6e-9])
    first = project(s, c, hint=(15e-9, 15e-9))
    project(s, c + [0.05e-9, 0, 0], hint=tuple(first.uv))
    ctrl = s.kernel_arrays()[0]
    # a 4 nm bump 4-5 nm to the side, outside the list's cells, rises closer than the plane below C
    ctrl[20:22, 15:17, 2] += 4e-9
    refresh_region(s, 20, 22, 15, 17)
    warm = project(s, c, hint=tuple(first.uv))
    check_against(s, c[None], _batch_of(warm))
    assert warm.distance < 6e-9 - 1e-10


def test_full_refresh_after_the_whole_net_moved(rng):
    s = fit_surface(rough_scan())
    project(s, (20e-9, 20e-9, 5e-9))
    s.kernel_arrays()[0][:, :, 2] += 3e-9  # moved without telling the projection ...
    projector(s).refresh()                 # ... and the full refresh (e.g. after reset())
    pts = queries(s, rng, 300)
    check_against(s, pts, project_many(s, pts))


def test_surfaces_still_pickle_and_copies_get_their_own_projector():
    import copy
    import pickle

    s = fit_surface(ridges_scan())
    c = (20e-9, 20e-9, 9e-9)
    first = project(s, c)
    for twin in (pickle.loads(pickle.dumps(s)), copy.deepcopy(s), s.copy()):
        again = project(twin, c)
        assert again.distance == first.distance
        assert projector(twin) is not projector(s)


# --------------------------------------------------------------------------------------------
# bad input
def test_bad_inputs_raise_clear_errors():
    s = fit_surface(rough_scan())
    with pytest.raises(SurfaceError, match="finite"):
        project(s, (np.nan, 0.0, 0.0))
    with pytest.raises(SurfaceError, match="finite"):
        collide(s, (0.0, np.inf, 0.0), 1e-9)
    with pytest.raises(SurfaceError, match="3 coordinates"):
        project(s, (0.0, 1.0))
    with pytest.raises(SurfaceError, match="3 coordinates"):
        project(s, "abc")
    with pytest.raises(ContactError, match="radius must be positive"):
        collide(s, (0.0, 0.0, 0.0), 0.0)
    with pytest.raises(ContactError, match="radius must be positive"):
        collide(s, (0.0, 0.0, 0.0), -1e-9)
    with pytest.raises(ContactError, match="radius must be positive"):
        collide(s, (0.0, 0.0, 0.0), np.nan)
    with pytest.raises(ContactError, match="a number"):
        collide(s, (0.0, 0.0, 0.0), "big")
    with pytest.raises(SurfaceError, match="hint must be finite"):
        project(s, (0.0, 0.0, 0.0), hint=(np.nan, 0.0))
    with pytest.raises(SurfaceError, match=r"shape \(n, 3\)"):
        project_many(s, np.zeros((4, 2)))
    with pytest.raises(SurfaceError, match="rows hold NaN"):
        project_many(s, [[0.0, 0.0, np.nan]])
    with pytest.raises(SurfaceError, match="hints must have shape"):
        project_many(s, np.zeros((4, 3)), hints=np.zeros((3, 2)))
    with pytest.raises(ContactError, match="radius must be positive"):
        collide_many(s, np.zeros((4, 3)), radius=-1.0)
    with pytest.raises(SurfaceError, match="BSplineSurface"):
        project(object(), (0.0, 0.0, 0.0))
    with pytest.raises(SurfaceError, match="BSplineSurface"):
        project([1, 2], (0.0, 0.0, 0.0))
    with pytest.raises(SurfaceError, match="not inside"):
        refresh_region(s, 0, 99, 0, 3)


def test_any_numeric_input_gives_the_float_answer_and_bad_ones_the_precise_error():
    """The single-query fast path hands the caller's numbers to the compiled entry as they are:
    numpy scalars, arrays, ints must answer exactly as floats do; a bad hint still gets its error."""
    s = fit_surface(rough_scan())
    c, r = (40e-9, 50e-9, 12e-9), 10e-9
    ref = collide(s, c, r, hint=(41e-9, 49e-9))
    for centre, radius, hint in [(np.array(c), np.float64(r), np.array([41e-9, 49e-9])),
                                 (list(c), r, [41e-9, 49e-9]),
                                 (tuple(np.float64(v) for v in c), r, (np.float64(41e-9), 49e-9))]:
        got = collide(s, centre, radius, hint=hint)
        assert got.uv == ref.uv and got.depth == ref.depth and type(got.radius) is float
        assert np.array_equal(got.point, ref.point) and np.array_equal(got.normal, ref.normal)
    ints, floats = project(s, (0, 0, 1)), project(s, (0.0, 0.0, 1.0))
    assert ints.uv == floats.uv and ints.distance == floats.distance
    for bad in [(np.inf, 0.0), (0.0, -np.inf), np.array([np.nan, 0.0])]:
        with pytest.raises(SurfaceError, match="hint must be finite"):
            collide(s, c, r, hint=bad)
    with pytest.raises(SurfaceError, match="hint must be None or"):
        collide(s, c, r, hint=(1.0, 2.0, 3.0))
    with pytest.raises(SurfaceError, match="center must be finite"):
        collide(s, np.array([0.0, np.nan, 0.0]), r)
    with pytest.raises(ContactError, match="radius must be positive"):
        collide(s, c, np.float64(-1e-9))


def test_nan_control_points_are_reported():
    ctrl = fit_surface(rough_scan(12)).control_points.copy()
    s = fit_surface(rough_scan(12))
    bad = BSplineSurface.construct_fast(ctrl, s.knots_u, s.knots_v)
    ctrl[4, 5, 2] = np.nan
    with pytest.raises(SurfaceError, match="non-finite"):
        project(bad, (5e-9, 5e-9, 3e-9))
    # NaN written into a live net after the projector was built: refresh_region says so ...
    live = fit_surface(rough_scan(12))
    project(live, (5e-9, 5e-9, 3e-9))
    live.kernel_arrays()[0][6, 6, 1] = np.nan
    with pytest.raises(SurfaceError, match="non-finite"):
        refresh_region(live, 6, 7, 6, 7)
    # ... and the query reports it instead of returning garbage
    with pytest.raises(SurfaceError, match="NaN"):
        project(live, (5e-9, 5e-9, 3e-9))
    out = np.empty(pj.OUT_SIZE)
    assert pj.collide_kernel(*projector(live).kernel_args(), 5e-9, 5e-9, 3e-9, 1e-9, np.nan, np.nan,
                             out) == status.NON_FINITE


def test_kernel_status_for_bad_scalars():
    s = fit_surface(rough_scan(12))
    args = projector(s).kernel_args()
    out = np.empty(pj.OUT_SIZE)
    assert pj.collide_kernel(*args, np.nan, 0.0, 0.0, 1e-9, np.nan, np.nan, out) == status.BAD_INPUT
    assert pj.collide_kernel(*args, 0.0, 0.0, 0.0, 0.0, np.nan, np.nan, out) == status.BAD_INPUT
    assert pj.collide_kernel(*args, 0.0, 0.0, 0.0, np.inf, np.nan, np.nan, out) == status.BAD_INPUT


# --------------------------------------------------------------------------------------------
# the kernel API for the haptic loop
@njit
def _loop(args, path, radius, outs):
    """A haptic-loop-like kernel: warm-started collisions along a path."""
    hu = np.nan
    hv = np.nan
    worst = 0
    for k in range(path.shape[0]):
        st = pj.collide_kernel(args[0], args[1], args[2], args[3], args[4], args[5], args[6], args[7], args[8],
                               path[k, 0], path[k, 1], path[k, 2], radius, hu, hv, outs[k])
        hu = outs[k, pj.OUT_U]
        hv = outs[k, pj.OUT_V]
        worst = min(worst, st)
    return worst


def test_kernel_loop_matches_the_python_api_and_allocates_nothing(rng):
    from numba.core.runtime import _nrt_python, rtsys

    s = fit_surface(rough_scan())
    args = projector(s).kernel_args()
    path = np.array([20e-9, 20e-9, 6e-9]) + np.cumsum(rng.normal(scale=0.1e-9, size=(400, 3)), axis=0)
    outs = np.empty((400, pj.OUT_SIZE))
    assert _loop(args, path, 4e-9, outs) >= 0
    ref = collide_many(s, path, 4e-9)
    np.testing.assert_allclose(outs[:, pj.OUT_DEPTH], ref.depth, rtol=0, atol=TOL)
    same = np.linalg.norm(outs[:, pj.OUT_PX:pj.OUT_PZ + 1] - ref.point, axis=1) < 1e-15  # not a tie
    assert same.mean() > 0.9
    # the same point to 1e-15 m on a surface curved at 1/nm: normals agree to ~1e-6
    np.testing.assert_allclose(outs[same, pj.OUT_NX:pj.OUT_NZ + 1], ref.normal[same], atol=1e-6)
    enabled = _nrt_python.memsys_stats_enabled()
    _nrt_python.memsys_enable_stats()
    try:
        a0 = rtsys.get_allocation_stats().alloc
        _loop(args, path[:1], 4e-9, outs)
        a1 = rtsys.get_allocation_stats().alloc
        _loop(args, path, 4e-9, outs)
        a2 = rtsys.get_allocation_stats().alloc
    finally:
        if not enabled:
            _nrt_python.memsys_disable_stats()
    assert a2 - a1 == a1 - a0   # 400 ticks allocate exactly what 1 tick does (the call itself)


def test_batch_equals_single_queries(rng):
    s = fit_surface(ridges_scan())
    pts = queries(s, rng, 50)
    batch = collide_many(s, pts, 6e-9)
    for k, p in enumerate(pts):
        one = collide(s, p, 6e-9)
        assert one.depth == batch.depth[k] and one.in_contact == batch.in_contact[k]
        np.testing.assert_array_equal(one.point, batch.point[k])
        np.testing.assert_array_equal(one.uv, batch.uv[k])
        assert one.status == batch.status[k] and one.on_boundary == batch.on_boundary[k]


# --------------------------------------------------------------------------------------------
# the candidate structure
def de_casteljau_patch(net, s, t):
    """Point of the bicubic Bézier patch ``net`` (16, 3) at local (s, t) in [0, 1]^2."""
    b = net.reshape(4, 4, 3)
    bs = np.array([(1 - s) ** 3, 3 * s * (1 - s) ** 2, 3 * s * s * (1 - s), s ** 3])
    bt = np.array([(1 - t) ** 3, 3 * t * (1 - t) ** 2, 3 * t * t * (1 - t), t ** 3])
    return np.einsum("k,m,kmc->c", bs, bt, b)


@pytest.mark.parametrize("a,b", [(0, 0), (1, 2), (5, 7), (36, 36)])
def test_cell_bezier_nets_reproduce_the_surface_and_split_exactly(a, b, rng):
    s = perturbed(fit_surface(rough_scan()), rng)
    ctrl, _, ku, kv = s.kernel_arrays()
    tree = projector(s).tree
    net = np.empty((16, 3))
    cd.cell_net(ctrl, tree.mu, tree.mv, a, b, net)
    quarters = np.empty((64, 3))
    cd.net_split(net, 0, quarters, 0, 16, 32, 48)
    for st_ in rng.uniform(0, 1, size=(20, 2)):
        u = ku[a + 3] + st_[0] * (ku[a + 4] - ku[a + 3])
        v = kv[b + 3] + st_[1] * (kv[b + 4] - kv[b + 3])
        np.testing.assert_allclose(de_casteljau_patch(net, *st_), s.evaluate(u, v), atol=1e-21)
        q = (st_[0] >= 0.5) + 2 * (st_[1] >= 0.5)
        local = 2 * st_ - [q & 1, q >> 1]
        np.testing.assert_allclose(de_casteljau_patch(quarters[16 * q:16 * q + 16], *local), s.evaluate(u, v),
                                   atol=1e-21)


def test_oriented_boxes_contain_their_cells_at_every_level(rng):
    s = perturbed(fit_surface(steps_scan()), rng)
    tree = projector(s).tree
    (u0, u1), (v0, v1) = s.domain
    uu, vv = np.meshgrid(np.linspace(u0, u1, 301), np.linspace(v0, v1, 301), indexing="ij")
    pts = s.evaluate(uu.ravel(), vv.ravel())
    a = np.minimum(((uu.ravel() - u0) / H).astype(int), tree.levels[0, 1] - 1)
    b = np.minimum(((vv.ravel() - v0) / H).astype(int), tree.levels[0, 2] - 1)
    for lev, (off, ni, nj) in enumerate(tree.levels):
        node = off + (a >> lev) * nj + (b >> lev)
        nd = tree.nodes[node]
        n, t = nd[:, 0:3], nd[:, 3:6]
        sv = np.cross(n, t)
        for axis, (lo, hi) in zip((t, sv, n), ((6, 7), (8, 9), (10, 11))):
            proj = (pts * axis).sum(axis=1)
            assert np.all(proj >= nd[:, lo] - 1e-21) and np.all(proj <= nd[:, hi] + 1e-21)
        np.testing.assert_allclose((n * t).sum(1), 0.0, atol=1e-15)
        np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-15)


def test_convexity_radius_certifies_a_positive_definite_hessian(rng):
    """For C within the certified radius of a whole cell, the Hessian of D is positive definite at
    every sampled point of the cell."""
    s = perturbed(fit_surface(ridges_scan()), rng, 0.05e-9, 0.1e-9)
    tree = projector(s).tree
    ctrl, _, ku, kv = s.kernel_arrays()
    nj0 = tree.levels[0, 2]
    checked = 0
    for cell in rng.choice(tree.levels[0, 1] * nj0, 60, replace=False):
        a, b = divmod(int(cell), nj0)
        rho = tree.nodes[cell, cd.RHO]
        if not (0 < rho < 1e-3):
            continue
        uu, vv = np.meshgrid(np.linspace(ku[a + 3], ku[a + 4], 7), np.linspace(kv[b + 3], kv[b + 4], 7))
        sp, su, sv, suu, suv, svv = (x.reshape(-1, 3) for x in s.evaluate(uu.ravel(), vv.ravel(), 2))
        centre = sp.mean(axis=0)
        for _ in range(5):
            direction = rng.normal(size=3)
            c = centre + direction / np.linalg.norm(direction) * rng.uniform(0, rho)
            r = sp - c
            if np.linalg.norm(r, axis=1).max() >= rho:
                continue
            huu = (su * su).sum(1) + (suu * r).sum(1)
            huv = (su * sv).sum(1) + (suv * r).sum(1)
            hvv = (sv * sv).sum(1) + (svv * r).sum(1)
            assert np.all(huu > 0) and np.all(huu * hvv - huv * huv > 0)
            checked += 1
    assert checked > 50


@njit
def _certified(nodes, curv, node, x, y, z):
    near2, far2, lift = cd.node_bounds2(nodes, node, x, y, z)
    rho = nodes[node, cd.RHO]
    return cd.cell_certified(nodes, curv, node, far2, x, y, z), far2 < rho * rho


def test_signed_certificate_far_above_caps(rng):
    """Far above a cap (z = -k r^2, perturbed) the unsigned radius fails but the signed test
    certifies D convex on the cells; wherever it does, the sampled Hessian is positive definite."""
    x, y = grid(24)
    cap = -((x - 12e-9) ** 2 + (y - 12e-9) ** 2) / (2 * 8e-9)
    s = perturbed(fit_surface(Scan(cap, H, H)), rng, 0.5e-12, 1e-12)  # slightly deformed: not a height field
    tree = projector(s).tree
    ctrl, _, ku, kv = s.kernel_arrays()
    nj0 = tree.levels[0, 2]
    signed_only = 0
    for cell in rng.choice(tree.levels[0, 1] * nj0, 80, replace=False):
        a, b = divmod(int(cell), nj0)
        uu, vv = np.meshgrid(np.linspace(ku[a + 3], ku[a + 4], 6), np.linspace(kv[b + 3], kv[b + 4], 6))
        sp, su, sv, suu, suv, svv = (q.reshape(-1, 3) for q in s.evaluate(uu.ravel(), vv.ravel(), 2))
        for height in (5e-9, 50e-9, 500e-9):
            c = sp.mean(axis=0) + [rng.normal() * 3e-9, rng.normal() * 3e-9, height]
            certified, by_radius = _certified(tree.nodes, tree.curv, int(cell), *c)
            if not certified:
                continue
            signed_only += not by_radius
            r = sp - c
            huu = (su * su).sum(1) + (suu * r).sum(1)
            huv = (su * sv).sum(1) + (suv * r).sum(1)
            hvv = (sv * sv).sum(1) + (svv * r).sum(1)
            assert np.all(huu > 0) and np.all(huu * hvv - huv * huv > 0)
    assert signed_only > 40
    # and in a valley (the cap upside down) far above, nothing may be certified
    bowl = fit_surface(Scan(-cap, H, H))
    t2 = projector(bowl).tree
    c = np.array([12e-9, 12e-9, 500e-9])
    assert not _certified(t2.nodes, t2.curv, 11 * t2.levels[0, 2] + 11, *c)[0]


def test_excluded_pieces_hold_no_local_minimum(rng):
    """Where the exclusion tests prune a piece (no stationary point, or negative curvature
    everywhere), Newton started anywhere in it converges to a local minimum outside it."""
    s = perturbed(fit_surface(rough_scan(24, seed=4)), rng, 0.1e-9, 0.2e-9)
    tree = projector(s).tree
    ctrl, _, ku, kv = s.kernel_arrays()
    (lo_u, hi_u), (lo_v, hi_v) = s.domain
    nj0 = tree.levels[0, 2]
    ev = np.empty((6, 3))
    net = np.empty((16, 3))
    quarters = np.empty((64, 3))
    excluded = 0
    for _ in range(150):
        a, b = rng.integers(1, tree.levels[0, 1] - 1), rng.integers(1, nj0 - 1)
        node = a * nj0 + b
        nx, ny, nz, tx, ty, tz = tree.nodes[node, :6]
        cd.cell_net(ctrl, tree.mu, tree.mv, a, b, net)
        cd.net_split(net, 0, quarters, 0, 16, 32, 48)
        centre = s.evaluate(0.5 * (ku[a + 3] + ku[a + 4]), 0.5 * (kv[b + 3] + kv[b + 4]))
        c = centre + rng.normal(size=3) * [3e-9, 3e-9, 1e-9] + [0, 0, rng.uniform(1e-9, 60e-9)]
        u0, u1, v0, v1 = ku[a + 3], ku[a + 4], kv[b + 3], kv[b + 4]
        um, vm = 0.5 * (u0 + u1), 0.5 * (v0 + v1)
        pieces = [(net, 0, u0, u1, v0, v1)] + [(quarters, 16 * q, *rect) for q, rect in
                                               enumerate([(u0, um, v0, vm), (um, u1, v0, vm), (u0, um, vm, v1),
                                                          (um, u1, vm, v1)])]
        for arr, e, p0, p1, q0, q1 in pieces:
            ext = cd.net_extents(arr, e, 16, nx, ny, nz, tx, ty, tz)
            far2 = cd.extents_bounds2(*ext, nx, ny, nz, tx, ty, tz, *c)[1]
            vals = cd.net_curvature(arr[e:e + 16], p1 - p0, q1 - q0, nx, ny, nz)
            if not cp._no_local_minimum(ctrl, ku, kv, ev, arr, e, p0, p1, q0, q1, *vals[:9], *ext,
                                        nx, ny, nz, tx, ty, tz, far2, *c):
                continue
            excluded += 1
            for su, sv in rng.uniform(0, 1, size=(6, 2)):
                u, v, d2, it, conv = newton_box(ctrl, ku, kv, ev, *c, p0 + su * (p1 - p0), q0 + sv * (q1 - q0),
                                                   lo_u, hi_u, lo_v, hi_v, 1e-9 * H, 1e-9 * H, H, 200)
                if conv:
                    assert not (p0 - 1e-15 <= u <= p1 + 1e-15 and q0 - 1e-15 <= v <= q1 + 1e-15)
    assert excluded > 100


def test_bezier_matrices_are_a_partition_of_unity():
    s = fit_surface(rough_scan(12))
    m = cd.bezier_matrices(s.kernel_arrays()[2])
    np.testing.assert_allclose(m.sum(axis=2), 1.0, atol=1e-15)


# --------------------------------------------------------------------------------------------
# properties (hypothesis)
_PROP_SURFACE = {}


def _prop_surface():
    if "s" not in _PROP_SURFACE:
        _PROP_SURFACE["s"] = perturbed(fit_surface(rough_scan(24, seed=9)), np.random.default_rng(3), 0.15e-9, 0.3e-9)
        s = _PROP_SURFACE["s"]
        (u0, u1), (v0, v1) = s.domain
        uu, vv = np.meshgrid(np.linspace(u0, u1, 97), np.linspace(v0, v1, 97))
        _PROP_SURFACE["samples"] = s.evaluate(uu.ravel(), vv.ravel())
    return _PROP_SURFACE["s"], _PROP_SURFACE["samples"]


coords = st.tuples(st.floats(-3e-9, 26e-9), st.floats(-3e-9, 26e-9), st.floats(-6e-9, 25e-9))


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(c=coords)
def test_property_residual_is_along_the_normal(c):
    s, _ = _prop_surface()
    p = project(s, c)
    r = np.asarray(c) - p.point
    if p.on_boundary or np.linalg.norm(r) < 1e-12:
        return
    # the foot is found to ~1e-17 m (a Newton step below 1e-5 knot spacings ends the iteration)
    assert np.linalg.norm(np.cross(r, p.normal)) <= 1e-7 * np.linalg.norm(r) + 1e-16
    assert p.distance == pytest.approx(float(r @ p.normal), rel=1e-12, abs=1e-24)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(c=coords)
def test_property_never_farther_than_any_sampled_point(c):
    s, samples = _prop_surface()
    p = project(s, c)
    assert abs(p.distance) <= np.linalg.norm(samples - np.asarray(c), axis=1).min() + 1e-20


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(c=coords, hint=st.tuples(st.floats(-1e-9, 24e-9), st.floats(-1e-9, 24e-9)))
def test_property_warm_and_cold_agree(c, hint):
    s, _ = _prop_surface()
    assert abs(project(s, c, hint=hint).distance - project(s, c).distance) <= TOL


def test_docstring_examples_run():
    import doctest

    for module in (pj, cd):
        failed, attempted = doctest.testmod(module, optionflags=doctest.NORMALIZE_WHITESPACE)
        assert attempted > 0 and failed == 0, module.__name__


def test_reset_refreshes_the_projection():
    """surface.reset() refreshes the projector it has (BSplineSurface.attach): after a dent and a
    reset, projections equal those of a fresh copy of the surface."""
    import numpy as np

    from arsurf.contact.deformation import Deformer
    from arsurf.contact.projection import project, projector
    from arsurf.spline.surface import BSplineSurface

    rng = np.random.default_rng(5)
    s = BSplineSurface.from_heights(rng.normal(size=(30, 30)) * 2e-9, (0.0, 108e-9), (0.0, 108e-9))
    proj = projector(s)
    calls = []
    original = proj.refresh
    proj.refresh = lambda: (calls.append(1), original())[1]
    Deformer(s).apply((54e-9, 54e-9, s.evaluate(54e-9, 54e-9)[2] + 16e-9), 20e-9, (0, 0, 1), 10e-9)
    s.reset()
    assert calls == [1]
    fresh = s.copy()
    for q in rng.uniform((30e-9, 30e-9, -2e-9), (80e-9, 80e-9, 15e-9), (200, 3)):
        assert project(s, q).distance == project(fresh, q).distance
