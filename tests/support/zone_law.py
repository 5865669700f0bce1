"""The zone law the closed-form tests share (tests/contact/test_zone_quadric.py, test_zone_join.py): a
10 nm tip, E* 50 GPa, w 0.05 J/m^2 (the Maugis-Dugdale law's Dugdale stress), and its range h0 (m)."""
from __future__ import annotations

from arsurf.contact.maugis_dugdale import MaugisDugdale
from arsurf.contact.zone_law import ZoneLaw

R = 10e-9
LAW = ZoneLaw.from_law(MaugisDugdale(R, 50e9, 0.05))
H0 = LAW.interaction_range
