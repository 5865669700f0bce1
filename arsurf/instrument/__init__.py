"""The AFM instrument that carries the tip: stages, trajectories, engage, controllers.

* :mod:`~arsurf.instrument.interface` - the :class:`Instrument` interface (read tip position and
  signals, move within limits, engage, withdraw, feedback), its limits and frame.
* :mod:`~arsurf.instrument.lspb` - Linear Segments with Parabolic Blends interpolation.
* :mod:`~arsurf.instrument.stages` - micro stage, nano stage and PicoCube of [Alabdulmuhsin].
* :mod:`~arsurf.instrument.instrument` - virtual AFM: stages, sample, lever spring, noisy photodiode.
* :mod:`~arsurf.instrument.imaging` - the virtual AFM images its sample (tip dilation, drift, lag, noise).
* :mod:`~arsurf.instrument.engage` - the engage procedure of [Alabdulmuhsin] (Fig. 3.10).
* :mod:`~arsurf.instrument.nanonis_protocol` - the Nanonis TCP programming interface's messages.
* :mod:`~arsurf.instrument.nanonis` - a Nanonis controller as an Instrument.
* :mod:`~arsurf.instrument.nanonis_sim` - a simulated Nanonis controller in front of any Instrument.
* :mod:`~arsurf.instrument.link` - the live link: the instrument read and moved in its own thread.

Nothing is imported here: ``import arsurf.instrument`` stays cheap.
"""
