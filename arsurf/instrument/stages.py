"""Positioning stages of the AFM of [Alabdulmuhsin], moved through LSPB profiles.

Each stage is one axis with a travel range, a resolution (the smallest step it executes: targets
are rounded to the resolution grid) and the velocity and acceleration limits its LSPB moves use.
Ranges and resolutions are those of [Alabdulmuhsin] (Tables 3.1-3.3); velocity and acceleration limits
that the seed does not give are stated as assumptions next to each preset.

Examples
--------
>>> stage = PICOCUBE
>>> stage.quantize(1.23456e-6)       # 0.1 nm grid
1.2346e-06
>>> move = stage.move(0.0, 1e-6)     # Fig. 4.6: a 1000 nm step, smoothed
>>> move.end.tolist()
[1e-06]
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from arsurf.errors import InstrumentError
from arsurf.instrument.lspb import LSPB


@dataclass(frozen=True)
class Stage:
    """One stage axis.

    Parameters
    ----------
    name : str
    travel : float, metres
        Range: positions from 0 to ``travel``.
    resolution : float, metres
        Smallest executable step; targets are rounded to multiples of it.
    max_velocity, max_acceleration : float, m/s and m/s^2
        LSPB limits.
    source : str
        Where the numbers come from.
    """

    name: str
    travel: float
    resolution: float
    max_velocity: float
    max_acceleration: float
    source: str = ""

    def __post_init__(self) -> None:
        for f in ("travel", "resolution", "max_velocity", "max_acceleration"):
            v = float(getattr(self, f))
            if not (math.isfinite(v) and v > 0.0):
                raise InstrumentError(f"{self.name}: {f} must be positive and finite, SI units (got {getattr(self, f)!r})")
            object.__setattr__(self, f, v)
        if self.resolution > self.travel:
            raise InstrumentError(f"{self.name}: resolution {self.resolution!r} m exceeds the travel {self.travel!r} m")

    def quantize(self, position):
        """Nearest position on the resolution grid (metres), float or array."""
        p = np.asarray(position, dtype=np.float64)
        q = np.round(p / self.resolution) * self.resolution
        # express the grid point with the resolution's own digits (1.2346e-06, not 1.2346000000000001e-06)
        digits = max(0, -int(math.floor(math.log10(self.resolution))) + 3)
        q = np.round(q, digits)
        return float(q) if q.ndim == 0 else q

    def check(self, position) -> float:
        """``position`` as a float if it is within the travel, else :class:`InstrumentError`."""
        p = float(position)
        if not math.isfinite(p) or p < -0.5 * self.resolution or p > self.travel + 0.5 * self.resolution:
            raise InstrumentError(
                f"{self.name}: target {p!r} m is outside the travel [0, {self.travel:g}] m; "
                "move another stage (coarse/fine) or re-centre this one"
            )
        return p

    def move(self, start: float, target: float) -> LSPB:
        """LSPB move from ``start`` to ``target`` rounded to the resolution grid (minimum time)."""
        s = self.check(start)
        t = self.quantize(self.check(target))
        return LSPB.plan(s, t, self.max_velocity, self.max_acceleration)


# [Alabdulmuhsin], Table 3.1: PI M-112.1DG, 25 mm travel, 0.05 um resolution, 1.5 mm/s. The acceleration
# is not in the seed: 10 mm/s^2 (assumed; a DC-motor stage reaches 1.5 mm/s in 0.15 s).
MICRO_STAGE = Stage("micro stage (PI M-112.1DG)", travel=25e-3, resolution=0.05e-6, max_velocity=1.5e-3,
                    max_acceleration=10e-3, source="[Alabdulmuhsin] Table 3.1; acceleration assumed")

# [Alabdulmuhsin], Table 3.2: PI P-620.ZCL PIHera Z axis, 50 um travel, 0.2 nm resolution (the XY
# P-621.2CL has 100 um; the text gives 0.4 nm for XY, the table 0.2 nm). Velocity and acceleration
# limits are the LSPB smoothing chosen to spare the piezo (assumed): 100 um/s, 10 mm/s^2.
NANO_STAGE = Stage("nano stage Z (PI P-620.ZCL)", travel=50e-6, resolution=0.2e-9, max_velocity=100e-6,
                   max_acceleration=10e-3, source="[Alabdulmuhsin] Table 3.2; limits assumed")
NANO_STAGE_XY = Stage("nano stage XY (PI P-621.2CL)", travel=100e-6, resolution=0.2e-9, max_velocity=100e-6,
                      max_acceleration=10e-3, source="[Alabdulmuhsin] Table 3.2; limits assumed")

# [Alabdulmuhsin], Table 3.3: PI P-363 PicoCube, 5 um travel, 0.1 nm resolution; limits assumed as for
# the nano stage.
PICOCUBE = Stage("PicoCube (PI P-363)", travel=5e-6, resolution=0.1e-9, max_velocity=100e-6,
                 max_acceleration=10e-3, source="[Alabdulmuhsin] Table 3.3; limits assumed")
