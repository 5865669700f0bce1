"""Offline replay of recorded sessions (:mod:`arsurf.replay.replay`) and its figures (:mod:`arsurf.replay.plots`)."""
