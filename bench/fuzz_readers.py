"""Fuzz the scan readers at scale: mutated copies of every real scan, each read in an isolated
worker process with a time limit. Prints one JSON document (not a test: it never asserts).

Mutations (fixed seed), cycled per mutant: truncation anywhere, bit flips in the header (first
4 KiB), bit flips anywhere, a run of random bytes, an edit of a number in a text header
(huge, negative, zero, NaN), and for HDF5 files an edit of one numeric attribute or dataset
shape-bearing attribute (grid size, lengths, calibration multipliers). Each mutant's outcome is:

- ``loaded``: a Scan came back (then checked: 2-D float64, a finite pixel, finite positive
  spacings within the readers' plausibility range; ``implausible`` counts failures of that check);
- ``refused``: an :class:`arsurf.errors.ScanError` (the project's one-line error);
- ``other``: any other exception (type names listed; should be 0);
- ``crash``: the worker died (signal or exit status; should be 0);
- ``hang``: the worker took longer than the time limit (should be 0).

The worker runs ``load_scan`` on one file at a time under an address-space limit
(``--mem-limit-mb``), so a header that asks for a huge allocation shows up as ``refused`` (our
size checks) or ``other`` (MemoryError escaping), never as a machine that swaps; it is restarted
after a crash or a hang.

Run: python bench/fuzz_readers.py [--mutants 200] [--seed 1] [--timeout 20] [--files a.spm,...]
The real scans are taken from $ARSURF_REAL_SCANS or ../shared/scans-real beside the project, plus
the bundled samples of the .nhf, .mdt and .asd readers in tests/data (SOURCES.md there).
"""
from __future__ import annotations

import argparse
import json
import os
import re
import select
import shutil
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

import numpy as np
from tqdm import tqdm

ROOT = Path(__file__).resolve().parents[1]
REAL = Path(os.environ.get("ARSURF_REAL_SCANS", ROOT.parent / "shared" / "scans-real"))
DATA = ROOT / "tests" / "data"
DATA_SUFFIXES = (".nhf", ".mdt", ".asd")
HDF5 = b"\x89HDF\r\n\x1a\n"

WORKER = r"""
import json, resource, sys, traceback
limit = int(sys.argv[1]) * 2**20
if limit > 0:
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
import numpy as np
from arsurf.errors import ScanError
from arsurf.scan.io import load_scan
from arsurf.scan.readers._common import PIXEL_RANGE
for line in sys.stdin:
    path = line.rstrip("\n")
    out = {}
    try:
        s = load_scan(path)
        h = s.heights
        ok = (h.ndim == 2 and h.dtype == np.float64 and bool(np.isfinite(h).any())
              and all(np.isfinite(v) and PIXEL_RANGE[0] <= v <= PIXEL_RANGE[1] for v in (s.dx, s.dy)))
        out = {"outcome": "loaded", "plausible": bool(ok), "format": s.metadata.get("format"),
               "unit": s.metadata.get("z_unit")}
    except ScanError as exc:
        out = {"outcome": "refused", "type": type(exc).__name__, "one_line": "\n" not in str(exc)}
    except BaseException as exc:
        out = {"outcome": "other", "type": type(exc).__name__, "message": str(exc)[:200]}
    sys.stdout.write(json.dumps(out) + "\n")
    sys.stdout.flush()
"""


class Worker:
    """One ``load_scan`` process fed file paths on stdin; restarted after a crash or a hang."""

    def __init__(self, mem_mb: int):
        self.mem_mb = mem_mb
        self.proc = None

    def start(self):
        env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
        self.proc = subprocess.Popen([sys.executable, "-c", WORKER, str(self.mem_mb)], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env=env)

    def run(self, path: Path, timeout: float) -> dict:
        if self.proc is None or self.proc.poll() is not None:
            self.start()
        try:
            self.proc.stdin.write(str(path) + "\n")
            self.proc.stdin.flush()
        except BrokenPipeError:
            return self._dead()
        ready, _, _ = select.select([self.proc.stdout], [], [], timeout)
        if not ready:
            self.stop()
            return {"outcome": "hang"}
        line = self.proc.stdout.readline()
        if not line:
            return self._dead()
        return json.loads(line)

    def _dead(self) -> dict:
        code = self.proc.wait()
        self.proc = None
        return {"outcome": "crash", "returncode": code}

    def stop(self):
        if self.proc is not None:
            self.proc.kill()  # our own child, by its handle
            self.proc.wait()
            self.proc = None


_NUM = re.compile(rb"(?<![\w.])[-+]?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")


def mutate_bytes(data: bytes, rng: np.random.Generator, kind: int) -> bytes:
    b = bytearray(data)
    n = len(b)
    if kind == 0:  # truncation
        return bytes(b[: int(rng.integers(0, n))])
    if kind == 1:  # header bit flips
        for _ in range(int(rng.integers(1, 8))):
            i = int(rng.integers(0, min(n, 4096)))
            b[i] ^= 1 << int(rng.integers(0, 8))
    elif kind == 2:  # bit flips anywhere
        for _ in range(int(rng.integers(1, 32))):
            i = int(rng.integers(0, n))
            b[i] ^= 1 << int(rng.integers(0, 8))
    elif kind == 3:  # a run of random bytes
        i, k = int(rng.integers(0, n)), int(rng.integers(1, 64))
        b[i : i + k] = rng.integers(0, 256, k, dtype=np.uint8).tobytes()
    else:  # a number of a text header replaced (huge, negative, zero, NaN)
        head = bytes(b[: min(n, 1 << 16)])
        nums = list(_NUM.finditer(head))
        if not nums:
            return mutate_bytes(data, rng, 2)
        m = nums[int(rng.integers(0, len(nums)))]
        new = [b"999999999999", b"-1", b"0", b"nan", b"1e308", b"-2147483648", b"4294967296"][int(rng.integers(0, 7))]
        b[m.start() : m.end()] = new
    return bytes(b)


def mutate_hdf5(src: Path, dst: Path, rng: np.random.Generator) -> str:
    """Copy ``src`` and change one numeric attribute (grid, lengths, scaling) to a hostile value."""
    import h5py

    shutil.copy(src, dst)
    with h5py.File(dst, "r+") as f:
        targets = []

        def visit(name, obj):
            for k, v in obj.attrs.items():
                if isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool):
                    targets.append((name, k))
        f.visititems(visit)
        for k, v in f.attrs.items():
            if isinstance(v, (int, float, np.integer, np.floating)):
                targets.append(("", k))
        if not targets:
            return "none"
        prefer = [t for t in targets if re.search(r"length|multiplier|offset|scaling|calibration|axis|image_|points|"
                                                  r"lines|version", t[1])]
        name, key = (prefer or targets)[int(rng.integers(0, len(prefer or targets)))]
        obj = f[name] if name else f
        value = [0, -1, 2**31 - 1, 1e308, float("nan"), -1e-300, 3][int(rng.integers(0, 7))]
        old = obj.attrs[key]
        obj.attrs[key] = np.asarray(value, dtype=np.asarray(old).dtype if np.asarray(old).dtype.kind == "f"
                                    else np.float64 if isinstance(value, float) else np.int64)
        return f"{name}@{key}={value}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mutants", type=int, default=200, help="mutants per file (default 200)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--timeout", type=float, default=20.0, help="seconds per file before it counts as a hang")
    ap.add_argument("--mem-limit-mb", type=int, default=4096, help="address-space limit of the worker")
    ap.add_argument("--files", default="", help="comma-separated names in the real-scan folder (default: all)")
    args = ap.parse_args(argv)
    if not REAL.is_dir():
        print(json.dumps({"error": f"real scans not found in {REAL}; set ARSURF_REAL_SCANS"}))
        return 2
    sources = {p.name: p for p in REAL.iterdir() if p.is_file() and p.suffix.lower() not in (".md",)}
    sources.update({p.name: p for p in DATA.iterdir() if p.suffix.lower() in DATA_SUFFIXES})
    names = [n for n in args.files.split(",") if n] or sorted(sources)
    unknown = [n for n in names if n not in sources]
    if unknown:
        print(json.dumps({"error": f"not in {REAL} or {DATA}: {unknown}"}))
        return 2
    worker = Worker(args.mem_limit_mb)
    report: dict = {"seed": args.seed, "mutants_per_file": args.mutants, "timeout_s": args.timeout,
                    "mem_limit_mb": args.mem_limit_mb, "files": {}}
    totals: Counter = Counter()
    t_all = time.perf_counter()
    # on stderr (stdout is the JSON report), only on a terminal
    bar = tqdm(total=len(names) * args.mutants, desc="fuzz", unit="mutant", file=sys.stderr, disable=None,
               mininterval=0.5)
    with tempfile.TemporaryDirectory(prefix="arsurf-fuzz-") as tmp:
        for name in names:
            src = sources[name]
            data = src.read_bytes()
            is_h5 = data.startswith(HDF5)
            rng = np.random.default_rng([args.seed, sum(name.encode())])
            counts: Counter = Counter()
            others: Counter = Counter()
            examples: dict = {}
            times = []
            base = worker.run(src, args.timeout)
            for k in range(args.mutants):
                dst = Path(tmp) / f"m{k}{src.suffix}"
                kinds = 6 if is_h5 else 5
                kind = k % kinds
                if kind == 5:
                    label = "hdf5-attr:" + mutate_hdf5(src, dst, rng)
                else:
                    dst.write_bytes(mutate_bytes(data, rng, kind))
                    label = ["truncate", "header-bits", "bits", "byte-run", "header-number"][kind]
                t0 = time.perf_counter()
                res = worker.run(dst, args.timeout)
                times.append(time.perf_counter() - t0)
                outcome = res["outcome"]
                counts[outcome] += 1
                if outcome == "loaded" and not res.get("plausible", True):
                    counts["implausible"] += 1
                if outcome == "refused" and not res.get("one_line", True):
                    counts["multi_line_message"] += 1
                if outcome == "other":
                    others[res["type"]] += 1
                if outcome in ("other", "crash", "hang") and outcome not in examples:
                    keep = Path(tmp).parent / f"arsurf-fuzz-{outcome}-{name}-{k}{src.suffix}"
                    shutil.copy(dst, keep)
                    examples[outcome] = {"mutation": label, "result": res, "kept": str(keep)}
                dst.unlink(missing_ok=True)
                bar.update(1)
            totals.update(counts)
            report["files"][name] = {
                "original": base.get("outcome"), "mutants": args.mutants,
                **{o: counts.get(o, 0) for o in ("loaded", "refused", "other", "crash", "hang", "implausible",
                                                  "multi_line_message")},
                "other_types": dict(others), "examples": examples,
                "median_s_per_file": float(np.median(times)) if times else None,
                "max_s_per_file": float(np.max(times)) if times else None,
            }
    bar.close()
    worker.stop()
    report["total"] = {o: totals.get(o, 0) for o in ("loaded", "refused", "other", "crash", "hang", "implausible",
                                                      "multi_line_message")}
    report["total"]["mutants"] = sum(totals[o] for o in ("loaded", "refused", "other", "crash", "hang"))
    report["seconds"] = time.perf_counter() - t_all
    report["python"] = sys.version.split()[0]
    print(json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
