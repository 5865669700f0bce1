"""What the HDF5 checks cost: arsurf._h5safe.open_hdf5 (read into memory, core-driver image, tree
walk) against plain h5py.File on the same files, both reading every dataset, in the same run.

Files: the HDF5 real scans (``sample_0.h5-jpk``, ``sample_0_1.topostats`` from $ARSURF_REAL_SCANS
or ../shared/scans-real), the bundled ``.nhf`` excerpt and a 60,000-tick session. Prints one JSON
document: per file its size, the median and largest time of each way over ``--repeat`` runs, and
the check alone (open_hdf5 without reading the datasets).

Run: python bench/hdf5_checks.py [--repeat 7]
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import h5py
import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))
from _timing import emit  # noqa: E402

from arsurf._h5safe import GZIP_LIMIT, open_hdf5  # noqa: E402

REAL = Path(os.environ.get("ARSURF_REAL_SCANS", ROOT.parent / "shared" / "scans-real"))


def _read_all(f) -> int:
    n = 0
    def visit(name, obj):
        nonlocal n
        if isinstance(obj, h5py.Dataset):
            n += np.asarray(obj[()]).nbytes
    f.visititems(visit)
    return n


def _time(fn, repeat: int) -> dict:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return {"median_ms": 1e3 * statistics.median(times), "max_ms": 1e3 * max(times)}


def _session(path: Path) -> Path:
    from test_session_fuzz import _meta, _record

    from arsurf.sessions.writer import SessionWriter

    with SessionWriter(path, _meta(), created="2026-01-01T00:00:00+00:00", when_full="wait") as w:
        _record(w, 60_000, np.random.default_rng(0))
    return path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=7)
    args = ap.parse_args()
    files = {n: REAL / n for n in ("sample_0.h5-jpk", "sample_0_1.topostats") if (REAL / n).exists()}
    files["nanosurf_wavemode_excerpt.nhf"] = ROOT / "tests" / "data" / "nanosurf_wavemode_excerpt.nhf"
    with tempfile.TemporaryDirectory(prefix="arsurf-h5bench-") as d:
        files["session_60000_ticks.h5"] = _session(Path(d) / "s.h5")
        out = {}
        for name, p in files.items():
            session = name.startswith("session")
            opts = {"soft_links": False, "max_expansion": GZIP_LIMIT} if session else {}

            def plain():
                with h5py.File(p, "r") as f:
                    return _read_all(f)

            def checked():
                with open_hdf5(p, "file", **opts) as f:
                    return _read_all(f)

            def check_only():
                open_hdf5(p, "file", **opts).close()

            assert plain() == checked()
            out[name] = {"bytes": p.stat().st_size, "h5py_open_and_read": _time(plain, args.repeat),
                         "open_hdf5_and_read": _time(checked, args.repeat),
                         "open_hdf5_checks_only": _time(check_only, args.repeat)}
    emit("hdf5_checks", {"repeat": args.repeat, "files": out})


if __name__ == "__main__":
    main()
