"""Put this checkout's folder on the editable install's ``sys.path`` (``make setup`` runs it).

Why: ``pip install -e .`` makes ``arsurf`` importable through setuptools' import hook, which Python
asks only after its path search. A script run from the folder that holds the clone (named
``arsurf``, as ``git clone`` names it) puts that folder first on ``sys.path``, where the clone is a
folder without ``__init__.py``: the path search takes it as a namespace package ``arsurf``, the
hook is never asked, and ``arsurf.load_scan`` is missing. With the checkout itself on ``sys.path``
(this ``.pth`` file), the path search also meets ``<checkout>/arsurf/__init__.py``, and a regular
package wins over namespace folders wherever they come on the path.

setuptools' own ``editable_mode=compat`` writes the same kind of ``.pth`` but then cannot map
``viewer/`` to ``arsurf_viewer`` (``tool.setuptools.package-dir``), and ``editable_mode=strict``
links files, so a module added later is not seen until the next install; this keeps the
default hook for ``arsurf_viewer`` and adds the path for ``arsurf``.

Usage: ``python tools/editable_root.py`` with the interpreter of the environment. Does nothing
unless arsurf is installed there in editable mode from this checkout. Idempotent.
"""
from __future__ import annotations

import json
import sys
import sysconfig
from importlib import metadata
from pathlib import Path
from urllib.parse import unquote, urlparse

ROOT = Path(__file__).resolve().parents[1]
PTH = "arsurf_checkout_root.pth"


def editable_from_here() -> bool:
    """True when the ``arsurf`` distribution of this interpreter is an editable install of ROOT."""
    try:
        text = metadata.distribution("arsurf").read_text("direct_url.json")
    except metadata.PackageNotFoundError:
        return False
    try:
        info = json.loads(text or "{}")
    except ValueError:
        return False
    url = urlparse(info.get("url", ""))
    return bool(info.get("dir_info", {}).get("editable")) and url.scheme == "file" and \
        Path(unquote(url.path)).resolve() == ROOT


def main() -> int:
    target = Path(sysconfig.get_paths()["purelib"]) / PTH
    if not editable_from_here():
        target.unlink(missing_ok=True)  # a regular install needs none (its package is on the path)
        return 0
    text = f"{ROOT}\n"
    if not target.is_file() or target.read_text() != text:
        target.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
