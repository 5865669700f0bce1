"""Named layouts of the flat float64 vectors the compiled kernels read and write.

A kernel takes its parameters, keeps its state and writes its results in preallocated float64
vectors (no allocation per tick). Every such vector is a :class:`Layout`: the fields are named
once, in order, with their widths; the module that owns the kernel turns the offsets it needs into
module-level integer constants (numba folds them into the compiled code), allocates the vector
with :meth:`Layout.zeros`/:meth:`Layout.full`, and Python code reads fields by name. A vector that
carries another's fields first (a parameter vector with extra entries) is :meth:`Layout.extended`.
No kernel vector is sized or indexed by a hand-counted number (``tests/test_layout.py``).

Examples
--------
>>> import numpy as np
>>> OUT = Layout("example", [("point", 3), ("depth", 1)])
>>> OUT.size, OUT.offset("depth")
(4, 3)
>>> v = np.arange(4.0)
>>> OUT.get(v, "point").tolist(), OUT.get(v, "depth")
([0.0, 1.0, 2.0], 3.0)
>>> OUT.extended("example with weight", [("weight", 1)]).offset("weight")
4
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

    def items(self) -> list[tuple[str, int]]:
        """The fields and their widths, in order (what the layout was built from)."""
        return [(f, self._width[f]) for f in self._offset]

    def width(self, field: str) -> int:
        return self._width[field]

    def extended(self, name: str, fields: list[tuple[str, int]]) -> "Layout":
        """This layout's fields followed by ``fields``: a vector a kernel of this layout also reads."""
        return Layout(name, self.items() + list(fields))

    def zeros(self) -> np.ndarray:
        """A new vector of this layout, zeros."""
        return np.zeros(self.size)

    def full(self, value: float) -> np.ndarray:
        """A new vector of this layout, every element ``value``."""
        return np.full(self.size, value, dtype=np.float64)

    def pack(self, values: dict) -> np.ndarray:
        """A new vector with every field's value (a scalar, or a sequence of the field's width).

        Examples
        --------
        >>> Layout("pair", [("a", 1), ("b", 2)]).pack({"b": (2.0, 3.0), "a": 1.0}).tolist()
        [1.0, 2.0, 3.0]
        """
        if set(values) != set(self._offset):
            raise ValueError(f"layout {self.name}: values for {sorted(values)}, fields are {sorted(self._offset)}")
        v = np.empty(self.size)
        for field, value in values.items():
            v[self.slice(field)] = value
        return v

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
        return f"Layout({self.name!r}, {self.items()})"
