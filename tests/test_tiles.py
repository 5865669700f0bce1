"""The tiled projector (pyramids built per tile, on demand) gives the whole-surface projector's
answers: random queries on hard surfaces, near tile borders, far above, warm chains, a pool too
small to hold every tile, deformed nets, NaN nets, and the model tick on a tiled surface."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter
from test_projection import TOL, ridges_scan, steps_scan, trench_scan

from arsurf.assembly import make_model
from arsurf import status
from arsurf.contact import projection as pj
from arsurf.contact.deformation import Deformer
from arsurf.contact.projection import Projector, TiledProjector, collide_many, project_many
from arsurf.errors import SurfaceError
from arsurf.scan.scan import Scan
from arsurf.spline.fit import fit_surface
from arsurf.spline.surface import BSplineSurface

H = 1e-9


def rough(n=70, seed=3):
    rng = np.random.default_rng(seed)
    return fit_surface(Scan(gaussian_filter(rng.normal(size=(n, n)), 1.5) * 8e-9, H, H))


SURFACES = {
    "rough": rough,
    "trench": lambda: fit_surface(trench_scan()),
    "ridges": lambda: fit_surface(ridges_scan()),
    "steps": lambda: fit_surface(steps_scan()),
}


def _run(proj, pts, chain=False, hints=None):
    out = np.empty((len(pts), pj.OUT_SIZE))
    hts = np.empty((0, 2)) if hints is None else hints
    pj.project_batch_kernel(proj.kernel_args(), pts, hts, chain, 10e-9, out)
    return out


def _queries(surface, rng, n, above=30e-9):
    (u0, u1), (v0, v1) = surface.domain
    z = surface.control_points[..., 2]
    return np.column_stack([rng.uniform(u0 - 4e-9, u1 + 4e-9, n), rng.uniform(v0 - 4e-9, v1 + 4e-9, n),
                            rng.uniform(z.min() - 2e-9, z.max() + above, n)])


def _same(a, b):
    """``b`` (tiled) is never farther than ``a`` (whole pyramid), equal to TOL where ``a``
    converged, and the same point wherever the answer is not a tie."""
    da, db = np.abs(a[:, pj.OUT_DISTANCE]), np.abs(b[:, pj.OUT_DISTANCE])
    assert np.all(db <= da + TOL)
    converged = a[:, pj.OUT_STATUS] == status.OK
    assert np.max(np.abs(da - db)[converged]) <= TOL
    gap = np.linalg.norm(a[:, pj.OUT_PX:pj.OUT_PX + 3] - b[:, pj.OUT_PX:pj.OUT_PX + 3], axis=1)
    ties = (gap > TOL) & converged
    # a different point is only allowed where two points are equally close (to 1e-12 m)
    assert np.all(np.abs(da[ties] - db[ties]) <= TOL)
    assert ties.mean() < 0.01
    np.testing.assert_array_equal(a[converged & ~ties, pj.OUT_BOUNDARY], b[converged & ~ties, pj.OUT_BOUNDARY])


@pytest.mark.parametrize("name", sorted(SURFACES))
@pytest.mark.parametrize("tile", [1, 5, 16])
def test_tiled_answers_equal_the_whole_pyramid(name, tile):
    s = SURFACES[name]()
    rng = np.random.default_rng(len(name) + tile)
    pts = _queries(s, rng, 1500)
    _same(_run(Projector(s), pts), _run(TiledProjector(s, tile=tile), pts))


def test_queries_on_tile_borders_and_far_above():
    s = rough()
    rng = np.random.default_rng(7)
    tile = 8
    (u0, _), (v0, _) = s.domain
    edges_u = u0 + H * tile * np.arange(1, 8)
    edges_v = v0 + H * tile * np.arange(1, 8)
    n = 600
    pts = np.column_stack([rng.choice(edges_u, n) + rng.normal(scale=1e-12, size=n),
                           rng.choice(edges_v, n) + rng.normal(scale=0.3e-9, size=n),
                           rng.uniform(-5e-9, 12e-9, n)])
    far = _queries(s, rng, 300, above=400e-9)
    pts = np.vstack([pts, far])
    _same(_run(Projector(s), pts), _run(TiledProjector(s, tile=tile), pts))


def test_warm_chains_and_a_pool_smaller_than_the_surface():
    s = rough(90, seed=5)
    rng = np.random.default_rng(11)
    walk = np.cumsum(rng.normal(scale=0.4e-9, size=(3000, 3)), axis=0)
    (u0, u1), (v0, v1) = s.domain
    pts = np.column_stack([u0 + np.mod(walk[:, 0], u1 - u0), v0 + np.mod(walk[:, 1], v1 - v0),
                           2e-9 + np.abs(np.mod(walk[:, 2], 20e-9) - 10e-9)])
    small = TiledProjector(s, tile=4, pool_bytes=1)  # 4 slots for 529 tiles: evicts all the time
    assert small.grid[pj.G_SLOTS] == 4 and small.tile_count == 23 * 23  # 89 x 89 knot cells
    cold = _run(Projector(s), pts)
    _same(cold, _run(small, pts, chain=True))
    assert small.builds > small.grid[pj.G_SLOTS]  # it did evict and rebuild


def test_deformation_refreshes_only_built_tiles_and_stays_exact():
    s = rough()
    live = s.copy()
    tiled = TiledProjector(live, tile=6)
    setattr(live, pj._ATTR, tiled)  # the deformer refreshes the projector the surface holds
    live.attach(tiled)
    rng = np.random.default_rng(2)
    warm = _queries(live, rng, 200)
    _run(tiled, warm)  # build some tiles before the dent
    c = (35e-9, 35e-9, float(live.evaluate(35e-9, 35e-9)[2]) + 12e-9)
    Deformer(live).apply(c, 20e-9, (0.0, 0.0, 1.0), 14e-9)
    assert live.is_deformed and tiled.slack[0] > 0.0
    pts = np.vstack([_queries(live, rng, 800), c + rng.normal(scale=5e-9, size=(400, 3))])
    fresh = live.copy()  # a new, whole-surface projector from the deformed net
    _same(_run(Projector(fresh), pts), _run(tiled, pts))


def test_nan_control_points_are_reported_not_searched():
    s = rough(40)
    ctrl = s.control_points.copy()
    ctrl[20, 20, 2] = np.nan
    bad = BSplineSurface.construct_fast(ctrl, s.knots_u, s.knots_v)
    t = TiledProjector(bad, tile=4)
    out = np.empty(pj.OUT_SIZE)
    x, y = bad.evaluate(10e-9, 10e-9)[:2]
    assert pj.collide_any(t.kernel_args(), x, y, 1e-9, 1e-8, np.nan, np.nan, out) == 0  # far from the NaN: fine
    x, y = ctrl[20, 20, :2]
    assert pj.collide_any(t.kernel_args(), x, y, 1e-9, 1e-8, np.nan, np.nan, out) == status.NON_FINITE


def test_large_surfaces_get_a_tiled_projector_and_the_python_api_uses_it(monkeypatch):
    monkeypatch.setattr(pj, "TILED_ABOVE", 100)
    s = rough(40)
    proj = pj.projector(s)
    assert isinstance(proj, TiledProjector)
    rng = np.random.default_rng(4)
    pts = _queries(s, rng, 300)
    many = project_many(s, pts)
    ref = _run(Projector(s.copy()), pts)
    assert np.max(np.abs(np.abs(many.distance) - np.abs(ref[:, pj.OUT_DISTANCE]))) <= TOL
    one = pj.project(s, pts[0])
    assert abs(abs(one.distance) - abs(ref[0, pj.OUT_DISTANCE])) <= TOL
    c = collide_many(s, pts, 10e-9)
    np.testing.assert_allclose(c.depth, 10e-9 - many.distance, rtol=0, atol=1e-21)


def test_the_model_tick_is_the_same_on_a_tiled_surface(monkeypatch):
    s = rough(60)
    plain = make_model(s.copy(), tip_radius=10e-9, effective_modulus=10e9, work_of_adhesion=0.1)
    monkeypatch.setattr(pj, "TILED_ABOVE", 100)
    tiled = make_model(s.copy(), tip_radius=10e-9, effective_modulus=10e9, work_of_adhesion=0.1)
    assert len(tiled.kernel_args()[0]) == 16 and len(plain.kernel_args()[0]) == 9
    rng = np.random.default_rng(9)
    path = np.cumsum(rng.normal(scale=0.5e-9, size=(400, 3)), axis=0) + (30e-9, 30e-9, 0.0)
    for c in path:
        c = c.copy()
        c[2] = float(s.evaluate(c[0], c[1])[2]) + 9e-9 + 2e-9 * np.sin(c[2] * 1e9)
        a, b = plain.step(c), tiled.step(c)
        assert abs(a.depth - b.depth) <= TOL and a.md_status == b.md_status
        np.testing.assert_allclose(a.simulated_force, b.simulated_force, rtol=0,  # a 1e-15 m point error over R
                                   atol=1e-6 * np.linalg.norm(a.simulated_force) + 1e-20)


def test_a_scan_too_large_for_this_machine_is_refused_before_fitting(monkeypatch):
    from arsurf import _validation

    monkeypatch.setattr(_validation, "available_memory", lambda: 1 << 20)  # 1 MB free
    scan = Scan(np.zeros((300, 300)), H, H)
    with pytest.raises(SurfaceError, match=r"fitting this 300x300 scan needs about .* GB but this machine has .* "
                                           r"available; crop it"):
        fit_surface(scan)
    monkeypatch.setattr(_validation, "available_memory", lambda: None)  # unknown: no guard
    assert fit_surface(Scan(np.zeros((8, 8)), H, H)).shape == (10, 10)


def test_the_packed_dispatch_answers_the_same_from_python():
    """_project_struct run as plain Python (not through its compiled overload) picks the same
    kernel for either projector and gives the compiled answers."""
    s = rough(40)
    q = (20e-9, 20e-9, float(s.evaluate(20e-9, 20e-9)[2]) + 6e-9)
    for proj in (Projector(s), TiledProjector(s, tile=8)):
        a, b = np.empty(pj.OUT_SIZE), np.empty(pj.OUT_SIZE)
        assert pj._project_struct(proj._packed, *q, np.nan, np.nan, a) == 0
        pj.project_any(proj.kernel_args(), *q, np.nan, np.nan, b)
        assert abs(a[pj.OUT_DISTANCE] - b[pj.OUT_DISTANCE]) <= TOL
