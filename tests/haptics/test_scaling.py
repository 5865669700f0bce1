"""Position and force scaling: [Alabdulmuhsin] Tables 4.2-4.6, clutch/indexing, limits."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from arsurf.errors import HapticsError
from arsurf.haptics.device import BUTTON_1, BUTTON_2, TOUCH_X
from arsurf.haptics.scaling import (
    CLAMPED,
    CLUTCHED,
    HAND_RESOLUTION,
    MASTER_OUTSIDE,
    NONFINITE,
    SEED001_K_F,
    ForceScaling,
    PositionScaling,
)

# [Alabdulmuhsin] Table 4.2 (X and Z axes, 120 mm of haptic travel) and Table 4.3 (Y axis, 160 mm):
# (probe range nm, resolution nm as printed). Two cells are garbled in the source text
# ("120/120 -> (blank)" and "12/120 -> 0 1"); their values follow from the same rule: 1 and 0.1.
TABLE_4_2 = [(5000, 41.7), (1200, 10.0), (1000, 8.3), (500, 4.2), (120, 1.0), (100, 0.8), (12, 0.1)]
TABLE_4_3 = [(5000, 31.3), (1600, 10.0), (1000, 6.3), (500, 3.1), (160, 1.0), (100, 0.6), (16, 0.1)]


@pytest.mark.parametrize("table, axis", [(TABLE_4_2, 0), (TABLE_4_2, 2), (TABLE_4_3, 1)])
def test_seed001_tables_4_2_and_4_3(table, axis):
    ws = TOUCH_X.workspace  # 120 mm (X_h), 160 mm (Y_h), 120 mm (Z_h)
    assert ws[axis] * 1e3 == (160.0 if axis == 1 else 120.0)
    for probe_nm, resolution_nm in table:
        s = PositionScaling.from_ranges(probe_nm * 1e-9, ws)
        # sensitivity column: probe nm / haptic mm
        assert s.sensitivity_nm_per_mm[axis] == pytest.approx(probe_nm / (ws[axis] * 1e3), rel=1e-12)
        # resolution column: what a 1 mm hand step moves the probe, to the table's 0.1 nm
        res_nm = s.resolution(HAND_RESOLUTION)[axis] * 1e9
        assert round(res_nm + 1e-9, 1) == resolution_nm
        # range column: the whole haptic workspace maps onto the probe range
        assert s.probe_range(ws)[axis] * 1e9 == pytest.approx(probe_nm, rel=1e-12)
        # and the same from the sensitivity as the table writes it
        s2 = PositionScaling.from_sensitivity(probe_nm / (ws[axis] * 1e3))
        np.testing.assert_allclose(s2.scale[axis], s.scale[axis], rtol=1e-12)


def test_device_resolution_is_finer_than_the_hand():
    # [Alabdulmuhsin]: the Touch X resolves 0.023 mm, the hand about 1 mm
    s = PositionScaling.from_sensitivity(5000 / 120)
    assert s.resolution(0.023e-3)[0] * 1e9 == pytest.approx(0.958, abs=1e-3)


def test_seed001_force_tables_4_4_to_4_6():
    k, S_n, G_l = 0.3, 1117e-9, 63.78e-9  # N/m, m/V, N/V (magnitude), [Alabdulmuhsin] section 4.1
    L, h = 450e-6, 15e-6  # cantilever length and tip height, Table 4.1
    fs = ForceScaling(SEED001_K_F)
    # Table 4.4: F_h,z / V_v = K_f k S_n; F_h,y / V_h = K_f G_l
    assert fs.apply([0.0, 0.0, k * S_n * 1.0])[2] == pytest.approx(5.0265, abs=5e-5)
    assert fs.apply([0.0, G_l * 1.0, 0.0])[1] == pytest.approx(0.9567, abs=5e-5)
    # Table 4.5: F_h,z = K_f k delta_z (Eq. 26). The printed 3.38 N at 700 nm is a misprint:
    # the rule the table states (and its other rows) give 3.15 N.
    for dz_nm, f_printed in [(0, 0.0), (100, 0.45), (200, 0.9), (500, 2.25), (1000, 4.5)]:
        assert fs.apply([0.0, 0.0, k * dz_nm * 1e-9])[2] == pytest.approx(f_printed, abs=5e-3)
    assert fs.apply([0.0, 0.0, k * 700e-9])[2] == pytest.approx(3.15, abs=1e-9)
    # Table 4.6: F_h,y = K_f G_l l / (h S_n) delta_y (Eq. 28), theta_x = delta_y / h
    for dy_nm, theta_deg, f_printed in [(10, 0.04, 0.26), (25, 0.10, 0.64), (50, 0.19, 1.28),
                                        (100, 0.38, 2.57), (150, 0.57, 3.85)]:
        f_probe = G_l * L / (h * S_n) * dy_nm * 1e-9
        assert fs.apply([0.0, f_probe, 0.0])[1] == pytest.approx(f_printed, abs=5e-3)
        assert np.degrees(dy_nm * 1e-9 / h) == pytest.approx(theta_deg, abs=5e-3)


def test_seed003_per_axis_force_scaling():
    fs = ForceScaling((25e6, 2e6, 25e6))  # A_f^x, A_f^y (Fig. 5 and 6)
    out = fs.apply([1.7e-6, 1e-6, 0.0])  # 1.7 uN at point E (section V-A)
    np.testing.assert_allclose(out, [42.5, 2.0, 0.0])
    np.testing.assert_allclose(fs.inverse(out), [1.7e-6, 1e-6, 0.0])
    nan_out = fs.apply([np.nan, 0.0, 0.0])
    assert np.isnan(nan_out[0]) and fs.flags & NONFINITE  # flagged; the safety layer zeroes it


def test_clutch_recentres_the_master_without_moving_the_probe():
    s = PositionScaling(1e-5, probe_origin=(1e-6, 0, 0))
    p0 = s.map([0.0, 0.0, 0.0])
    np.testing.assert_allclose(p0, [1e-6, 0, 0])
    p1 = s.map([0.05, 0.0, 0.0])
    np.testing.assert_allclose(p1, [1e-6 + 5e-7, 0, 0])
    # hold the clutch and bring the stylus back to the centre: the probe stays
    for x in np.linspace(0.05, -0.02, 20):
        p = s.map([x, 0.01, 0.0], buttons=BUTTON_1)
        np.testing.assert_array_equal(p, p1)
        assert s.flags & CLUTCHED
    # released at x = -0.02: moving on from there continues from where the probe stopped
    p2 = s.map([-0.02, 0.01, 0.0])
    np.testing.assert_allclose(p2, p1, rtol=0, atol=1e-18)
    p3 = s.map([0.03, 0.01, 0.0])
    np.testing.assert_allclose(p3, p1 + [5e-7, 0, 0], rtol=1e-12)
    # [Bolopion]: 40 um of probe travel needs indexing with a 35 cm master (A_d = 50e3)
    s = PositionScaling(1 / 50e3, master_origin=(-0.125, 0, 0))  # probe at 0 with the stylus at -125 mm
    for _ in range(8):  # 8 strokes of 25 cm, clutching back in between
        for xm in np.linspace(-0.125, 0.125, 11):
            p = s.map([xm, 0, 0])
        s.map([0.125, 0, 0], buttons=BUTTON_1)
        s.map([-0.125, 0, 0], buttons=BUTTON_1)
    assert p[0] == pytest.approx(8 * 0.25 / 50e3)  # 40 um


@settings(max_examples=100, deadline=None)
@given(
    path=st.lists(st.tuples(st.floats(-0.1, 0.1), st.floats(-0.1, 0.1), st.floats(-0.1, 0.1),
                            st.sampled_from([0, BUTTON_1, BUTTON_2])), min_size=1, max_size=40),
    scale=st.floats(1e-7, 1e-3),
)
def test_property_the_probe_only_moves_with_the_clutch_released(path, scale):
    s = PositionScaling(scale)
    prev_p, prev_x, prev_free = s.map([0.0, 0.0, 0.0]), np.zeros(3), True
    for x, y, z, b in path:
        xm = np.array([x, y, z])
        p = s.map(xm, buttons=b)
        if b & BUTTON_1:
            np.testing.assert_array_equal(p, prev_p)  # clutched: frozen
        elif prev_free:
            np.testing.assert_allclose(p - prev_p, scale * (xm - prev_x), rtol=1e-9, atol=1e-18)
        else:
            np.testing.assert_array_equal(p, prev_p)  # the release tick re-anchors: no jump
        prev_p, prev_x, prev_free = p, xm, not (b & BUTTON_1)


def test_limits_and_workspace_flags():
    s = PositionScaling(1e-5, probe_limits=((-1e-6, -1e-6, 0.0), (1e-6, 1e-6, 2e-6)), workspace=TOUCH_X.workspace)
    p = s.map([0.5, 0.0, 0.0])
    assert p[0] == 1e-6 and s.flags & CLAMPED and s.flags & MASTER_OUTSIDE
    p = s.map([0.0, 0.0, -0.01])
    assert p[2] == 0.0 and s.flags & CLAMPED and not s.flags & MASTER_OUTSIDE
    p = s.map([0.05, 0.0, 0.05])  # x = 50 mm is inside the 120 mm box centred on 0
    np.testing.assert_allclose(p, [5e-7, 0.0, 5e-7])
    assert s.flags == 0
    # the map is reversible inside the limits
    np.testing.assert_allclose(s.to_master(p), [0.05, 0.0, 0.05], rtol=1e-12)


def test_nonfinite_master_keeps_the_last_probe_position():
    s = PositionScaling(1e-5)
    p = s.map([0.01, 0.0, 0.0])
    q = s.map([np.nan, 0.0, 0.0])
    np.testing.assert_array_equal(p, q)
    assert s.flags == NONFINITE


def test_bad_settings_are_refused():
    with pytest.raises(HapticsError, match="scale must be non-zero"):
        PositionScaling(0.0)
    with pytest.raises(HapticsError, match="scale must be finite"):
        PositionScaling(np.nan)
    with pytest.raises(HapticsError, match="lower must be below upper"):
        PositionScaling(1e-5, probe_limits=((1, 0, 0), (0, 1, 1)))
    with pytest.raises(HapticsError, match="ranges must be positive"):
        PositionScaling.from_ranges(-5e-6, 0.12)
    with pytest.raises(HapticsError, match="force gain must be positive"):
        ForceScaling(-15e6)
    with pytest.raises(HapticsError, match="3-vector"):
        ForceScaling([1.0, 2.0])
    with pytest.raises(HapticsError, match=r"force must have shape \(3,\)"):
        ForceScaling(1.0).apply([1.0])
