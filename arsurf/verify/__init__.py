"""Closing the loop: the model's prediction meets the next scan (``arsurf verify``).

* :mod:`~arsurf.verify.register` - the scan after registered to the scan before on the substrate
  (phase correlation, robust affine fit): the drift.
* :mod:`~arsurf.verify.tubes` - the nanotubes found in a scan, fitted as segments with the tip's
  broadening removed.
* :mod:`~arsurf.verify.compare` - found tubes matched to the model's poses: position and angle
  errors, and the flag of a wrong model.
* :mod:`~arsurf.verify.figure` - prediction and scan after, side by side and overlaid ([MWCNT]
  Fig. 9).
* :mod:`~arsurf.verify.verify` - a session and its scans in, the report, figure and next scene out.
* :mod:`~arsurf.verify.command` - the ``arsurf verify`` command.

Nothing is imported here: ``import arsurf.verify`` stays cheap.
"""
