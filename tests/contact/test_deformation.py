"""Control-net dents: on the sphere inside the contact radius, nothing inside the tip, local, reversible."""
import numpy as np
import pytest

from arsurf.contact.deformation import PATCH_PER_CONTACT, RIM_MARGIN, Deformer
from arsurf.errors import ContactError
from arsurf.scan.scan import Scan
from arsurf.spline.fit import fit_surface
from arsurf.spline.surface import BSplineSurface

H = 4e-9  # net spacing (the 4 nm grid)


@pytest.fixture
def flat():
    return BSplineSurface.from_heights(np.zeros((103, 103)), (0.0, 100 * H), (0.0, 100 * H))


def _rho(points, c, n):
    rel = points - c
    s = rel @ n
    return np.linalg.norm(rel - s[..., None] * n, axis=-1), s


@pytest.mark.parametrize("R, depth, a", [(20e-9, 2e-9, 10e-9), (50e-9, 5e-9, 30e-9), (5e-9, 1e-9, 4e-9)])
def test_points_within_contact_radius_lie_on_the_sphere_and_none_inside(flat, R, depth, a):
    """Any (a, depth): the contact zone on the sphere, nothing inside the tip."""
    c = np.array([200e-9 + 1.3e-9, 200e-9 - 0.7e-9, R - depth])
    n = np.array([0.0, 0.0, 1.0])
    res = Deformer(flat).apply(c, R, n, a, depth=depth, zone_radius=a + 1e-9)
    P = flat.control_points.reshape(-1, 3)
    P0 = flat.rest_control_points.reshape(-1, 3)
    rho, _ = _rho(P0, c, n)
    dist = np.linalg.norm(P - c, axis=1)
    inner = rho < a
    np.testing.assert_allclose(dist[inner], R, rtol=1e-12)          # adhered zone on the sphere
    assert dist.min() >= R * (1 - 1e-12)                              # nothing inside the tip
    moved = np.any(P != P0, axis=1)
    assert moved.sum() == res.moved > 0
    # the elastic surface reaches out to the patch radius max(R, 4a), not further
    assert rho[moved].max() <= max(R, PATCH_PER_CONTACT * a) + 1e-15


def test_points_outside_the_patch_are_bitwise_unchanged_and_cost_is_local(flat):
    before = flat.control_points.copy()
    d = Deformer(flat)
    res = d.apply((150e-9, 150e-9, 18e-9), 20e-9, (0, 0, 1), 12e-9)
    i0, i1, j0, j1 = res.patch
    r_box = max(20e-9, PATCH_PER_CONTACT * 12e-9)
    assert (i1 - i0) * (j1 - j0) <= (2 * r_box / H + 5) ** 2             # O((2 r_b/h)^2), not O(net)
    mask = np.ones(flat.shape, bool)
    mask[i0:i1, j0:j1] = False
    assert np.array_equal(flat.control_points[mask], before[mask])


def test_moving_tip_leaves_no_trace_and_release_restores_bitwise(flat):
    d = Deformer(flat)
    for x in np.linspace(100e-9, 300e-9, 25):
        d.apply((x, 200e-9, 17e-9), 20e-9, (0, 0, 1), 10e-9)
    # only the last dent remains
    P = flat.control_points
    moved = np.argwhere(np.any(P != flat.rest_control_points, axis=2))
    r_box = max(20e-9, PATCH_PER_CONTACT * 10e-9)   # the contact zone and the elastic surface around it
    assert np.all(np.abs(flat.rest_control_points[moved[:, 0], moved[:, 1], 0] - 300e-9) < r_box + H)
    d.release()
    assert np.array_equal(flat.control_points, flat.rest_control_points) and not flat.is_deformed


def test_tilted_normal_and_adhesive_neck_pulls_points_up(rng):
    y, x = np.mgrid[0:60, 0:60] * H
    s = fit_surface(Scan(0.3 * x + rng.normal(size=x.shape) * 0.1e-9, dx=H, dy=H))
    n = np.array([-0.3, 0.0, 1.0]) / np.hypot(0.3, 1.0)
    foot = np.array([120e-9, 120e-9, 0.3 * 120e-9])
    R, a = 20e-9, 8e-9
    c = foot + n * (R + 1e-9)  # tip 1 nm ABOVE the surface: only adhesion (a > 0) holds the neck
    d = Deformer(s)
    d.apply(c, R, n, a)
    P, P0 = s.control_points, s.rest_control_points
    rho, sax = _rho(P0.reshape(-1, 3), c, n)
    inner = rho < a
    assert inner.any()
    lifted = (P.reshape(-1, 3) - P0.reshape(-1, 3))[inner] @ n
    assert np.all(lifted > 0)                                            # pulled towards the tip
    np.testing.assert_allclose(np.linalg.norm(P.reshape(-1, 3)[inner] - c, axis=1), R, rtol=1e-12)


def test_approach_retract_cycle_returns_to_rest(flat):
    d = Deformer(flat)
    for z in np.r_[np.linspace(25e-9, 15e-9, 11), np.linspace(15e-9, 25e-9, 11)]:
        a = np.sqrt(max(20e-9 * (20e-9 - z), 0.0))  # Hertz-like radius from the depth
        d.apply((200e-9, 200e-9, z), 20e-9, (0, 0, 1), a)
    assert not flat.is_deformed  # tip 5 nm above at the end: nothing touched


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"radius": -1e-9}, "radius` must be positive"),
        ({"radius": 0.0}, "radius` must be positive"),
        ({"contact_radius": np.nan}, "contact_radius"),
        ({"normal": (0, 0, 2)}, "unit vector"),
        ({"center": (np.nan, 0, 0)}, "center` must be finite"),
    ],
)
def test_bad_input(flat, kwargs, match):
    args = {"center": (100e-9, 100e-9, 10e-9), "radius": 20e-9, "normal": (0, 0, 1), "contact_radius": 5e-9}
    args.update(kwargs)
    with pytest.raises(ContactError, match=match):
        Deformer(flat).apply(**args)


def test_refuses_a_net_that_is_not_a_height_field(flat):
    ctrl = flat.control_points.copy()
    ctrl[5, 5, 0] += 1e-10
    with pytest.raises(ContactError, match="height-field net"):
        Deformer(BSplineSurface(ctrl, flat.knots_u, flat.knots_v))


def test_projection_stays_exact_on_the_dented_surface(rng):
    """After a dent (the net is no longer a height field) the projection still finds the global
    closest point: compared with a dense sampling polished by Newton (brute force)."""
    from arsurf.contact.projection import project

    y, x = np.mgrid[0:40, 0:40] * H
    s = fit_surface(Scan(2e-9 * np.sin(x / 20e-9) * np.cos(y / 30e-9), dx=H, dy=H))
    project(s, (80e-9, 80e-9, 30e-9))  # build the projector before deforming: it must be refreshed
    d = Deformer(s)
    c = np.array([80e-9, 80e-9, s.evaluate(80e-9, 80e-9)[2] + 20e-9 - 4e-9])
    d.apply(c, 20e-9, (0, 0, 1), 12e-9)
    uu, vv = np.meshgrid(np.linspace(0, 39 * H, 400), np.linspace(0, 39 * H, 400))
    dense = s.evaluate(uu, vv).reshape(-1, 3)
    for q in [c, c + [3e-9, -2e-9, -1e-9], c + [12e-9, 5e-9, 5e-9]] + list(c + rng.normal(size=(20, 3)) * 8e-9):
        p = project(s, q)
        brute = np.linalg.norm(dense - q, axis=1).min()
        assert abs(p.distance) <= brute + 1e-15        # never worse than any sample
        assert brute - abs(p.distance) < 0.5e-9        # and within the sampling resolution
        assert abs(np.linalg.norm(np.asarray(p.point) - q) - abs(p.distance)) < 1e-15


# ---------------------------------------------------------------------------------------------
# the elastic surface outside the contact (issue 17: the dent spans a, not the overlap sqrt(2 R delta))

import math  # noqa: E402

from arsurf.contact.deformation import dent_displacement, elastic_displacement  # noqa: E402
from arsurf.contact.maugis_dugdale import MaugisDugdale  # noqa: E402
from tests.support.reference import ref_md_traction, ref_surface_displacement  # noqa: E402

R_TIP = 20e-9
#: (E*, w, sigma0, depth): DMT-like (lambda 0.2), the transition (~1), JKR-like (lambda 4), and a tensile neck
MD_CASES = [(50e9, 0.05, 0.5e9, 1.0e-9), (10e9, 0.1, 0.6e9, 1.5e-9), (2e9, 0.2, 0.6e9, 2.0e-9),
            (10e9, 0.1, 0.6e9, -0.1e-9)]


def _state(E, w, s0, depth):
    md = MaugisDugdale(R_TIP, E, w, s0)
    st = md.contact_state(depth=depth)
    assert st.branch == "contact"
    return md, st.radius, st.cohesive_radius


@pytest.mark.parametrize("E, w, s0, depth", MD_CASES)
def test_elastic_displacement_is_boussinesq_over_maugis_tractions(E, w, s0, depth):
    """The closed form (Hertz + flat punches for the Dugdale zone) against Boussinesq's point-load
    solution summed over Maugis' tractions by adaptive quadrature; the tractions themselves are
    checked against the MD load and the contact condition inside a."""
    md, a, c = _state(E, w, s0, depth)
    from scipy.integrate import quad

    P = 2 * math.pi * sum(quad(lambda t: ref_md_traction(t, a, c, R_TIP, E, s0) * t, lo, hi, limit=400, epsabs=0.0,
                               epsrel=1e-12)[0] for lo, hi in ((0.0, a), (a, c)))
    assert P == pytest.approx(md.load(depth), rel=1e-7, abs=1e-9 * md.load_scale)
    for x in (0.0, 0.5, 0.9):   # inside: the surface is the paraboloid of the contact solution
        assert ref_surface_displacement(x * a, a, c, R_TIP, E, s0) == pytest.approx(
            depth - (x * a) ** 2 / (2 * R_TIP), abs=1e-6 * md.depth_scale)
    for rho in [a * x for x in (1.0, 1.0001, 1.05, 1.3, 2.0, 4.0, 8.0)] + [c, 0.5 * (a + c), 1.5 * c]:
        u = elastic_displacement(rho, a, R_TIP, depth, c)
        assert u == pytest.approx(ref_surface_displacement(rho, a, c, R_TIP, E, s0), abs=1e-6 * md.depth_scale)


@pytest.mark.parametrize("E, w, s0, depth", MD_CASES)
def test_the_gap_at_the_edge_of_the_dugdale_zone_is_its_range(E, w, s0, depth):
    """Maugis' condition h(c) = h0 = w / sigma0, which fixes c: an independent check of the profile."""
    md, a, c = _state(E, w, s0, depth)
    gap = elastic_displacement(c, a, R_TIP, depth, c) - depth + c * c / (2 * R_TIP)
    assert gap == pytest.approx(md.interaction_range, rel=1e-7)


def _fine_flat(h=0.25e-9, n=241):
    return BSplineSurface.from_heights(np.zeros((n, n)), (0.0, (n - 3) * h), (0.0, (n - 3) * h)), h


@pytest.mark.parametrize("case", ["hertz"] + [f"md{i}" for i in range(len(MD_CASES))])
def test_the_dents_rim_is_the_contact_radius(case):
    """On the sphere exactly the points within a (not the geometric overlap sqrt(2 R delta));
    outside, the surface is below the tip and follows the elastic profile."""
    s, h = _fine_flat()
    if case == "hertz":
        depth = 1.5e-9
        a = c = math.sqrt(R_TIP * depth)
    else:
        E, w, s0, depth = MD_CASES[int(case[2:])]
        _, a, c = _state(E, w, s0, depth)
    centre = np.array([29e-9 + 0.07e-9, 29e-9 - 0.11e-9, R_TIP - depth])
    Deformer(s).apply(centre, R_TIP, (0.0, 0.0, 1.0), a, depth=depth, zone_radius=c)
    P = s.control_points.reshape(-1, 3)
    P0 = s.rest_control_points.reshape(-1, 3)
    rho, _ = _rho(P0, centre, np.array([0.0, 0.0, 1.0]))
    dist = np.linalg.norm(P - centre, axis=1)
    on_sphere = np.abs(dist - R_TIP) <= 1e-12 * R_TIP
    assert on_sphere.any()
    rim = rho[on_sphere].max()
    assert a - math.sqrt(2) * h <= rim < a                                   # the dent's rim is a ...
    overlap = math.sqrt(max(2 * R_TIP * depth - depth ** 2, 0.0))
    if overlap > a + 2 * h:                                                  # ... not the overlap
        between = (rho > a + h) & (rho < overlap - h)
        assert between.any() and np.all(dist[between] > R_TIP)
    outside = rho >= a
    assert np.all(dist[outside] > R_TIP)                                     # below the tip
    near = outside & (rho < 0.5 * PATCH_PER_CONTACT * a)                      # before the fade
    u = dent_displacement(rho[near], a, R_TIP, depth, c)    # the elastic surface, lifted onto the sphere at a
    # the compiled dent reads tables (bilinear, then a 48-point profile): within 1 % of the dent's scale
    # (the largest errors sit at the edge of the Dugdale zone, where the profile has a log kink)
    scale = max(abs(depth), a * a / R_TIP, a * a / R_TIP - depth)   # the Hertz and the adhesive parts
    np.testing.assert_allclose(P0[near, 2] - P[near, 2], u, atol=1e-2 * scale)


def test_a_contact_wider_than_the_tip_leaves_no_nan(flat):
    """a > 0.9 R (a very soft sample): the contact zone follows the contact's paraboloid."""
    R, a, depth = 5e-9, 7e-9, 6e-9
    c = np.array([200e-9, 200e-9, R - depth])
    Deformer(flat).apply(c, R, (0, 0, 1), a, depth=depth, zone_radius=8e-9)
    P, P0 = flat.control_points.reshape(-1, 3), flat.rest_control_points.reshape(-1, 3)
    assert np.isfinite(P).all()
    rho, _ = _rho(P0, c, np.array([0.0, 0.0, 1.0]))
    ring = rho < a
    assert ring.any()
    np.testing.assert_allclose(P0[ring, 2] - P[ring, 2], depth - rho[ring] ** 2 / (2 * R), rtol=1e-12)


@pytest.mark.parametrize("a_over_r", [0.2, 0.5, 0.85])
def test_the_dent_is_continuous_where_it_leaves_the_tip(a_over_r):
    """At the rim the elastic surface (on the contact's paraboloid) is lifted onto the sphere:
    the net's step across rho = a is a fraction of the knot spacing's worth of slope, not the
    sphere-paraboloid gap (a^4/8R^3 ~ 0.14 nm at a = 0.85 R = 17 nm)."""
    s, h = _fine_flat()
    a = a_over_r * R_TIP
    depth = a * a / R_TIP
    centre = np.array([29e-9, 29e-9, R_TIP - depth])
    Deformer(s).apply(centre, R_TIP, (0.0, 0.0, 1.0), a, depth=depth, zone_radius=a)
    P, P0 = s.control_points.reshape(-1, 3), s.rest_control_points.reshape(-1, 3)
    rho, _ = _rho(P0, centre, np.array([0.0, 0.0, 1.0]))
    inner = (rho < a) & (rho > a - 2 * h)
    outer = (rho >= a) & (rho < a + 2 * h)
    slope = abs(np.polyfit(rho[outer | inner], P[outer | inner, 2], 1)[0])
    step = P[outer, 2].mean() - P[inner, 2].mean()
    assert abs(step) <= 4 * h * max(slope, 0.05) + 0.02 * a * a / R_TIP
    on_sphere = depth - (R_TIP - np.sqrt(R_TIP ** 2 - a ** 2))       # the sphere at the rim, within the margin
    assert 0.0 <= dent_displacement(a, a, R_TIP, depth, a) - on_sphere <= RIM_MARGIN * a * a / R_TIP * (1 + 1e-9)


# ---------------------------------------------------------------------------------------------
# the dent the tick records (O(1)) and the net moved to it when read (issue 28)

def _rough_fine_model(rng, pitch=0.25e-9, n=160, tip=20e-9):
    from arsurf.contact.maugis_dugdale import MaugisDugdale
    from arsurf.force.cantilever import Cantilever
    from arsurf.model import ARModel

    z = 0.4e-9 * rng.normal(size=(n, n))
    k = np.exp(-0.5 * (np.arange(-8, 9) / 3.0) ** 2)
    k /= k.sum()
    for axis in (0, 1):   # a rough surface correlated over ~1 nm
        z = np.apply_along_axis(lambda r: np.convolve(r, k, mode="same"), axis, z)
    s = fit_surface(Scan(z, dx=pitch, dy=pitch))
    model = ARModel(s, tip, MaugisDugdale(tip, 5e9, 0.05), Cantilever(450e-6, 50e-6, 2.5e-6, 15e-6, 169e9, 0.27))
    return s, model


def _slide(s, model, ticks=40, read_every=0):
    (u0, u1), (v0, v1) = s.domain
    x0, y0 = 0.4 * (u0 + u1), 0.5 * (v0 + v1)
    z0 = float(s.rest_control_points[..., 2].max()) + model.tip_radius - 1.0e-9   # ~1 nm deep
    for k in range(ticks):
        model.tick((x0 + 0.05e-9 * k, y0 + 0.02e-9 * k, z0))
        if read_every and k % read_every == 0:
            s.sync()
    return model.out.copy()


def test_tick_records_the_dent_without_writing_the_net(rng):
    """The tick is O(1) in the net: it writes no control point (it records the dent); the first
    read moves the net to it."""
    s, model = _rough_fine_model(rng)
    o = _slide(s, model)
    ctrl, rest, _, _ = s.raw_arrays()
    from arsurf.model import M_IN_CONTACT, M_MOVED

    assert o[M_IN_CONTACT] == 1.0 and o[M_MOVED] > 1000            # in contact, a large dent box
    assert np.array_equal(ctrl, rest)                               # nothing written by the ticks
    assert s.is_deformed                                            # ... the read shows the dent


def test_dent_read_late_is_bitwise_the_full_dent_of_the_last_tick(rng):
    """Read once after many ticks, read after every third tick, or the full dent pressed from
    rest with today's rule (a fresh net, Deformer.apply): the same net, bit for bit. The moved
    points are the full dent's, and a release gives the rest net back exactly."""
    from arsurf.contact.deformation import D_A, D_CX, D_CZ, D_DEPTH, D_NX, D_NZ, D_RADIUS, D_ZONE

    s_late, m_late = _rough_fine_model(np.random.default_rng(7))
    s_often, m_often = _rough_fine_model(np.random.default_rng(7))
    _slide(s_late, m_late, read_every=0)
    _slide(s_often, m_often, read_every=3)
    late = s_late.control_points.copy()
    assert np.array_equal(late, s_often.control_points)
    d = m_late._deformer.dent
    assert d[D_RADIUS] > 0 and d[D_A] > 0
    twin = BSplineSurface.construct_fast(s_late.rest_control_points.copy(), s_late.knots_u, s_late.knots_v)
    twin._height_field = True
    full = Deformer(twin).apply(d[D_CX:D_CZ + 1], d[D_RADIUS], d[D_NX:D_NZ + 1], d[D_A], depth=d[D_DEPTH],
                                zone_radius=d[D_ZONE])
    assert full.moved > 1000                                        # a fine net: a large dent
    assert np.array_equal(twin.control_points, late)
    m_late.reset()
    ctrl, rest, _, _ = s_late.raw_arrays()
    assert np.array_equal(ctrl, rest) and not s_late.is_deformed


def test_incremental_restore_leaves_exactly_the_last_dent(flat):
    """Dents far apart, overlapping, and a release: each point written once per dent, and the
    net is always the last dent pressed from rest (today's rule: restore all, then dent)."""
    d = Deformer(flat)
    twin = flat.copy()
    for c in [(150e-9, 150e-9, 18e-9), (152e-9, 149e-9, 17.5e-9), (300e-9, 100e-9, 18e-9), (301e-9, 101e-9, 19e-9)]:
        d.apply(c, 20e-9, (0, 0, 1), 9e-9, depth=2e-9, zone_radius=12e-9)
        twin.reset()
        Deformer(twin).apply(c, 20e-9, (0, 0, 1), 9e-9, depth=2e-9, zone_radius=12e-9)
        assert np.array_equal(flat.control_points, twin.control_points)
    d.release()
    assert np.array_equal(flat.control_points, flat.rest_control_points)


def test_a_deep_copied_model_dents_its_own_surface(rng):
    """HapticLoop.warm_up ticks a deep copy: the copy's dent reaches the copy's net, never the original's."""
    import copy

    s, model = _rough_fine_model(rng, pitch=1e-9, n=60)
    twin = copy.deepcopy(model)
    _slide(twin.surface, twin)
    assert twin.surface.is_deformed and not s.is_deformed
    _slide(s, model)
    assert np.array_equal(s.control_points, twin.surface.control_points)


@pytest.mark.parametrize("pitch_nm", [0.1, 0.5, 2.0, 8.0])
@pytest.mark.parametrize("tip_nm", [2.0, 20.0, 50.0])
def test_the_tick_tables_dent_read_late_is_the_full_dent_over_pitch_and_tip(pitch_nm, tip_nm):
    """On the tick table's surfaces (bench/_tick_table.py: 0.5 nm rms, correlated over max(6 nm, 3 px), at most a quarter of these 64 px)
    at 0.1-8 nm pitch under 2-50 nm tips, the net read once after a slide is the full dent of the
    last tick pressed from rest, bit for bit: the stated tolerance of the lazy dent is zero."""
    from arsurf.contact.deformation import D_A, D_CX, D_CZ, D_DEPTH, D_NX, D_NZ, D_RADIUS, D_ZONE
    from arsurf.contact.maugis_dugdale import MaugisDugdale
    from arsurf.force.cantilever import Cantilever
    from arsurf.model import M_IN_CONTACT, ARModel
    from arsurf.scan.synthetic import rough

    pitch, tip = pitch_nm * 1e-9, tip_nm * 1e-9
    s = fit_surface(rough((64, 64), pitch, rms=0.5e-9, correlation_length=min(max(6e-9, 3 * pitch), 16 * pitch), seed=2))
    model = ARModel(s, tip, MaugisDugdale(tip, 5e9, 0.05), Cantilever(450e-6, 50e-6, 2.5e-6, 15e-6, 169e9, 0.27))
    inner = s.rest_control_points[16:-16, 16:-16]                    # over the highest inner point, 1 nm deep
    i, j = np.unravel_index(np.argmax(inner[..., 2]), inner.shape[:2])
    x, y, z = inner[i, j, 0], inner[i, j, 1], inner[i, j, 2] + tip - 1e-9
    for k in range(30):
        model.tick((x + 0.02 * pitch * k, y, z))
    assert model.out[M_IN_CONTACT] == 1.0
    d = model._deformer.dent
    twin = BSplineSurface.construct_fast(s.rest_control_points.copy(), s.knots_u, s.knots_v)
    twin._height_field = True
    Deformer(twin).apply(d[D_CX:D_CZ + 1], d[D_RADIUS], d[D_NX:D_NZ + 1], d[D_A], depth=d[D_DEPTH],
                         zone_radius=d[D_ZONE])
    assert s.is_deformed and np.array_equal(s.control_points, twin.control_points)


# ---------------------------------------------------------------------------------------------
# several contacts of one tip, each recording its own dent (issue 28: the second and further contacts)

_DENT_A = dict(center=(150e-9, 150e-9, 18e-9), radius=20e-9, normal=(0, 0, 1), contact_radius=9e-9,
               depth=2e-9, zone_radius=12e-9)


def _tilted(c, n, a=6e-9):
    n = np.asarray(n, float) / np.linalg.norm(n)
    return dict(center=c, radius=20e-9, normal=n, contact_radius=a, depth=a * a / 20e-9 - 0.3e-9, zone_radius=1.5 * a)


def test_one_contact_of_several_dents_as_the_single_contact(flat):
    """A three-contact deformer with only contact 1 pressed gives the one-contact dent, bit for
    bit, with the same points moved and box."""
    multi, single = Deformer(flat, contacts=3), Deformer(twin := flat.copy())
    r3 = multi.apply(**_DENT_A, contact=1)
    r1 = single.apply(**_DENT_A)
    assert r3 == r1 and r1.moved > 100
    assert np.array_equal(flat.control_points, twin.control_points)


def test_contacts_far_apart_each_dent_as_alone_and_release_one_by_one(flat):
    """Two contacts whose boxes do not meet: the net is each one's single dent in its own box
    and rest elsewhere; releasing one leaves exactly the other; releasing all gives rest, bitwise."""
    b = dict(_DENT_A, center=(300e-9, 100e-9, 18.5e-9))
    alone_a, alone_b = flat.copy(), flat.copy()
    d = Deformer(flat, contacts=2)
    ra, rb = d.apply(**_DENT_A, contact=0), d.apply(**b, contact=1)
    Deformer(alone_a).apply(**_DENT_A)
    Deformer(alone_b).apply(**b)
    net, rest = flat.control_points.copy(), flat.rest_control_points
    expect = rest.copy()
    i0, i1, j0, j1 = ra.patch
    expect[i0:i1, j0:j1] = alone_a.control_points[i0:i1, j0:j1]
    i0, i1, j0, j1 = rb.patch
    expect[i0:i1, j0:j1] = alone_b.control_points[i0:i1, j0:j1]
    assert np.array_equal(net, expect) and ra.moved > 100
    d.release(contact=0)
    assert np.array_equal(flat.control_points, alone_b.control_points)
    d.apply(**_DENT_A, contact=0)
    d.release()
    assert np.array_equal(flat.control_points, rest) and not flat.is_deformed


def test_two_contacts_of_one_tip_superpose_their_elastic_surfaces():
    """A tip in a groove touches both flanks: the two contacts' elastic displacements add
    (linear elasticity) where neither contact disc nor the tip is; each disc lies on the tip;
    no control point is left inside the tip; the sync writes each point once (its moved count
    is the union's)."""
    h = 0.5e-9
    x = np.arange(160) * h
    z = 0.35 * np.abs(x - x.mean())[:, None] * np.ones((1, 160))   # a V groove along y, flanks at 19 deg
    s = BSplineSurface.from_heights(z, (0.0, x[-1]), (0.0, x[-1]))
    R = 20e-9
    t = np.arctan(0.35)
    c = np.array([x.mean(), x.mean(), R / np.cos(t) - 0.6e-9])      # pressed 0.6e-9 cos t into both flanks
    n0, n1 = (-np.sin(t), 0.0, np.cos(t)), (np.sin(t), 0.0, np.cos(t))
    dents = [_tilted(c, n0), _tilted(c, n1)]
    both = Deformer(s, contacts=2)
    for k, dent in enumerate(dents):
        both.apply(**dent, contact=k)
    alone, clear = [], np.ones(z.shape, bool)
    for dent in dents:
        one = BSplineSurface.from_heights(z, (0.0, x[-1]), (0.0, x[-1]))
        Deformer(one).apply(**dent)
        alone.append(one.control_points - one.rest_control_points)
        clear &= np.linalg.norm(one.control_points - c, axis=-1) > R * (1 + 1e-6)   # not put on the tip alone
    rest, net = s.rest_control_points, s.control_points
    dist = np.linalg.norm(net - c, axis=-1)
    assert dist.min() >= R * (1 - 1e-12)                              # nothing inside the tip
    discs = np.zeros(z.shape, bool)
    for dent in dents:
        rho, _ = _rho(rest, c, np.asarray(dent["normal"]))
        discs |= rho < dent["contact_radius"]
    assert discs.sum() > 20 and np.allclose(dist[discs], R, rtol=1e-12)   # the discs on the tip
    free = ~discs & clear & (np.linalg.norm(rest - c, axis=-1) > R) & (dist > R * (1 + 1e-6))
    both_moved = (np.abs(alone[0]).max(-1) > 0) & (np.abs(alone[1]).max(-1) > 0) & free
    assert both_moved.sum() > 100                                     # the elastic surfaces overlap
    np.testing.assert_allclose((net - rest)[free], (alone[0] + alone[1])[free], rtol=0, atol=1e-21)


def test_the_sync_kernel_leaves_the_gil_and_a_deformer_copies():
    """The net is written without the GIL (the haptic thread ticks on while a reader syncs); the
    deformer's lock is not copied: a deep copy makes its own."""
    import copy
    import pickle

    from arsurf.contact.deformation import sync_dent_kernel

    assert sync_dent_kernel.targetoptions.get("nogil") is True
    s = BSplineSurface.from_heights(np.zeros((40, 40)), (0.0, 39 * H), (0.0, 39 * H))
    d = Deformer(s, contacts=2)
    d.apply(center=(80e-9, 80e-9, 18e-9), radius=20e-9, normal=(0, 0, 1), contact_radius=9e-9, contact=1)
    for twin in (copy.deepcopy(s), pickle.loads(pickle.dumps(s))):
        assert np.array_equal(twin.control_points, s.control_points)
        (dt,) = twin._dents
        dt.release()
        assert not twin.is_deformed and s.is_deformed and dt._lock is not d._lock


@pytest.mark.parametrize("kwargs, match", [({"contacts": 0}, "contacts"), ({"contacts": 1.5}, "contacts"),
                                           ({"record": np.zeros(20), "contacts": 2}, "record")])
def test_bad_contact_counts(flat, kwargs, match):
    with pytest.raises(ContactError, match=match):
        Deformer(flat, **kwargs)
    d = Deformer(flat, contacts=2)
    with pytest.raises(ContactError, match="contact"):
        d.apply(**_DENT_A, contact=2)
