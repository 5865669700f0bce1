"""Nano-object manipulation models: what the tip pushes and how it moves.

* :mod:`~arsurf.manipulation.nanotube` - rigid MWCNT on the surface, pushed by the tip ([MWCNT],
  Eq. 9 corrected); collision with the tip sphere and the tube's height map.
* :mod:`~arsurf.manipulation.z_strategy` - the "Z" strategy: plan alternate end pushes to a goal.
* :mod:`~arsurf.manipulation.sphere_rolling` - microsphere rolling under a tipless cantilever and
  the forces rendered on two haptic axes ([Bolopion], Eq. 12-14).
* :mod:`~arsurf.manipulation.scene` - tubes as live scene objects of the haptic loop (push every
  tick, friction resistance on the tip), the substrate under them for the spline.

The instrument that moves the tip (stages, LSPB, engage) is :mod:`arsurf.instrument`.
Nothing is imported here: ``import arsurf.manipulation`` stays cheap.
"""
