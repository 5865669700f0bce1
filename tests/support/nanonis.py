"""The virtual AFM the Nanonis tests put behind the simulated controller: a flat sample, the tip
0.3 um above it at (X0, Y0), a quiet photodiode (1e-4 peak to peak). Metres."""
from __future__ import annotations

from arsurf.instrument.instrument import PhotodiodeNoise, VirtualAFM

X0, Y0 = 5e-6, 5e-6
QUIET = PhotodiodeNoise(peak_to_peak=1e-4)


def quiet_afm(**kw) -> VirtualAFM:
    """A :class:`~arsurf.instrument.instrument.VirtualAFM` on a flat sample; ``kw`` override the defaults."""
    kw = {"probe_height": 0.3e-6, "tip_xy": (X0, Y0), "noise": QUIET, "keep_history": False, **kw}
    return VirtualAFM(0.0, **kw)
