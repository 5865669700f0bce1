"""
Where a pushed nanotube turns
=============================

A rod of length L lying on a substrate with uniform friction, pushed sideways at arc length l,
turns about the point s = l - sqrt(l² - lL + L²/2) ([MWCNT] Eq. 9, solved correctly; its Eq. 10
is wrong). Pushed at its end it pivots at L(1 - 1/√2) from the other end, the classical result;
pushed at its middle it translates.
"""
import matplotlib.pyplot as plt
import numpy as np

import arsurf

L = 500e-9
push = np.linspace(0.0, L, 201)
pivot = np.array([arsurf.rotation_centre(p, L) for p in push])
fig, ax = plt.subplots(figsize=(5, 4), layout="constrained")
ax.plot(push / L, pivot / L)
ax.axhline(1 - 1 / np.sqrt(2), color="0.6", lw=0.8)
ax.annotate("L(1 - 1/√2)", (0.02, 1 - 1 / np.sqrt(2) + 0.02))
ax.set_xlabel("push point  l / L")
ax.set_ylabel("rotation centre  s / L")
print(f"pushed at the end: s = {arsurf.rotation_centre(L, L) / L:.6f} L (1 - 1/sqrt 2 = {1 - 1 / np.sqrt(2):.6f})")
