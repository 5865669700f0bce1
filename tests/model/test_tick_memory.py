"""The compiled model tick allocates nothing and leaves no reference behind (docs/kernels.rst,
"Reference counts"): a slide across valleys narrower than the tip (the contacts found and
discovered again as the tip moves), with a material map, with the energy of the whole tip (with
and without a map); each with the virtual coupling, which may run a tick again in steps."""
from __future__ import annotations

import numpy as np
import pytest
from numba import njit
from numba.core.runtime import _nrt_python, rtsys

from arsurf.contact.material_map import build_material_map
from arsurf.contact.material_conversion import MaterialConversion
from arsurf.model import M_IN_CONTACT, SIGNALS_SYNTHESISED, ARModel, model_tick_kernel
from arsurf.scan.scan import Scan
from arsurf.spline.fit import fit_surface
from tests.support.valleys import LEVER, R, height_for, valley_model


@njit
def _ticks(a, probes, out):
    """The model tick at each probe in one compiled call; returns the ticks in contact."""
    touching = 0
    for k in range(probes.shape[0]):
        model_tick_kernel(a[0], a[1], a[2], a[3], a[4], a[5], a[6], a[7], a[8], a[9], a[10], a[11],
                          probes[k, 0], probes[k, 1], probes[k, 2], 1e-6, -1e-6, SIGNALS_SYNTHESISED,
                          a[12], a[13], a[14], a[15], out)
        touching += out[M_IN_CONTACT] > 0.5
    return touching


def _valley_slide(n=400):
    z = height_for("sinusoid", 33e-9, depth=0.6e-9)
    x = np.linspace(15e-9, 51e-9, n)  # three valleys, 0.09 nm a tick
    return np.column_stack([x, np.full(n, 24e-9), np.full(n, z)])


def _mapped_model(zone_energy=False):
    """A flat 128 nm square whose modulus steps 2 -> 20 GPa at x = 64 nm (the map's own law)."""
    n, h = 64, 2e-9
    x = np.arange(n) * h
    es = np.where(x < 64e-9, 2e9, 20e9) * np.ones((n, 1))
    chan = lambda v, name, unit: Scan(np.asarray(v, float), h, h, name, {"z_unit": unit})  # noqa: E731
    m = build_material_map(Scan(np.zeros((n, n)), h, h), {"modulus": chan(es, "DMTModulus", "Pa"),
                                                          "adhesion": chan(np.full((n, n), 3e-9), "Adhesion", "N")},
                           MaterialConversion(R))
    return ARModel(fit_surface(Scan(np.zeros((n, n)), h, h)), R, m.contact_law(), LEVER, material=m,
                   coupling_stiffness=3.0, zone_energy=zone_energy)


def _mapped_slide(n=400):
    x = np.linspace(40e-9, 90e-9, n)
    return np.column_stack([x, np.full(n, 60e-9), np.full(n, R - 1e-9)])


def _closed_form_model():
    """A wave 4 nm peak to peak, 60 nm long, under the zone energy in closed form (the one term on its slopes)."""
    from arsurf.contact.maugis_dugdale import MaugisDugdale
    from arsurf.scan import synthetic

    wave = fit_surface(synthetic.sinusoid(shape=(96, 96), pixel=1e-9, amplitude=2e-9, period=60e-9, angle=0.6))
    return ARModel(wave, R, MaugisDugdale(R, 50e9, 0.05), LEVER, coupling_stiffness=3.0, zone_energy=True,
                   zone_closed_form=True)


def _wave_slide(n=400):
    x = np.linspace(30e-9, 60e-9, n)
    return np.column_stack([x, np.full(n, 48e-9), np.full(n, R + 0.5e-9)])


CASES = {
    "valleys": (lambda: valley_model("sinusoid", coupling=5.0), _valley_slide),
    "material map": (_mapped_model, _mapped_slide),
    "zone energy": (lambda: valley_model("sinusoid", coupling=5.0, zone_energy=True), _valley_slide),
    "zone energy with a material map": (lambda: _mapped_model(zone_energy=True), _mapped_slide),
    "zone energy in closed form": (_closed_form_model, _wave_slide),
}


def _stats():
    s = rtsys.get_allocation_stats()
    return np.array([s.alloc, s.free, s.mi_alloc, s.mi_free])


@pytest.mark.parametrize("case", list(CASES))
def test_the_compiled_tick_allocates_nothing_and_leaves_no_reference(case):
    make, slide = CASES[case]
    model = make()
    probes = slide()
    out = np.empty_like(model.out)
    enabled = _nrt_python.memsys_stats_enabled()
    _nrt_python.memsys_enable_stats()
    try:
        _ticks(model.kernel_args(), probes[:1], out)  # compiled, and the first tick's set-up done
        s0 = _stats()
        _ticks(model.kernel_args(), probes[1:2], out)
        s1 = _stats()
        touching = _ticks(model.kernel_args(), probes[2:], out)
        s2 = _stats()
    finally:
        if not enabled:
            _nrt_python.memsys_disable_stats()
    assert touching > 0.5 * (probes.shape[0] - 2)  # the slide presses on the surface
    one, many = s1 - s0, s2 - s1
    # 398 ticks allocate exactly what one does (the call's own arguments): nothing per tick
    np.testing.assert_array_equal(many, one)
    # and whatever a call takes it gives back: the blocks and the references on them
    assert many[0] == many[1] and many[2] == many[3]
