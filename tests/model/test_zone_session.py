"""The zone energy as the model's contact from a session's metadata and the command line: recorded
only when on, with whether it was taken in closed form, rebuilt by build_model (so a replay runs the
same contact; a session recorded before the closed form's key, with the lattice's sum it ran with),
refused in one line when it is not a boolean."""
from __future__ import annotations

import pytest

from arsurf.assembly import BUNDLED_SCAN, build_model, preset_metadata
from arsurf.cli.args import _contact_flag, _contact_options
from arsurf.contact.zone_energy import L_JOIN
from arsurf.errors import ContactError, SessionError


def test_the_session_records_and_rebuilds_the_zone_energy():
    scan = BUNDLED_SCAN
    plain = preset_metadata(scan, "demo")
    assert "zone_energy" not in plain and build_model(plain).model.zone_energy is False
    meta = preset_metadata(scan, "demo", zone_energy=True)
    assert meta["zone_energy"] is True
    model = build_model(meta).model
    assert model.zone_energy and model.zone_lattice is not None
    with pytest.raises(SessionError, match="zone_energy"):
        build_model({**meta, "zone_energy": "yes"})


def _closed(model) -> bool:
    """Whether the model's zone energy takes its closed form where trusted (its lattice's join flag)."""
    return bool(model.zone_lattice.arrays[L_JOIN][0])


def test_the_session_records_whether_the_zone_energy_was_in_closed_form():
    scan = BUNDLED_SCAN
    meta = preset_metadata(scan, "demo", zone_energy=True)
    assert meta["zone_closed_form"] is True and _closed(build_model(meta).model)  # the default
    summed = preset_metadata(scan, "demo", zone_energy=True, zone_closed_form=False)
    assert summed["zone_closed_form"] is False and not _closed(build_model(summed).model)
    before = {k: v for k, v in meta.items() if k != "zone_closed_form"}  # recorded before the key existed
    assert not _closed(build_model(before).model)  # the sum it ran with
    with pytest.raises(SessionError, match="zone_closed_form"):
        build_model({**meta, "zone_closed_form": 1})


def test_the_command_line_flag_is_off_unless_given():
    import argparse

    p = argparse.ArgumentParser()
    _contact_flag(p)
    assert p.parse_args([]).zone_energy is False and p.parse_args(["--zone-energy"]).zone_energy is True
    assert _contact_options(p.parse_args(["--zone-energy"])) == {"zone_energy": True, "zone_closed_form": True}
    assert _contact_options(p.parse_args(["--zone-energy", "--zone-sum"]))["zone_closed_form"] is False
    with pytest.raises(ContactError, match="--zone-sum .* give --zone-energy too"):
        _contact_options(p.parse_args(["--zone-sum"]))
