"""``python -m arsurf.cli``: the ``arsurf`` command (:func:`arsurf.cli.main`)."""
import sys

from arsurf.cli import main

sys.exit(main())
