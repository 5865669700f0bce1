"""``python -m arsurf``: the ``arsurf`` command."""
import sys

from arsurf.cli import main

sys.exit(main())
