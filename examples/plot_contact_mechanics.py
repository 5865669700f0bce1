"""
Maugis-Dugdale between DMT and JKR
==================================

The load-depth curve of a sphere on a flat for Maugis parameters λ from 0.05 to 5, in Maugis'
non-dimensional units (:math:`\\bar P = P/\\pi w R`, :math:`\\bar\\Delta = \\delta (K^2/\\pi^2 w^2 R)^{1/3}`),
with the Hertz curve (no adhesion) for reference. Small λ tends to DMT (pull-off
:math:`\\bar P = -2`), large λ to JKR (:math:`\\bar P = -1.5`).
"""
import math

import matplotlib.pyplot as plt
import numpy as np

import arsurf

R, E, w = 20e-9, 10e9, 0.1  # tip radius (m), effective modulus (Pa), work of adhesion (J/m^2)
K = 4.0 * E / 3.0
depth_unit = (math.pi**2 * w**2 * R / K**2) ** (1.0 / 3.0)
fig, ax = plt.subplots(figsize=(6, 4), layout="constrained")
for lam in (0.05, 0.3, 1.0, 5.0):
    # sigma0 from lambda = 2 sigma0 (R / (pi w K^2))^(1/3)
    sigma0 = lam / 2.0 * (math.pi * w * K**2 / R) ** (1.0 / 3.0)
    md = arsurf.MaugisDugdale(R, E, w, sigma0)
    a = np.linspace(1e-3, 2.5, 400) * (math.pi * w * R**2 / K) ** (1.0 / 3.0)
    states = [md.at_radius(float(x)) for x in a]  # both branches: the whole curve, stable and unstable
    depth = np.array([st.depth for st in states])
    load = np.array([st.load for st in states])
    ax.plot(depth / depth_unit, load / (math.pi * w * R), label=f"λ = {md.maugis_parameter:.2f}")
    print(f"lambda {md.maugis_parameter:.2f}: pull-off force {md.pull_off_force() / (math.pi * w * R):+.3f} pi w R")
depth = np.linspace(0, 3, 100) * depth_unit
ax.plot(depth / depth_unit, arsurf.Hertz(R, E).load(depth) / (math.pi * w * R), "k--", label="Hertz")
ax.axhline(-2.0, color="0.6", lw=0.8)
ax.axhline(-1.5, color="0.6", lw=0.8, ls=":")
ax.set_xlim(-1, 3)
ax.set_ylim(-2.5, 6)
ax.set_xlabel("depth  δ (K²/π²w²R)^(1/3)")
ax.set_ylabel("load  P / πwR")
ax.legend(frameon=False)
