"""Sessions record the material map (channels, conversion, hash) and replay rebuilds it exactly."""
from __future__ import annotations

import json

import numpy as np
import pytest

from arsurf.assembly import build_model, check_metadata, session_metadata
from arsurf.contact.material_conversion import MaterialConversion
from tests.conftest import write_qnm_npz
from arsurf.contact.material_map import material_map_from_file
from arsurf.errors import SessionError
from arsurf.force.cantilever import Cantilever
from arsurf.replay.replay import replay
from arsurf.sessions.schema import contact_fields
from arsurf.sessions.writer import SessionWriter
from arsurf.scan.prepare import prepare_scan

R = 20e-9
H = 2e-9
N = 48
LEVER = Cantilever(450e-6, 50e-6, 2.5e-6, 15e-6, 169e9, 0.27)
CHANNELS = {"modulus": "DMTModulus", "adhesion": "Adhesion", "deformation": None, "dissipation": None}
UNITS = {"modulus": "Pa", "adhesion": "N"}


@pytest.fixture(scope="module")
def qnm_file(tmp_path_factory):
    """A QNM-like .npz: a bump, a modulus step (soft left, stiff right) and a sticky stripe; the
    file states the spacing and that heights are in metres, not the mechanical channels' units."""
    d = tmp_path_factory.mktemp("qnm")
    y, x = np.mgrid[0:N, 0:N] * H
    height = 2e-9 * np.exp(-((x - 50e-9) ** 2 + (y - 50e-9) ** 2) / (30e-9) ** 2)
    modulus = np.where(x < 48e-9, 0.5e9, 5e9)
    adhesion = np.where(np.abs(y - 60e-9) < 10e-9, 8e-9, 3e-9)
    return write_qnm_npz(d / "qnm.npz", height, modulus, adhesion, H)


@pytest.fixture(scope="module")
def recorded(qnm_file, tmp_path_factory):
    d = tmp_path_factory.mktemp("session")
    scan = prepare_scan(qnm_file, "Height", "plane", 0.0, True)
    conv = MaterialConversion(R)
    m = material_map_from_file(qnm_file, conv, height=scan, channels=CHANNELS, units=UNITS)
    meta = session_metadata(scan=qnm_file, channel="Height", tip_radius=R, contact=m.contact_law(),
                            cantilever=LEVER, level="plane", material=m)
    setup = build_model(meta)
    model = setup.model
    assert model.material is not None and model.material.sha256 == m.sha256
    assert model.material.processing["sample_poisson_source"] == m.processing["sample_poisson_source"]
    k = np.arange(300)
    x = 20e-9 + 60e-9 * k / 299
    z = np.array([setup.surface.evaluate(xi, 60e-9)[2] for xi in x]) + R - 1.5e-9 * np.sin(np.pi * k / 299)
    loads = []
    with SessionWriter(d / "session.h5", meta) as w:
        for i in k:
            p = np.array([x[i], 60e-9, z[i]])
            tick = model.step(p)
            loads.append(tick.load)
            w.append(t=i * 1e-3, probe_position=p, probe_velocity=np.zeros(3), force=tick.simulated_force,
                     **contact_fields(tick))
    return d, meta, m, np.array(loads)


def test_the_session_records_which_map_was_used(recorded):
    d, meta, m, loads = recorded
    spec = meta["material"]
    assert spec["channels"] == {"modulus": "DMTModulus", "adhesion": "Adhesion"}
    assert spec["units"] == UNITS and spec["path"] is None and spec["sha256"] == m.sha256
    # nu_s was not stated: recorded as such, so a rebuild resolves it as the recording did (and says so)
    assert spec["conversion"]["sample_poisson"] is None and "default" in m.processing["sample_poisson_source"]
    assert MaterialConversion.from_metadata(spec["conversion"]).with_sample_poisson(None)[0] == m.conversion
    assert np.ptp(loads) > 0


def test_replay_rebuilds_the_map_and_the_contacts_exactly(recorded, qnm_file):
    d, meta, m, loads = recorded
    result = replay(d / "session.h5", qnm_file, d / "replay", overwrite=True)
    assert result.contact_mismatches == 0 and result.load_difference == 0.0
    summary = json.loads((d / "replay" / "summary.json").read_text())
    assert summary["material"]["sha256"] == m.sha256


def test_a_different_conversion_or_channel_is_refused_with_both_hashes(recorded, qnm_file):
    d, meta, m, loads = recorded
    other = json.loads(json.dumps(meta))
    other["material"]["conversion"]["sample_poisson"] = 0.25
    with pytest.raises(SessionError, match=f"recorded {m.sha256}"):
        build_model(other)
    other = json.loads(json.dumps(meta))
    other["material"]["channels"]["adhesion"] = "Height"  # a channel in m given as N: the reader's unit check
    with pytest.raises(SessionError, match="states z_unit = 'm'; z_unit='N'"):
        build_model(other)


@pytest.mark.parametrize("change, match", [
    ({"channels": {"modulus": "DMTModulus"}}, "modulus and adhesion at least"),
    ({"conversion": {"tip_radius": -1.0}}, "material.conversion is not valid"),
    ({"offset": [0.0]}, "offset must be two finite numbers"),
    ({"sha256": "zz"}, "64 lowercase hex"),
    ({"path": "elsewhere.npz"}, "file_sha256"),
])
def test_invalid_material_metadata_is_refused(recorded, change, match):
    d, meta, m, loads = recorded
    bad = json.loads(json.dumps(meta))
    bad["material"].update(change)
    with pytest.raises(SessionError, match=match):
        check_metadata(bad)
