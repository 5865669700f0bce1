"""The AFM instrument that carries the tip: stages, trajectories, engage.

* :mod:`~arsurf.instrument.lspb` - Linear Segments with Parabolic Blends interpolation.
* :mod:`~arsurf.instrument.stages` - micro stage, nano stage and PicoCube of seed 001.
* :mod:`~arsurf.instrument.instrument` - virtual AFM: stages, sample, lever spring, noisy photodiode.
* :mod:`~arsurf.instrument.engage` - the engage procedure of seed 001 (Fig. 3.10).

Nothing is imported here: ``import arsurf.instrument`` stays cheap.
"""
