"""The conventions every picture of arsurf follows, 2D figures (:mod:`arsurf.replay.plots`) and 3D
views (:mod:`arsurf_viewer.view`) alike: heights in the perceptually uniform :data:`HEIGHT_CMAP`,
colour limits at the 1st and 99th percentiles of the data shown (:func:`robust_limits`: one
scratch or speck does not wash the sample out), round colour-bar ticks (:func:`round_ticks`:
1, 2 or 5 x 10^k, never "-0.0") and scale bars of a round length (:func:`scale_bar_length`).

Examples
--------
>>> import numpy as np
>>> robust_limits(np.arange(101.0))
(1.0, 99.0)
>>> round_ticks(-0.04, 2.3)
([0.0, 0.5, 1.0, 1.5, 2.0], ['0.0', '0.5', '1.0', '1.5', '2.0'])
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["HEIGHT_CMAP", "PERCENTILES", "robust_limits", "scale_bar_length", "round_ticks"]

#: perceptually uniform map of heights (2D figures and 3D views)
HEIGHT_CMAP = "magma"
#: robust colour limits: these percentiles of the finite data shown
PERCENTILES = (1.0, 99.0)


def robust_limits(*arrays, percentiles: tuple[float, float] = PERCENTILES) -> tuple[float, float]:
    """Colour limits from the data: the ``percentiles`` of the finite values of all ``arrays``
    together (one pair for panels that are compared). A constant map gets +-1 around its value.

    Examples
    --------
    >>> robust_limits(np.arange(101.0), np.array([np.nan]))
    (1.0, 99.0)
    """
    values = np.concatenate([np.asarray(a, dtype=np.float64).ravel() for a in arrays]) if arrays else np.empty(0)
    values = values[np.isfinite(values)]
    if values.size == 0:
        return -1.0, 1.0
    lo, hi = (float(x) for x in np.percentile(values, percentiles))
    if not hi > lo:
        lo, hi = lo - 1.0, hi + 1.0
    return lo, hi


def _round_step(target: float) -> float:
    """The largest 1, 2 or 5 x 10^k not over ``target`` (> 0)."""
    k = math.floor(math.log10(target))
    best = 10.0 ** k
    for m in (2.0, 5.0, 10.0):
        if m * 10.0 ** k <= target * (1 + 1e-12):
            best = m * 10.0 ** k
    return float(best)


def scale_bar_length(span: float) -> float:
    """The longest 1, 2 or 5 x 10^k not over a quarter of ``span`` (same unit).

    Examples
    --------
    >>> scale_bar_length(1000.0), scale_bar_length(90.0), scale_bar_length(7.0)
    (200.0, 20.0, 1.0)
    """
    from arsurf.errors import FigureError

    span = float(span)
    if not (math.isfinite(span) and span > 0.0):
        raise FigureError(f"a scale bar needs a positive finite span (got {span!r})")
    return _round_step(0.25 * span)


def round_ticks(lo: float, hi: float, most: int = 6) -> tuple[list[float], list[str]]:
    """Colour-bar ticks inside [lo, hi]: the multiples of the smallest step of 1, 2 or 5 x 10^k
    that gives at most ``most`` of them (at least 2), and their labels with the decimals the step
    needs (zero is "0" or "0.0", never "-0.0").

    Examples
    --------
    >>> round_ticks(-12.7, 31.2)
    ([-10.0, 0.0, 10.0, 20.0, 30.0], ['-10', '0', '10', '20', '30'])
    >>> round_ticks(0.013, 0.052)[1]
    ['0.02', '0.03', '0.04', '0.05']
    """
    from arsurf.errors import FigureError

    lo, hi = float(lo), float(hi)
    if not (math.isfinite(lo) and math.isfinite(hi) and hi > lo):
        raise FigureError(f"colour-bar ticks need finite limits lo < hi (got {lo!r}, {hi!r})")
    step = _round_step((hi - lo) / 2.0)  # at least 3 ticks fit (2 steps)
    while True:
        first, last = math.ceil(lo / step - 1e-9), math.floor(hi / step + 1e-9)
        if last - first + 1 <= most:
            break
        step = _round_step(step * 2.01)  # the next round step up
    while True:  # the smallest round step that still gives at most `most` ticks
        smaller = _round_step(step * 0.99)
        f2, l2 = math.ceil(lo / smaller - 1e-9), math.floor(hi / smaller + 1e-9)
        if l2 - f2 + 1 > most:
            break
        step, first, last = smaller, f2, l2
    decimals = max(0, -math.floor(math.log10(step) + 1e-9))
    values = [round(i * step, decimals) + 0.0 for i in range(first, last + 1)]  # + 0.0: no -0.0
    return values, [f"{v:.{decimals}f}" for v in values]
