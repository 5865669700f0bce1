"""Named layouts of the flat float64 vectors the compiled kernels write.

A kernel writes its results into one preallocated vector (no allocation per tick); a
:class:`Layout` names the fields once, so kernels take plain integer offsets and Python code reads
fields by name instead of slicing with magic numbers.

Examples
--------
>>> import numpy as np
>>> OUT = Layout("example", [("point", 3), ("depth", 1)])
>>> OUT.size, OUT.offset("depth")
(4, 3)
>>> v = np.arange(4.0)
>>> OUT.get(v, "point").tolist(), OUT.get(v, "depth")
([0.0, 1.0, 2.0], 3.0)
"""
from __future__ import annotations

import numpy as np

__all__ = ["Layout"]


class Layout:
    """Fields of a flat vector, in order: ``[(name, width), ...]`` (width 1: a scalar)."""

    def __init__(self, name: str, fields: list[tuple[str, int]]):
        self.name = name
        self._offset: dict[str, int] = {}
        self._width: dict[str, int] = {}
        pos = 0
        for field, width in fields:
            if field in self._offset or width < 1:
                raise ValueError(f"layout {name}: field {field!r} repeated or of width {width}")
            self._offset[field] = pos
            self._width[field] = width
            pos += width
        self.size = pos

    @property
    def fields(self) -> tuple[str, ...]:
        return tuple(self._offset)

    def offset(self, field: str) -> int:
        """Index of the field's first element (an int a kernel can use as a constant)."""
        return self._offset[field]

    def slice(self, field: str) -> slice:
        start = self._offset[field]
        return slice(start, start + self._width[field])

    def get(self, vector: np.ndarray, field: str):
        """The field of ``vector``: a view for a vector field, a float for a scalar."""
        if self._width[field] == 1:
            return float(vector[self._offset[field]])
        return vector[self.slice(field)]

    def record(self, vector: np.ndarray) -> dict:
        """Every field of ``vector`` as copies (floats for scalars)."""
        return {f: (self.get(vector, f) if self._width[f] == 1 else self.get(vector, f).copy()) for f in self._offset}

    def __repr__(self) -> str:
        return f"Layout({self.name!r}, {[(f, self._width[f]) for f in self._offset]})"
