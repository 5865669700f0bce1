"""The :class:`Scan` record: one height channel of an AFM image, in SI units.

Convention (docs/design.rst, "Units and conventions"): ``heights[iy, ix]`` float64 metres, x grows with the column
index ix, y with the row index iy; ``dx``, ``dy`` are the pixel spacings (centre to centre) in metres.
Pixel (ix, iy) sits at x = ix*dx, y = iy*dy: the origin is the centre of the first pixel.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from arsurf.errors import InvalidHeights


@dataclass(frozen=True, eq=False)
class Scan:
    """A height map in metres with its pixel spacing.

    Parameters
    ----------
    heights : (ny, nx) float64, metres
        Height of pixel (iy, ix). NaN marks a missing pixel (see :func:`arsurf.inpaint`).
    dx, dy : float, metres
        Pixel spacing along x (columns) and y (rows); non-square pixels are allowed.
    channel : str
        Name of the channel as the file calls it (e.g. ``"Height"``, ``"Z raw"``).
    metadata : dict
        Everything else: instrument, format, and the processing history under ``"history"``.
    source : str
        Where the data came from (a path, or ``"synthetic:<name>"``).

    Examples
    --------
    >>> import numpy as np
    >>> s = Scan(np.zeros((4, 5)), dx=1e-9, dy=2e-9)
    >>> s.shape, [round(x * 1e9, 9) for x in s.size]      # first to last pixel centre, nm
    ((4, 5), [4.0, 6.0])
    >>> [round(x * 1e9, 9) for x in s.extent]              # scan size: pixels x spacing, nm
    [5.0, 8.0]
    """

    heights: np.ndarray
    dx: float
    dy: float
    channel: str = "Height"
    metadata: dict[str, Any] = field(default_factory=dict)
    source: str = ""

    def __post_init__(self) -> None:
        h = np.array(self.heights, dtype=np.float64, copy=True, order="C")
        if h.ndim != 2:
            raise InvalidHeights(
                f"heights must be a 2-D array (ny, nx) (got shape {h.shape}) in {self.source or 'scan'}"
            )
        if h.shape[0] < 1 or h.shape[1] < 1:
            raise InvalidHeights(f"heights is empty (shape {h.shape}) in {self.source or 'scan'}")
        if np.isinf(h).any():
            raise InvalidHeights(
                f"heights has {int(np.isinf(h).sum())} infinite pixels in {self.source or 'scan'}; "
                "replace them with NaN and use arsurf.inpaint(), or crop them away"
            )
        for name in ("dx", "dy"):
            value = float(getattr(self, name))
            if not (math.isfinite(value) and value > 0.0):
                raise InvalidHeights(
                    f"{name} must be a positive, finite pixel spacing in metres (got {value!r}) "
                    f"in {self.source or 'scan'}"
                )
            object.__setattr__(self, name, value)
        h.setflags(write=False)
        object.__setattr__(self, "heights", h)
        object.__setattr__(self, "metadata", dict(self.metadata))

    @property
    def shape(self) -> tuple[int, int]:
        """(ny, nx) pixels."""
        return self.heights.shape  # type: ignore[return-value]

    @property
    def size(self) -> tuple[float, float]:
        """Extent (x, y) in metres from the centre of the first pixel to the centre of the last,
        ``((nx - 1) dx, (ny - 1) dy)``: the domain of the fitted surface. Not the scan size that
        instruments state as nx pixels of width dx: that is :attr:`extent`."""
        ny, nx = self.shape
        return ((nx - 1) * self.dx, (ny - 1) * self.dy)

    @property
    def extent(self) -> tuple[float, float]:
        """Scan size (x, y) in metres as pixels times spacing, ``(nx dx, ny dy)`` (Gwyddion's
        ``xreal``, what most instruments call the scan size; Asylum's ``ScanSize`` is :attr:`size`)."""
        ny, nx = self.shape
        return (nx * self.dx, ny * self.dy)

    @property
    def x(self) -> np.ndarray:
        """(nx,) x coordinate of each column, metres."""
        return np.arange(self.shape[1]) * self.dx

    @property
    def y(self) -> np.ndarray:
        """(ny,) y coordinate of each row, metres."""
        return np.arange(self.shape[0]) * self.dy

    @property
    def nan_count(self) -> int:
        """Number of missing (NaN) pixels."""
        return int(np.isnan(self.heights).sum())

    @property
    def history(self) -> list:
        """Processing steps applied so far (levelling, smoothing, inpainting...)."""
        return list(self.metadata.get("history", []))

    def as_height(self) -> "Scan":
        """This scan marked as topography by the caller's decision (``metadata["height"] = True``,
        recorded in the history), for a channel in metres that its file names as another
        quantity (e.g. an Amplitude channel used as a height on purpose).

        Raises
        ------
        InvalidHeights
            The channel is not in metres (V, A, Pa...): no decision makes it a height.
        """
        unit = self.metadata.get("z_unit")
        if unit not in (None, "m"):
            raise InvalidHeights(f"channel {self.channel!r} of {self.source or 'scan'} is in {unit!r}, not metres: "
                                 "it cannot be used as a height")
        marked = replace(self, metadata={**self.metadata, "height": True})
        return marked.with_heights(self.heights, step={"operation": "as_height", "channel": self.channel})

    def with_heights(self, heights: np.ndarray, step: dict | None = None, **changes) -> "Scan":
        """A new Scan with other heights (same spacing), appending ``step`` to the history."""
        meta = dict(self.metadata)
        if step is not None:
            meta["history"] = [*self.metadata.get("history", []), step]
        return replace(self, heights=heights, metadata=meta, **changes)

    # -- notebook display (IPython) ----------------------------------------------------------
    def _display_rows(self) -> list[tuple[str, str]]:
        from arsurf._display import quantity

        ny, nx = self.shape
        unit = str(self.metadata.get("z_unit") or "m")
        finite = self.heights[np.isfinite(self.heights)]
        rows = [("channel", f"{self.channel} ({unit})"), ("pixels", f"{nx} x {ny} px"),
                ("pixel size", f"{quantity(self.dx, 'm')} x {quantity(self.dy, 'm')}"),
                ("scan size", f"{quantity(nx * self.dx, 'm')} x {quantity(ny * self.dy, 'm')}"),
                ("z range", quantity(float(np.ptp(finite)) if finite.size else math.nan, unit)),
                ("z min / max", f"{quantity(finite.min() if finite.size else math.nan, unit)} / "
                                f"{quantity(finite.max() if finite.size else math.nan, unit)}"),
                ("missing pixels", f"{self.nan_count} (NaN)")]
        if self.metadata.get("format"):
            rows.append(("format", str(self.metadata["format"])))
        if self.history:
            rows.append(("processing", " -> ".join(map(_step_text, self.history))))
        if self.source:
            rows.append(("source", self.source))
        return rows

    def _repr_png_(self) -> bytes:
        """A thumbnail of the map (IPython): axes and colour bar in units, robust colour limits."""
        from arsurf._display import map_png

        ny, nx = self.shape
        return map_png(self.heights, (0.0, (nx - 1) * self.dx, 0.0, (ny - 1) * self.dy),
                       str(self.metadata.get("z_unit") or "m"), self.channel or "z")

    def _repr_html_(self) -> str:
        """Channel, pixels, pixel and scan size, z range with units, and the thumbnail (IPython)."""
        from arsurf._display import card

        return card("Scan", self._display_rows(), self._repr_png_())

    def __repr__(self) -> str:
        ny, nx = self.shape
        finite = self.heights[np.isfinite(self.heights)]
        zr = (finite.max() - finite.min()) if finite.size else float("nan")
        return (
            f"Scan({self.channel!r}, {nx}x{ny} px, {self.size[0] * 1e9:.4g} x {self.size[1] * 1e9:.4g} nm, "
            f"dx={self.dx * 1e9:.4g} nm, dy={self.dy * 1e9:.4g} nm, z range {zr * 1e9:.4g} nm, "
            f"source={self.source!r})"
        )


def _step_text(step) -> str:
    """One processing step of a history as text: ``level (rows-median)``."""
    if not isinstance(step, dict):
        return str(step)
    name = step.get("operation") or step.get("step") or "?"
    return f"{name} ({step['method']})" if step.get("method") else str(name)
