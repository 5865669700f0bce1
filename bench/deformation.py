"""Benchmark: control-net dent update per tick (O(patch) kernel) vs a numpy pass over the net.

Tip radii 5, 20, 50 nm on a 4 nm grid (512 x 512 net), the tip sliding 0.1 nm per tick.
Run: .venv/bin/python bench/deformation.py   (prints JSON)
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _timing import emit, stats, time_calls  # noqa: E402

from arsurf.contact.deformation import Deformer, deform_kernel  # noqa: E402
from arsurf.contact.maugis_dugdale import MaugisDugdale  # noqa: E402
from arsurf.spline.surface import BSplineSurface  # noqa: E402

H = 4e-9


def numpy_full_net(ctrl, rest, c, R, n, a):
    """The same rule written the obvious way: every control point, every tick."""
    ctrl[...] = rest
    rel = rest - c
    s = rel @ n
    r = rel - s[..., None] * n
    rho2 = np.einsum("ijk,ijk->ij", r, r)
    inside = np.einsum("ijk,ijk->ij", rel, rel) < R * R
    m = (rho2 < R * R) & ((rho2 < a * a) | inside)
    cap = -np.sqrt(R * R - rho2[m])
    ctrl[m] = c + r[m] + cap[:, None] * n


def main() -> None:
    n_net = 512
    s = BSplineSurface.from_heights(np.zeros((n_net, n_net)), (0.0, (n_net - 3) * H), (0.0, (n_net - 3) * H))
    normal = np.array([0.0, 0.0, 1.0])
    results = {}
    for R in (5e-9, 20e-9, 50e-9):
        d = Deformer(s)
        ctrl, rest, ku, kv = s.kernel_arrays()
        # a Maugis-Dugdale contact 0.1 R deep (lambda ~ 1): contact zone and elastic surface around it
        md = MaugisDugdale(R, 10e9, 0.1)
        depth = 0.1 * R
        st = md.contact_state(depth=depth)
        a, zone = st.radius, st.cohesive_radius
        state = {"x": 400e-9}

        def tick_kernel():
            state["x"] += 0.1e-9
            deform_kernel(ctrl, rest, ku, kv, state["x"], 500e-9, 0.9 * R, R, 0.0, 0.0, 1.0, a, depth, zone, d.profile,
                          d.patch)

        def tick_numpy():
            state["x"] += 0.1e-9
            numpy_full_net(ctrl, rest, np.array([state["x"], 500e-9, 0.9 * R]), R, normal, a)

        k = stats(time_calls(tick_kernel, 20000))
        p = stats(time_calls(tick_numpy, 20))
        d.release()
        s.reset()
        results[f"R={R * 1e9:.0f}nm"] = {
            "kernel_tick": k,
            "numpy_full_net_tick": p,
            "ratio_numpy_over_kernel": p["median_us"] / k["median_us"],
            "patch_points": int((2 * R / H + 5) ** 2),
        }
    results["net"] = f"{n_net}x{n_net} control points, spacing {H * 1e9:.0f} nm"
    emit("deformation", results)


if __name__ == "__main__":
    main()
