"""Every real scan of ../shared/scans-real fits: the spline interpolates the (levelled) pixels."""
import numpy as np
import pytest

from arsurf.scan.inpaint import dropout_mask, inpaint
from arsurf.scan.io import load_scan
from arsurf.scan.level import level
from arsurf.spline.fit import fit_surface
from tests.support.real_scans import real_scan_path

REAL = [
    "2024-10-24_104052_PH_wg_wv_No3_15slits_pol45deg_anal90deg_fine.gwy",
    "2024-08-21_132732_PH_pmma_wedge_on_gold_thick_1600nm_Z_raw.gsf",
    "2018-02-09_1506_PH_dt20nmwindow1_Z_C.gsf",
    "2022-04-28_1518_PH_trivial_dose1,1_FB_horizontal_interf_synchronize_nanoFTIR_Z.gsf",
    "STM_nanonis_generic_4_5.sxm",
    "AR_20211011.ibw",
    "sample_0.jpk",
    "Veeco_20160622.003",
    "Park_20210916_034.tiff",
]


@pytest.mark.realscan
@pytest.mark.parametrize("name", REAL)
def test_real_scan_fits_and_interpolates(name):
    scan = load_scan(real_scan_path(name))
    if scan.nan_count or name.startswith("2022-04-28"):
        scan = inpaint(scan, mask=dropout_mask(scan))
    scan = level(scan, "plane")
    s = fit_surface(scan)
    ny, nx = scan.shape
    assert s.shape == (nx + 2, ny + 2)
    xx, yy = np.meshgrid(scan.x, scan.y)
    S = s.evaluate(xx, yy)
    zr = np.ptp(scan.heights)
    assert np.abs(S[..., 2] - scan.heights).max() <= 1e-10 * zr  # interpolation to rounding
    np.testing.assert_allclose(S[..., 0], xx, rtol=0, atol=1e-14 * nx * scan.dx)
    # between the pixels the spline stays within a modest overshoot of the data range
    u = (np.arange(nx - 1) + 0.5) * scan.dx
    v = (np.arange(ny - 1) + 0.5) * scan.dy
    mid = s.evaluate(*np.meshgrid(u, v))[..., 2]
    assert mid.min() > scan.heights.min() - zr and mid.max() < scan.heights.max() + zr
