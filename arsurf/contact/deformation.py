r"""Local deformation of the control net by the tip (seed 002), reversible and O(patch).

Seed 002: "all control points in the area of contact, i.e. which lie within the contact radius
around the central line of contact, are projected onto the sphere representing the tip". With C
the tip centre, R its radius, n the unit contact normal (out of the sample) and a the contact
radius (Maugis-Dugdale), a control point P at rest position P₀ has the axial and radial parts

.. math:: s = (P_0 - C)\cdot n, \qquad \mathbf r = (P_0 - C) - s\,n, \qquad ρ = |\mathbf r|.

It is moved onto the sample-side cap of the tip sphere,

.. math:: P = C + \mathbf r - \sqrt{R^2 - ρ^2}\; n,

when ρ < a (the adhered contact zone: pressed in on approach, held up by adhesion on
retraction - the neck), or when ρ < R and P₀ lies inside the sphere (no interpenetration: this
happens only where a is smaller than the geometric intersection radius, e.g. Hertz, where
a² = Rδ < 2Rδ). Every other control point keeps its rest position **bitwise**.

Only the index box of control points whose rest (x, y) lies within R (+ one knot spacing) of the
tip axis' foot can move: the kernel restores the previous box from the rest net and writes the
new one, so a tick costs O((2R/h)²) whatever the scan size. :meth:`Deformer.release` puts the
box back to rest; ``surface.reset()`` restores everything.

The rest net must be a height-field net on the Greville abscissae (what
:func:`arsurf.fit_surface` builds), so the index box is found in O(1) from the knot spacing.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from arsurf.errors import ContactError
from arsurf.spline.surface import BSplineSurface

# status bits returned by the kernel
DEFORM_OK = 0
DEFORM_NO_PATCH = 1  # the tip is outside the net's footprint: nothing to move


@njit(cache=True, inline="always")
def _index_range(lo, hi, u0, h, n):
    """Control indices whose Greville abscissa may lie in [lo, hi] (one spare each side)."""
    i0 = int(math.floor((lo - u0) / h)) - 1
    i1 = int(math.floor((hi - u0) / h)) + 3
    if i0 < 0:
        i0 = 0
    if i1 > n:
        i1 = n
    return i0, i1


@njit(cache=True)
def deform_kernel(ctrl, rest, ku, kv, cx, cy, cz, radius, nx, ny, nz, contact_radius, patch):
    """Restore ``patch`` (i0, i1, j0, j1) to rest, then dent the new patch; write it to ``patch``.

    Returns the number of control points moved (>= 0). ``contact_radius`` <= 0 only pushes
    points out of the sphere (no adhered zone); a ``radius`` <= 0 releases.
    """
    # 1. restore the previous patch
    for i in range(patch[0], patch[1]):
        for j in range(patch[2], patch[3]):
            for c in range(3):
                ctrl[i, j, c] = rest[i, j, c]
    patch[0] = patch[1] = patch[2] = patch[3] = 0
    if radius <= 0.0:
        return 0
    nu = ctrl.shape[0]
    nv = ctrl.shape[1]
    hu = (ku[nu] - ku[3]) / (nu - 3)
    hv = (kv[nv] - kv[3]) / (nv - 3)
    i0, i1 = _index_range(cx - radius, cx + radius, ku[3], hu, nu)
    j0, j1 = _index_range(cy - radius, cy + radius, kv[3], hv, nv)
    if i0 >= i1 or j0 >= j1:
        return 0
    r2 = radius * radius
    a2 = contact_radius * contact_radius if contact_radius > 0.0 else 0.0
    moved = 0
    for i in range(i0, i1):
        for j in range(j0, j1):
            px = rest[i, j, 0] - cx
            py = rest[i, j, 1] - cy
            pz = rest[i, j, 2] - cz
            s = px * nx + py * ny + pz * nz
            rx = px - s * nx
            ry = py - s * ny
            rz = pz - s * nz
            rho2 = rx * rx + ry * ry + rz * rz
            if rho2 >= r2:
                continue
            inside = px * px + py * py + pz * pz < r2
            if rho2 < a2 or inside:
                cap = -math.sqrt(r2 - rho2)
                ctrl[i, j, 0] = cx + rx + cap * nx
                ctrl[i, j, 1] = cy + ry + cap * ny
                ctrl[i, j, 2] = cz + rz + cap * nz
                moved += 1
    patch[0] = i0
    patch[1] = i1
    patch[2] = j0
    patch[3] = j1
    return moved


@dataclass(frozen=True)
class DeformationResult:
    """What one :meth:`Deformer.apply` did: points moved and the index box touched."""

    moved: int
    patch: tuple[int, int, int, int]


class Deformer:
    """Dents a surface's control net around the tip, one contact at a time, reversibly.

    Parameters
    ----------
    surface : BSplineSurface
        Its rest net must be a height-field net (as :func:`arsurf.fit_surface` makes).

    Examples
    --------
    >>> import numpy as np
    >>> from arsurf.spline.surface import BSplineSurface
    >>> s = BSplineSurface.from_heights(np.zeros((20, 20)), (0, 17e-9), (0, 17e-9))
    >>> d = Deformer(s)
    >>> d.apply(center=(8e-9, 8e-9, 4e-9), radius=5e-9, normal=(0, 0, 1), contact_radius=3e-9).moved > 0
    True
    >>> d.release(); s.is_deformed
    False
    """

    def __init__(self, surface: BSplineSurface):
        if not isinstance(surface, BSplineSurface):
            raise ContactError(f"Deformer needs a BSplineSurface (got {type(surface).__name__})")
        if not surface.is_height_field_net:
            raise ContactError(
                "the surface's rest net is not a height-field net (x must depend on i only and y on j only); "
                "build it with arsurf.fit_surface or BSplineSurface.from_heights"
            )
        self.surface = surface
        self.patch = np.zeros(4, dtype=np.int64)

    def apply(self, center, radius: float, normal, contact_radius: float) -> DeformationResult:
        """Release the previous dent and press the tip sphere (centre, radius) into the net.

        Parameters
        ----------
        center : (3,) float, metres
        radius : float, metres (> 0)
        normal : (3,) float, unit contact normal out of the sample
        contact_radius : float, metres (>= 0; 0 = no adhered zone)
        """
        c = np.asarray(center, dtype=np.float64).reshape(3)
        n = np.asarray(normal, dtype=np.float64).reshape(3)
        radius = float(radius)
        contact_radius = float(contact_radius)
        if not np.isfinite(c).all():
            raise ContactError(f"`center` must be finite (got {c}); it is the tip centre in metres")
        if not (math.isfinite(radius) and radius > 0.0):
            raise ContactError(f"`radius` must be positive (got {radius!r} m); it is the tip radius in metres")
        if not (math.isfinite(contact_radius) and contact_radius >= 0.0):
            raise ContactError(f"`contact_radius` must be >= 0 (got {contact_radius!r} m)")
        norm = float(np.linalg.norm(n))
        if not (math.isfinite(norm) and abs(norm - 1.0) < 1e-6):
            raise ContactError(f"`normal` must be a unit vector (got {n}, |n| = {norm:.6g})")
        before = self.patch.copy()
        ctrl, rest, ku, kv = self.surface.kernel_arrays()
        moved = deform_kernel(ctrl, rest, ku, kv, c[0], c[1], c[2], radius, n[0], n[1], n[2],
                              contact_radius, self.patch)
        self._refresh(before)
        return DeformationResult(int(moved), tuple(int(p) for p in self.patch))

    def release(self) -> None:
        """Put the last dented patch back to its rest positions (bitwise)."""
        before = self.patch.copy()
        ctrl, rest, ku, kv = self.surface.kernel_arrays()
        deform_kernel(ctrl, rest, ku, kv, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, self.patch)
        self._refresh(before)

    def _refresh(self, before: np.ndarray) -> None:
        """Tell the projection's hull boxes which index boxes changed (old and new patch), O(patch)."""
        from arsurf.contact.projection import refresh_region

        for box in (before, self.patch):
            if box[1] > box[0] and box[3] > box[2]:
                refresh_region(self.surface, int(box[0]), int(box[1]), int(box[2]), int(box[3]))
