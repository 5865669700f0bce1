"""The zone energy as the model's contact from a session's metadata and the command line: recorded
only when on, rebuilt by build_model (so a replay runs the same contact), refused in one line when
it is not a boolean."""
from __future__ import annotations

import pytest

from arsurf.assembly import BUNDLED_SCAN, build_model, preset_metadata
from arsurf.cli.args import _contact_flag
from arsurf.errors import SessionError


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


def test_the_command_line_flag_is_off_unless_given():
    import argparse

    p = argparse.ArgumentParser()
    _contact_flag(p)
    assert p.parse_args([]).zone_energy is False and p.parse_args(["--zone-energy"]).zone_energy is True
