"""Slow, obviously-right references for the spline tests (Cox-de Boor recursion, dense matrices)."""
from __future__ import annotations

import numpy as np


def cox_de_boor(knots, i, p, u):
    """N_{i,p}(u) by the textbook recursion (right-continuous; the last span closed at its end)."""
    t = knots
    if p == 0:
        if t[i] <= u < t[i + 1]:
            return 1.0
        # close the last non-empty span so the basis is a partition of unity at u = b
        if u == t[-1] and t[i] < t[i + 1] == t[-1]:
            return 1.0
        return 0.0
    left = 0.0 if t[i + p] == t[i] else (u - t[i]) / (t[i + p] - t[i]) * cox_de_boor(t, i, p - 1, u)
    right = 0.0 if t[i + p + 1] == t[i + 1] else (t[i + p + 1] - u) / (t[i + p + 1] - t[i + 1]) * cox_de_boor(t, i + 1, p - 1, u)
    return left + right


def cox_de_boor_derivative(knots, i, p, u, order):
    """d^order N_{i,p} / du^order by the recursive derivative formula."""
    if order == 0:
        return cox_de_boor(knots, i, p, u)
    t = knots
    a = 0.0 if t[i + p] == t[i] else p / (t[i + p] - t[i]) * cox_de_boor_derivative(t, i, p - 1, u, order - 1)
    b = 0.0 if t[i + p + 1] == t[i + 1] else p / (t[i + p + 1] - t[i + 1]) * cox_de_boor_derivative(t, i + 1, p - 1, u, order - 1)
    return a - b


def surface_reference(ctrl, ku, kv, u, v, du=0, dv=0):
    """S (or a partial derivative) by summing every basis function (no span logic at all)."""
    nu, nv = ctrl.shape[:2]
    bu = np.array([cox_de_boor_derivative(ku, i, 3, u, du) for i in range(nu)])
    bv = np.array([cox_de_boor_derivative(kv, j, 3, v, dv) for j in range(nv)])
    return np.einsum("i,j,ijc->c", bu, bv, ctrl)
