"""Force sensing: cantilever and photodiode models, calibration, and 3D force decoupling.

Modules (one job each; import them directly, nothing is imported here so ``import arsurf`` stays cheap):

* :mod:`arsurf.force.cantilever`  - :class:`Cantilever` (stiffnesses, load point, forward angles model)
* :mod:`arsurf.force.photodiode`  - quadrant voltages -> signals -> angles (:class:`Photodiode`)
* :mod:`arsurf.force.calibration` - k_v, k_h, S_n, wedge G_l and mu, thermal-noise k
* :mod:`arsurf.force.decoupling`  - :func:`decouple`, :func:`decouple_by_motion`, the numba kernel
* :mod:`arsurf.force.haptic_gains`     - signal -> haptic force gains ([Alabdulmuhsin] Tables 4.4-4.6)
* :mod:`arsurf.force.simulate`    - synthetic signals, thermal traces, force curves, wedge sliding
"""
