"""Nanotube model ([MWCNT], Eq. 9 corrected), pushing, scene integration and the "Z" planner."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import minimize_scalar

from arsurf.errors import ManipulationError
from arsurf.manipulation.nanotube import Nanotube, push, rotation_centre
from arsurf.manipulation.z_strategy import plan_z_pushes
from arsurf.scan.scan import Scan

L0 = 1e-6
SQ2 = math.sqrt(2.0)


def eq9_residuals(l, s, L, f=1.0):
    """[MWCNT] Eq. 9 for a push beyond the middle (mirror for l < L/2), with F from the force
    balance; returns (F, moment residual) in units of f and f L^2."""
    if l > L / 2:
        F = f * (L - s) - f * s
        moment = F * (l - s) - 0.5 * f * (L - s) ** 2 - 0.5 * f * s**2
    else:  # mirror: the segment [0, s] moves with the tip, [s, L] backwards
        F = f * s - f * (L - s)
        moment = F * (s - l) - 0.5 * f * s**2 - 0.5 * f * (L - s) ** 2
    return F, moment / (f * L * L)


# ------------------------------------------------------------------------------------------------
# rotation centre
# ------------------------------------------------------------------------------------------------


@settings(max_examples=200, deadline=None)
@given(frac=st.floats(0.0, 1.0), L=st.floats(1e-8, 1e-4))
def test_rotation_centre_satisfies_eq9_to_machine_precision(frac, L):
    l = frac * L
    if l == L / 2:
        return
    s = float(rotation_centre(l, L))
    F, residual = eq9_residuals(l, s, L)
    assert F > 0.0  # the push is positive: s lies on the far side of the middle
    assert abs(residual) <= 8 * np.finfo(float).eps
    assert 0.0 <= s <= L


def test_end_push_gives_the_classical_pivot():
    assert float(rotation_centre(L0, L0)) == pytest.approx(L0 * (1 - 1 / SQ2), rel=1e-15)
    assert float(rotation_centre(0.0, L0)) == pytest.approx(L0 / SQ2, rel=1e-15)


def test_printed_eq10_is_not_a_solution_of_eq9():
    # docs/design.rst, "Known errors in the sources": [MWCNT]'s Eq. 10 (L^2 under the root) violates its own Eq. 9
    L, l = L0, 0.9 * L0
    s_printed = l - math.sqrt(l * l - l * L + L * L)
    assert abs(eq9_residuals(l, s_printed, L)[1]) > 0.01
    assert abs(eq9_residuals(l, float(rotation_centre(l, L)), L)[1]) < 1e-15


@pytest.mark.parametrize("frac", [0.55, 0.7, 0.85, 1.0, 0.3, 0.05])
def test_pivot_minimises_the_push_force(frac):
    # slow reference: the pivot needing the least force F(s) = f[(L-s)^2 + s^2] / (2|l-s|)
    L = 1.0
    l = frac * L
    far = (0.0, l - 1e-9) if l > 0.5 else (l + 1e-9, 1.0)
    res = minimize_scalar(lambda s: ((L - s) ** 2 + s**2) / (2 * abs(l - s)), bounds=far,
                          method="bounded", options={"xatol": 1e-12})
    assert float(rotation_centre(l, L)) == pytest.approx(res.x, abs=1e-6)


def test_pivot_limits_and_middle():
    s = rotation_centre(np.array([0.5 + 1e-12, 0.5 - 1e-12, 0.5]), 1.0)
    assert s[0] == pytest.approx(0.0, abs=1e-11) and s[1] == pytest.approx(1.0, abs=1e-11)
    assert math.isinf(s[2])  # exact middle: translation, pivot at infinity
    # mirror symmetry s(l) = L - s(L - l)
    l = np.linspace(0, 1, 101)
    l = l[l != 0.5]
    np.testing.assert_allclose(rotation_centre(l, 1.0), 1.0 - rotation_centre(1.0 - l, 1.0), atol=1e-15)


def test_rotation_centre_rejects_points_off_the_tube():
    with pytest.raises(ManipulationError, match=r"0 <= l <= L"):
        rotation_centre(1.2e-6, 1e-6)
    with pytest.raises(ManipulationError, match="length must be positive"):
        rotation_centre(0.0, -1.0)


# ------------------------------------------------------------------------------------------------
# the tube record
# ------------------------------------------------------------------------------------------------


def test_tube_validation_messages():
    with pytest.raises(ManipulationError, match="length must be positive"):
        Nanotube(-1e-6, 10e-9)
    with pytest.raises(ManipulationError, match="angle must be finite"):
        Nanotube(1e-6, 10e-9, angle=float("nan"))
    with pytest.raises(ManipulationError, match="diameter must be a number"):
        Nanotube(1e-6, "wide")


def test_transform_places_the_canonical_tube():
    t = Nanotube(2e-6, 20e-9, x=1e-6, y=-3e-6, angle=2.0, base=5e-9)
    m = t.transform()
    ends = np.array([[-1e-6, 0, 0, 1], [1e-6, 0, 0, 1]]) @ m.T
    np.testing.assert_allclose(ends[:, :3], t.endpoints, atol=1e-21)
    assert t.endpoints[0, 2] == pytest.approx(15e-9)


# ------------------------------------------------------------------------------------------------
# pushing
# ------------------------------------------------------------------------------------------------

TUBE = Nanotube(L0, 20e-9, x=0.0, y=0.0, angle=0.0)
R_TIP = 10e-9
RHO = R_TIP + TUBE.radius


def side_push(tube, l, d, approach=2e-9, sign=1.0, R=R_TIP):
    """Push perpendicular to the axis at arc-length l by d after an approach gap."""
    u = tube.direction
    nu = np.array([-u[1], u[0]]) * sign
    t = tube.point_at(l)
    rho = R + tube.radius
    start = (t[0] - nu[0] * (rho + approach), t[1] - nu[1] * (rho + approach), t[2])
    return push(tube, start, (nu[0] * (approach + d), nu[1] * (approach + d)), R)


@pytest.mark.parametrize("frac", [1.0, 0.9, 0.75, 0.6, 0.25, 0.0])
def test_small_push_rotates_about_the_eq9_pivot(frac):
    l = frac * L0
    d = 1e-11  # small: the contact barely slides, the pivot is the one of the first contact
    res = side_push(TUBE, l, d)
    s = float(rotation_centre(l, L0))
    pivot_before = TUBE.point_at(s)[:2]
    pivot_after = res.tube.point_at(s)[:2]
    contact_before = TUBE.point_at(l)[:2]
    contact_after = res.tube.point_at(l)[:2]
    assert res.touched and res.status == "ok"
    assert np.linalg.norm(pivot_after - pivot_before) <= 1e-6 * d
    assert np.linalg.norm(contact_after - contact_before) == pytest.approx(d, rel=1e-6)
    assert res.tube.angle == pytest.approx(d / (l - s), rel=1e-6)  # sign: + beyond middle, - before
    assert res.pivot == pytest.approx(s, rel=1e-12)


def test_push_at_the_middle_translates():
    res = side_push(TUBE, 0.5 * L0, 30e-9)
    assert res.tube.angle == 0.0 and math.isinf(res.pivot)
    assert res.tube.x == pytest.approx(0.0, abs=1e-20)
    assert res.tube.y == pytest.approx(30e-9, rel=1e-9)


def test_end_on_push_slides_the_tube_along_its_axis():
    a = TUBE.endpoints[0]
    res = push(TUBE, (a[0] - RHO - 5e-9, 0.0, a[2]), (45e-9, 0.0), R_TIP)
    assert res.tube.angle == pytest.approx(0.0, abs=1e-15)
    assert res.tube.x == pytest.approx(40e-9, rel=1e-9)
    assert res.tube.y == pytest.approx(0.0, abs=1e-20)


def test_no_contact_leaves_the_tube_alone():
    res = push(TUBE, (0.0, 100e-9, TUBE.axis_height), (200e-9, 0.0), R_TIP)
    assert not res.touched and res.tube is TUBE and math.isnan(res.contact)
    # a tip higher than R + r above the axis passes over the tube
    res = push(TUBE, (0.0, -100e-9, TUBE.axis_height + RHO + 1e-12), (0.0, 200e-9), R_TIP)
    assert not res.touched


def test_descending_tip_pushes_the_tube_aside():
    start = (0.2e-6, 5e-9, TUBE.axis_height + RHO + 5e-9)
    res = push(TUBE, start, (0.0, 0.0, -RHO - 5e-9), R_TIP)
    end = np.add(start, (0.0, 0.0, -RHO - 5e-9))
    assert res.touched
    assert res.tube.tip_overlap(end, R_TIP) <= 1e-12 * RHO
    assert res.tube.y < 0.0  # the tip came down on the +y flank: the tube goes to -y


@settings(max_examples=150, deadline=None)
@given(
    angle=st.floats(-math.pi, math.pi),
    frac=st.floats(0.0, 1.0),
    heading=st.floats(-1.2, 1.2),
    dist=st.floats(0.0, 0.6),
    R=st.floats(1e-9, 40e-9),
    dz=st.floats(-1.0, 1.0),
    side=st.sampled_from([-1.0, 1.0]),
)
def test_tube_never_overlaps_or_passes_through_the_tip(angle, frac, heading, dist, R, dz, side):
    tube = Nanotube(L0, 20e-9, x=0.3e-6, y=-0.2e-6, angle=angle)
    reach = R + tube.radius
    z = tube.axis_height + dz * reach * 0.999
    rho = math.sqrt(reach**2 - (z - tube.axis_height) ** 2)
    u = tube.direction
    nu = np.array([-u[1], u[0]]) * side
    t = tube.point_at(frac * L0)[:2]
    start2 = t - nu * (rho + 1e-9)
    direction = math.cos(heading) * nu + math.sin(heading) * u
    disp = direction * dist * L0
    res = push(tube, (start2[0], start2[1], z), disp, R)
    end = np.array([start2[0] + disp[0], start2[1] + disp[1], z])
    assert res.tube.tip_overlap(end, R) <= 1e-12 * reach
    assert res.status == "ok"
    # no pass-through: if the tip ends beside the tube's body, it is on the side it came from
    nt = res.tube
    un = nt.direction
    rel = end[:2] - nt.endpoints[0, :2]
    along = rel @ un
    across = rel @ np.array([-un[1], un[0]])
    if 0.0 <= along <= L0:
        assert across * side < 0.0


def test_pushes_compose_like_one_long_push():
    # the live loop pushes in many small steps; a replay may push in one: same result (sub-steps)
    start = np.array([0.4e-6, -RHO - 1e-9, TUBE.axis_height])
    disp = np.array([0.0, 150e-9, 0.0])
    one = push(TUBE, start, disp, R_TIP, max_substep=1e-9).tube
    many = TUBE
    for k in range(150):
        many = push(many, start + disp * k / 150, disp / 150, R_TIP, max_substep=1e-9).tube
    np.testing.assert_allclose(many.pose, one.pose, atol=1e-15, rtol=1e-9)


def test_push_rejects_bad_input():
    with pytest.raises(ManipulationError, match="tip_center must be 3 finite"):
        push(TUBE, (0.0, 0.0), (1e-9, 0.0), R_TIP)
    with pytest.raises(ManipulationError, match="tip_displacement must be 3 finite"):
        push(TUBE, (0.0, 0.0, 0.0), (np.nan, 0.0), R_TIP)
    with pytest.raises(ManipulationError, match="tip_radius must be >= 0"):
        push(TUBE, (0.0, 0.0, 0.0), (1e-9, 0.0), -1e-9)
    with pytest.raises(ManipulationError, match=r"middle_band must be in \[0, 0.5\)"):
        push(TUBE, (0.0, 0.0, 0.0), (1e-9, 0.0), R_TIP, middle_band=0.7)


# ------------------------------------------------------------------------------------------------
# height map and collision
# ------------------------------------------------------------------------------------------------


def test_tip_overlap_is_the_distance_to_the_capsule():
    t = Nanotube(L0, 20e-9, angle=0.3)
    a, b = t.endpoints
    on_axis = 0.5 * (a + b)
    assert t.tip_overlap(on_axis + [0, 0, 25e-9], 5e-9) == pytest.approx(-10e-9 + 0.0, abs=1e-20)
    beyond_b = b + 0.5 * (b - a) / np.linalg.norm(b - a) * 30e-9  # 15 nm past the cap centre
    assert t.tip_overlap(beyond_b, 10e-9) == pytest.approx(5e-9, rel=1e-9)
    many = t.tip_overlap(np.stack([on_axis, beyond_b]), 10e-9)
    assert many.shape == (2,) and many[0] == pytest.approx(20e-9)
    with pytest.raises(ManipulationError, match=r"shape \(3,\) or \(n, 3\)"):
        t.tip_overlap((0.0, 0.0), 1e-9)


def brute_force_image(tube, x, y, R, n=181):
    """Slow reference: lowest apex height of a sphere of radius R over (x, y) that does not enter
    the tube, from a dense sampling of the tube surface (NaN where it does not touch)."""
    a, b = tube.endpoints
    r = tube.radius
    ts = np.linspace(-r, tube.length + r, 4 * n)
    ph = np.linspace(0.0, np.pi, n)
    T, P = np.meshgrid(ts, ph)
    u = tube.direction
    nu = np.array([-u[1], u[0]])
    along = np.clip(T, 0.0, tube.length)
    cap = T - along  # beyond the ends: hemispherical caps
    rad = np.sqrt(np.maximum(r * r - cap * cap, 0.0))
    px = a[0] + T * u[0] + rad * np.cos(P) * nu[0]
    py = a[1] + T * u[1] + rad * np.cos(P) * nu[1]
    pz = a[2] + rad * np.sin(P)
    h2 = (px - x) ** 2 + (py - y) ** 2
    ok = h2 < R * R if R > 0 else h2 < (0.5 * (ts[1] - ts[0])) ** 2 + (r * (ph[1] - ph[0])) ** 2
    if not ok.any():
        return np.nan
    zc = pz[ok] + np.sqrt(np.maximum(R * R - h2[ok], 0.0))
    return zc.max() - R


@pytest.mark.parametrize("R", [0.0, 15e-9])
def test_height_map_matches_a_brute_force_tip_image(R):
    t = Nanotube(300e-9, 20e-9, x=0.0, y=0.0, angle=0.6, base=2e-9)
    u = t.direction
    nu = np.array([-u[1], u[0]])
    for along, across in [(0.0, 0.0), (50e-9, 8e-9), (100e-9, -15e-9), (160e-9, 3e-9), (150e-9, 0.0)]:
        p = along * u + across * nu
        got = float(t.height_map(p[0], p[1], tip_radius=R))
        ref = brute_force_image(t, p[0], p[1], R)
        if math.isnan(ref):
            assert math.isnan(got)
        else:
            assert got == pytest.approx(ref, abs=0.2e-9)
    assert float(t.height_map(0.0, 0.0)) == pytest.approx(22e-9)


def test_add_to_heights_and_resting_on():
    h = np.zeros((40, 60))
    h[20, 30] = 3e-9  # a bump under the tube
    scan = Scan(h, dx=10e-9, dy=10e-9, source="synthetic:flat")
    t = Nanotube(200e-9, 20e-9, x=300e-9, y=200e-9, angle=0.0).resting_on(scan)
    assert t.base == pytest.approx(3e-9)
    out = t.add_to_heights(scan)
    assert out.heights[20, 30] == pytest.approx(23e-9)
    assert out.heights[20, 20] == pytest.approx(23e-9)  # axis end A at x = 200 nm
    assert out.heights[0, 0] == 0.0 and out.heights[30, 30] == 0.0
    assert out.history[-1]["step"] == "add_nanotube"
    arr = t.add_to_heights(h, dx=10e-9, dy=10e-9)
    np.testing.assert_array_equal(arr, out.heights)
    with pytest.raises(ManipulationError, match="give dx and dy"):
        t.add_to_heights(h)
    with pytest.raises(ManipulationError, match="outside the scan"):
        Nanotube(100e-9, 10e-9, x=-5e-6).resting_on(scan)


# ------------------------------------------------------------------------------------------------
# the "Z" strategy
# ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_z_plan_reaches_the_goal_and_replays(seed):
    rng = np.random.default_rng(seed)
    L = rng.uniform(0.5e-6, 2e-6)
    R = rng.uniform(3e-9, 20e-9)
    tube = Nanotube(L, 15e-9, *rng.uniform(-1e-6, 1e-6, 2), rng.uniform(-np.pi, np.pi))
    goal = Nanotube(L, 15e-9, *rng.uniform(-1.5e-6, 1.5e-6, 2), rng.uniform(-np.pi, np.pi))
    plan = plan_z_pushes(tube, goal, R, position_tolerance=5e-9, angle_tolerance=0.005)
    assert plan.converged
    # replaying the pushes with the public model reproduces the plan and reaches the goal
    cur = tube
    for p in plan.pushes:
        assert cur.tip_overlap(p.start, R) < 0.0  # each push starts clear of the tube
        cur = push(cur, p.start, p.displacement, R).tube
        assert cur == p.after
    assert math.hypot(cur.x - goal.x, cur.y - goal.y) <= 5e-9
    d = (cur.angle - goal.angle) % math.pi
    assert min(d, math.pi - d) <= 0.005
    ends = [p.end for p in plan.pushes]
    assert all(a != b for a, b in zip(ends, ends[1:]))  # "Z": the ends alternate


def test_z_plan_pure_sideways_move_is_a_zigzag():
    tube = Nanotube(1e-6, 20e-9)
    plan = plan_z_pushes(tube, (0.0, 0.4e-6, 0.0), 10e-9, position_tolerance=2e-9, angle_tolerance=1e-3)
    assert plan.converged and len(plan.pushes) >= 2
    # every push goes the same way (+y): the tip path draws a Z, not a turn in place
    assert all(p.displacement[1] > 0 for p in plan.pushes)


def test_z_plan_rejects_bad_tolerances():
    with pytest.raises(ManipulationError, match="position_tolerance must be positive"):
        plan_z_pushes(TUBE, (0.0, 0.0, 0.0), 1e-9, position_tolerance=0.0, angle_tolerance=0.1)
    with pytest.raises(ManipulationError, match="goal must be a Nanotube or"):
        plan_z_pushes(TUBE, (0.0, 0.0), 1e-9, position_tolerance=1e-9, angle_tolerance=0.1)
