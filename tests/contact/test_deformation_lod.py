"""The read of the dented net visits only the tiles the dent reaches (issue 28), and gives the
reference full dent (:func:`sync_dent_kernel`, every point of the guard box) bit for bit."""
import numpy as np
import pytest

from arsurf.contact.deformation import (DENT_SIZE, PROFILE_SIZE, TILE, Deformer, record_dent_kernel,
                                        sync_dent_kernel)
from arsurf.scan.synthetic import rough
from arsurf.spline.fit import fit_surface
from arsurf.spline.surface import BSplineSurface


def _reference(s, n):
    """A copy of the rest net with the reference kernel's state (n contacts)."""
    ctrl, rest, ku, kv = s.raw_arrays()
    return rest.copy(), np.zeros(PROFILE_SIZE * n), np.zeros(4 * n, dtype=np.int64)


def _dents(s, tip):
    """A sequence of (contact, centre, normal, a, depth, c) on ``s``: a slide over the highest
    inner point, a tilted adhesive contact, a contact wider than 0.9 R, a jump far away, a second
    contact overlapping the first, releases (R = 0)."""
    rest = s.rest_control_points
    nu, nv = rest.shape[:2]
    inner = rest[nu // 4:-nu // 4, nv // 4:-nv // 4]
    i, j = np.unravel_index(np.argmax(inner[..., 2]), inner.shape[:2])
    x, y, z = inner[i, j]
    h = s.spacing[0]
    a = min(0.3 * tip, 8 * h + 0.1 * tip)
    up = (0.0, 0.0, 1.0)
    tilt = np.array([0.3, -0.2, 1.0]) / np.linalg.norm([0.3, -0.2, 1.0])
    seq = []
    for k in range(6):   # a slide, a fraction of a pixel per read
        seq.append((0, (x + 0.37 * h * k, y + 0.11 * h * k, z + tip - 0.3 * a * a / tip), up, a, a * a / tip, a))
    seq.append((0, (x, y, z + tip - 0.5e-9), tilt, a, a * a / tip - 0.3e-9, 1.6 * a))      # tilted, adhesive
    seq.append((0, (x + 3 * h, y, z + tip - 0.95 * tip), up, 0.95 * tip, 0.9 * tip, tip))  # a > 0.9 R
    far = rest[nu // 5, 4 * nv // 5]
    seq.append((0, (far[0], far[1], far[2] + tip - 0.2e-9), up, a, a * a / tip, a))       # a jump away
    seq.append((1, (far[0] + 2 * a, far[1], far[2] + tip - 0.2e-9), tilt, 0.7 * a, 0.49 * a * a / tip, 0.7 * a))
    seq.append((0, (x, y, z + tip - 0.3e-9), up, 0.0, 0.0, 0.0))                            # no contact zone
    seq.append((1, None, None, 0.0, 0.0, 0.0))                                              # release contact 1
    seq.append((0, None, None, 0.0, 0.0, 0.0))                                              # release all
    return seq


@pytest.mark.parametrize("pitch_nm", [0.1, 0.5, 2.0])
@pytest.mark.parametrize("tip_nm", [2.0, 20.0, 50.0])
def test_the_tiled_read_is_the_reference_full_dent_bit_for_bit(pitch_nm, tip_nm):
    """On rough nets (0.5 nm rms) at 0.1-2 nm pitch under 2-50 nm tips, through slides, a tilted
    adhesive contact, a contact wider than 0.9 R, jumps, a second contact and releases, the net
    a read gives (the tiled sync) equals the reference sync of every guard-box point, bitwise,
    with the same count of dented points: the tiles it skips hold no point the dent moves."""
    pitch, tip = pitch_nm * 1e-9, tip_nm * 1e-9
    s = fit_surface(rough((72, 72), pitch, rms=0.5e-9, correlation_length=min(max(6e-9, 3 * pitch), 16 * pitch),
                          seed=5))
    d = Deformer(s, contacts=2)
    ref, profile, patch = _reference(s, 2)
    _, rest, ku, kv = s.raw_arrays()
    record = np.zeros(2 * DENT_SIZE)
    fewer = False   # a read that wrote fewer points than the guard boxes hold
    for k, c, n, a, depth, zone in _dents(s, tip):
        if c is None:
            d.release(contact=k)
            record_dent_kernel(record[k * DENT_SIZE:(k + 1) * DENT_SIZE], ku, kv, 0, 0, 0, 0.0, 0, 0, 1, 0, 0, 0)
            moved = d.sync()
        else:
            moved = d.apply(c, tip, n, a, depth=depth, zone_radius=zone, contact=k).moved
            record_dent_kernel(record[k * DENT_SIZE:(k + 1) * DENT_SIZE], ku, kv, *c, tip, *n, a, depth, zone)
        expect = sync_dent_kernel(ref, rest, ku, kv, record, profile, patch)
        assert np.array_equal(s.control_points, ref)
        assert moved in (expect, -1)
        fewer |= _area(d.written.reshape(-1, 4)[2:]) < _area(patch.reshape(-1, 4))
    assert np.array_equal(s.control_points, s.rest_control_points)
    if tip_nm >= 20.0 and pitch_nm <= 0.5:
        assert fewer   # the guard box out to R was not all visited


def _area(boxes):
    return int(sum(max(b[1] - b[0], 0) * max(b[3] - b[2], 0) for b in boxes))


def test_the_read_writes_the_dents_reach_not_the_guard_box():
    """A 50 nm tip pressed 0.2 nm into a flat 0.25 nm net (a ~ 3 nm): the guard box reaches out
    to R = 50 nm (400 points a side), the tiles written only out to 3a and the tip's ball where
    it cuts the net (the sphere at rest height: sqrt(2 R 0.2 nm) ~ 4.5 nm), each widened by one
    tile; everything outside them is at rest."""
    h, n = 0.25e-9, 480
    s = BSplineSurface.from_heights(np.zeros((n, n)), (0.0, (n - 3) * h), (0.0, (n - 3) * h))
    R, a = 50e-9, 3e-9
    c = np.array([60e-9, 60e-9, R - 0.2e-9])
    res = Deformer(s).apply(c, R, (0, 0, 1), a, depth=a * a / R, zone_radius=a)
    i0, i1, j0, j1 = res.patch
    assert i1 - i0 > 380 and j1 - j0 > 380                  # the guard box: out to R
    (w,) = [b for b in s._dents[0].written.reshape(-1, 4) if b[1] > b[0]]
    reach = 3 * a + 1.5 * TILE * h                           # 3a plus a tile's half-diagonal
    assert (w[1] - w[0]) * h <= 2 * reach + 2 * TILE * h and (w[3] - w[2]) * h <= 2 * reach + 2 * TILE * h
    moved = np.any(s.control_points != s.rest_control_points, axis=-1)
    outside = np.ones((n, n), bool)
    outside[w[0]:w[1], w[2]:w[3]] = False
    assert moved.sum() > 1000 and not moved[outside].any()
