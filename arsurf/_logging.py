"""Messages and progress bars: one logger tree, ``arsurf``, and tqdm bars that follow it.

Every module logs to ``logging.getLogger(__name__)`` (the viewer to ``arsurf.viewer``), children
of the ``arsurf`` logger, which has only a :class:`logging.NullHandler`: a library prints nothing
unless its user configures logging. The ``arsurf`` command does (:func:`configure_cli`): progress
messages (INFO) on stderr, ``-q`` keeps warnings and errors only, ``-v`` adds the debug messages.

:func:`progress` is the one way to show a bar (tqdm, on stderr) for a step that takes more than
about a second. It is off when stderr is not a terminal (tqdm's own rule), when the ``arsurf``
logger does not pass INFO (``-q``, or a library user who set it to WARNING), or when the caller
says so.

Examples
--------
>>> for _ in progress(range(3), desc="example", enabled=False):
...     pass
"""
from __future__ import annotations

import logging
import sys

__all__ = ["LOGGER", "progress", "configure_cli"]

#: the package's logger; modules use its children (``logging.getLogger(__name__)``)
LOGGER = logging.getLogger("arsurf")
if not any(isinstance(h, logging.NullHandler) for h in LOGGER.handlers):
    LOGGER.addHandler(logging.NullHandler())


def progress(iterable=None, *, total: int | None = None, desc: str = "", unit: str = "it", enabled: bool = True,
             initial: int = 0, logger: logging.Logger = LOGGER):
    """A tqdm bar on stderr, shown only on a terminal when ``logger`` passes INFO and ``enabled``.

    Parameters
    ----------
    iterable : iterable, optional
        Wrapped (as ``tqdm(iterable)``); or None and call ``update(n)``.
    total : int, optional
        Number of steps (default: ``len(iterable)`` when it has one).
    desc, unit : str
        Label and unit shown.
    enabled : bool
        False: never shown.
    initial : int
        Steps already done (a resumed batch).
    logger : logging.Logger
        Whose level decides (default the ``arsurf`` logger).

    Returns
    -------
    tqdm.tqdm
    """
    from tqdm import tqdm

    disable = None if enabled and logger.isEnabledFor(logging.INFO) else True  # None: off when not a TTY
    return tqdm(iterable, total=total, desc=desc, unit=unit, file=sys.stderr, disable=disable, leave=False, initial=initial,
                mininterval=0.25, dynamic_ncols=True)


class _CliFormatter(logging.Formatter):
    """INFO as the bare message; warnings and errors as ``arsurf: warning: ...``; ``-v`` names the logger."""

    def __init__(self, verbose: bool):
        super().__init__()
        self.verbose = verbose

    def format(self, record: logging.LogRecord) -> str:
        message = record.getMessage()
        if record.levelno >= logging.WARNING:
            return f"arsurf: {record.levelname.lower()}: {message}"
        return f"[{record.name}] {message}" if self.verbose else message


def configure_cli(verbosity: int) -> logging.Handler:
    """Send the ``arsurf`` logger to stderr for the command line (replacing an earlier call's handler).

    Parameters
    ----------
    verbosity : int
        < 0 (``-q``): warnings and errors; 0: progress messages too (INFO); > 0 (``-v``): debug.

    Returns
    -------
    logging.Handler
        The handler installed.
    """
    for h in list(LOGGER.handlers):
        if getattr(h, "_arsurf_cli", False):
            LOGGER.removeHandler(h)
    handler = logging.StreamHandler(sys.stderr)
    handler._arsurf_cli = True
    handler.setFormatter(_CliFormatter(verbosity > 0))
    LOGGER.addHandler(handler)
    LOGGER.setLevel(logging.WARNING if verbosity < 0 else logging.INFO if verbosity == 0 else logging.DEBUG)
    return handler
