"""
From a scan to a surface
========================

The bundled scan (three nanotubes on a rough substrate) is levelled, smoothed with a 1 nm
Gaussian and fitted with an interpolating bicubic B-spline. The spline passes through every pixel
of the processed scan; between the pixels it is smooth, with the derivatives the Newton projection
needs.
"""
import matplotlib.pyplot as plt
import numpy as np

import arsurf
from arsurf.data import bundled_scan

scan = arsurf.smooth(arsurf.level(arsurf.load_scan(bundled_scan()), "plane"), 1e-9)
surface = arsurf.fit_surface(scan)
surface

# %%
# A profile across a tube: the pixels of the scan and the spline between them, 8x finer.
y = 0.56e-6
iy = int(round(y / scan.dy))
x_fine = np.linspace(0.5e-6, 0.75e-6, 400)
z_fine = surface.evaluate(x_fine, np.full(x_fine.size, iy * scan.dy))[:, 2]
ix = (scan.x >= x_fine[0]) & (scan.x <= x_fine[-1])
fig, ax = plt.subplots(figsize=(6, 3), layout="constrained")
ax.plot(x_fine * 1e9, z_fine * 1e9, lw=1.2, label="B-spline S(u, v)")
ax.plot(scan.x[ix] * 1e9, scan.heights[iy, ix] * 1e9, "o", ms=3, label="pixels (levelled, smoothed)")
ax.set_xlabel("x (nm)")
ax.set_ylabel("z (nm)")
ax.legend(frameon=False)
residual = np.abs(surface.evaluate(scan.x[ix], np.full(ix.sum(), iy * scan.dy))[:, 2] - scan.heights[iy, ix]).max()
print(f"largest |spline - pixel| on this profile: {residual:.2e} m")
