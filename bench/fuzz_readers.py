"""Fuzz the scan readers at scale: mutated copies of every real scan, each read in an isolated
worker process with a time and an address-space limit, every outcome counted. Prints one JSON
document (not a test: it never asserts).

Mutations and classification are those of tests/test_readers_fuzz.py (``mutate``, ``classify``;
fixed seed), cycled per mutant: truncation, bit flips in the header (first 4 KiB) and anywhere, a
run of random bytes, a number of a text header made huge/negative/zero/NaN, one digit of such a
number changed, and for HDF5 files one numeric attribute (grid, lengths, calibration) set to a
hostile value, and an HDF5 feature reaching outside the file planted in a random dataset
(tests/hdf5_attacks.py; ``hdf5_features`` reports per feature the outcomes - ``followed`` when it
was not refused, which must never happen - the refusals whose message names it, and the slowest
read). Outcomes of arsurf's ``load_scan``:

- ``refused``: an :class:`arsurf.errors.ScanError` (``multi_line_message`` counts those not on one line);
- ``equal``, ``damaged_pixels``, ``rescaled``, ``plausible``: accepted, and right or within the
  plausibility rules (see the test module);
- ``misread``: a silent misread the classification detects (should be 0; examples kept);
- ``other``: any other exception (should be 0); ``crash``: the worker died; ``hang``: time limit.

Memory: the worker reports the tracemalloc peak of each read; ``max_alloc_per_file_byte`` is the
largest peak over the mutant's size and ``over_memory_bound`` counts reads above the test's
bound (``MEMORY_FACTOR`` x size + slack), under an address-space limit (``--mem-limit-mb``).

Peers, on the same mutants in the same kind of worker: ``gsffile.read_gsf`` for .gsf files and
``igor2.binarywave.load`` for .ibw (the maintained third-party readers we could use instead);
their outcomes are ``refused`` (any exception: they have no error class of their own), the
classification of their array against their reading of the intact file (``equal``,
``damaged_pixels``, ``rescaled``, ``misread``; ``plausible`` for another shape: they check no
calibration), ``crash``, ``hang``; their median time and largest allocation per read next to ours.

Run: python bench/fuzz_readers.py [--mutants 200] [--seed 1] [--timeout 20] [--files a.spm,...] [--no-peers]
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

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT / "tests"))
from hdf5_attacks import KINDS as FEATURES  # noqa: E402
from hdf5_attacks import plant  # noqa: E402
from test_readers_fuzz import KINDS, MEMORY_FACTOR, MEMORY_SLACK, OUTCOMES, mutate  # noqa: E402

REAL = Path(os.environ.get("ARSURF_REAL_SCANS", ROOT.parent / "shared" / "scans-real"))
DATA = ROOT / "tests" / "data"
DATA_SUFFIXES = (".nhf", ".mdt", ".asd")
HDF5 = b"\x89HDF\r\n\x1a\n"
PEERS = {".gsf": "gsffile", ".ibw": "igor2"}

WORKER = r"""
import json, resource, sys, time, tracemalloc
limit = int(sys.argv[1]) * 2**20
if limit > 0:
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
sys.path.insert(0, sys.argv[2])
import numpy as np
from arsurf.errors import ScanError
from arsurf.scan.io import load_scan
from test_readers_fuzz import classify, classify_values

def peer_read(reader, path):
    if reader == "gsffile":
        from gsffile import read_gsf
        return np.asarray(read_gsf(path)[0], dtype=np.float64)
    import igor2.binarywave as bw
    return np.asarray(bw.load(path)["wave"]["wData"], dtype=np.float64)

intact = {}
for line in sys.stdin:
    req = json.loads(line)
    reader, path = req["reader"], req["path"]
    key = (reader, req["original"])
    seconds = peak = refused_s = refused_peak = None
    try:
        if key not in intact:
            intact[key] = load_scan(req["original"]) if reader == "arsurf" else peer_read(reader, req["original"])
        tracemalloc.start()  # both readers traced: the same overhead on both times
        t0 = time.perf_counter()
        try:
            got = load_scan(path) if reader == "arsurf" else peer_read(reader, path)
            seconds = time.perf_counter() - t0
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            if seconds is None:  # refused: its time and memory, apart (the HDF5 features are timed so)
                refused_s, refused_peak = time.perf_counter() - t0, tracemalloc.get_traced_memory()[1]
            tracemalloc.stop()
        if req["kind"] == "hdf5-feature":  # a feature reaching outside the file must be refused, never read
            out = {"outcome": "followed"}
        elif reader == "arsurf":
            outcome, reason = classify(intact[key], got, req["kind"], req["changed"])
            out = {"outcome": outcome, "reason": reason}
        else:
            b = intact[key]
            if got.shape != b.shape:
                out = {"outcome": "misread" if req["kind"] == "truncate" else "plausible"}
            else:
                out = dict(zip(("outcome", "reason"), classify_values(b, got, req["kind"], req["changed"])))
    except ScanError as exc:
        out = {"outcome": "refused", "one_line": "\n" not in str(exc), "message": str(exc)[-160:]}
    except BaseException as exc:
        out = {"outcome": "other" if reader == "arsurf" else "refused", "type": type(exc).__name__,
               "message": str(exc)[:200]}
    out.update(seconds=seconds, peak=peak, refused_s=refused_s, refused_peak=refused_peak)
    sys.stdout.write(json.dumps(out) + "\n")
    sys.stdout.flush()
"""


class Worker:
    """One reading process fed requests on stdin; restarted after a crash or a hang."""

    def __init__(self, mem_mb: int):
        self.mem_mb = mem_mb
        self.proc = None

    def start(self):
        env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
        self.proc = subprocess.Popen([sys.executable, "-c", WORKER, str(self.mem_mb), str(ROOT / "tests")],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                                     text=True, env=env)

    def run(self, request: dict, timeout: float) -> dict:
        if self.proc is None or self.proc.poll() is not None:
            self.start()
        try:
            self.proc.stdin.write(json.dumps(request) + "\n")
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
        prefer = [t for t in targets if re.search(r"length|multiplier|offset|scaling", t[1])]
        name, key = (prefer or targets)[int(rng.integers(0, len(prefer or targets)))]
        obj = f[name] if name else f
        value = [0, -1, 2**31 - 1, 1e308, float("nan"), -1e-300, 3][int(rng.integers(0, 7))]
        old = obj.attrs[key]
        obj.attrs[key] = np.asarray(value, dtype=np.asarray(old).dtype if np.asarray(old).dtype.kind == "f"
                                    else np.float64 if isinstance(value, float) else np.int64)
        return f"{name}@{key}={value}"


def mutate_hdf5_feature(src: Path, dst: Path, rng: np.random.Generator, feature: str, workdir: Path) -> str:
    """Copy ``src`` and plant the HDF5 feature ``feature`` (tests/hdf5_attacks.py: external storage on
    /etc/passwd or on a FIFO, external link, virtual dataset, huge unwritten size, dangling soft
    link, unexpected filter) in one of its datasets, chosen at random."""
    import h5py

    shutil.copy(src, dst)
    names: list[str] = []
    with h5py.File(dst, "r") as f:
        f.visititems(lambda name, obj: names.append(name) if isinstance(obj, h5py.Dataset) else None)
    target = names[int(rng.integers(len(names)))]
    plant(dst, target, feature, workdir)
    return f"{feature}@{target}"


def _median(values) -> float | None:
    values = [v for v in values if v is not None]
    return float(np.median(values)) if values else None


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mutants", type=int, default=200, help="mutants per file (default 200)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--timeout", type=float, default=20.0, help="seconds per read before it counts as a hang")
    ap.add_argument("--mem-limit-mb", type=int, default=4096, help="address-space limit of the workers")
    ap.add_argument("--files", default="", help="comma-separated names in the real-scan folder (default: all)")
    ap.add_argument("--no-peers", action="store_true", help="do not run gsffile/igor2 on the .gsf/.ibw mutants")
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
    ours, peer = Worker(args.mem_limit_mb), Worker(args.mem_limit_mb)
    counted = (*OUTCOMES, "followed", "other", "crash", "hang", "multi_line_message", "over_memory_bound")
    report: dict = {"seed": args.seed, "mutants_per_file": args.mutants, "timeout_s": args.timeout,
                    "mem_limit_mb": args.mem_limit_mb, "memory_bound": f"{MEMORY_FACTOR} x file size + "
                    f"{MEMORY_SLACK >> 20} MiB", "files": {}}
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
            peer_name = None if args.no_peers else PEERS.get(src.suffix.lower())
            rng = np.random.default_rng([args.seed, sum(name.encode())])
            counts: Counter = Counter()
            peer_counts: Counter = Counter()
            by_kind: dict = {}
            others: Counter = Counter()
            examples: dict = {}
            times, peer_times, ratios, peer_ratios = [], [], [], []
            kinds = (*KINDS, "hdf5-attr", "hdf5-feature") if is_h5 else KINDS
            features: dict = {}
            for k in range(args.mutants):
                kind = kinds[k % len(kinds)]
                dst = Path(tmp) / f"m{k}{src.suffix}"
                feature = None
                if kind == "hdf5-attr":
                    label, changed = "hdf5-attr:" + mutate_hdf5(src, dst, rng), 0
                elif kind == "hdf5-feature":
                    feature = sorted(FEATURES)[(k // len(kinds)) % len(FEATURES)]
                    label, changed = "hdf5-feature:" + mutate_hdf5_feature(src, dst, rng, feature, Path(tmp)), 0
                else:
                    mutant, changed = mutate(data, rng, kind)
                    dst.write_bytes(mutant)
                    label = kind
                req = {"path": str(dst), "original": str(src), "kind": kind, "changed": changed}
                res = ours.run({**req, "reader": "arsurf"}, args.timeout)
                outcome = res["outcome"]
                counts[outcome] += 1
                by_kind.setdefault(kind, Counter())[outcome] += 1
                times.append(res.get("seconds"))
                if feature is not None:
                    fe = features.setdefault(feature, {"outcomes": Counter(), "named": 0, "max_s": 0.0, "alloc": 0.0})
                    fe["outcomes"][outcome] += 1
                    fe["named"] += int(outcome == "refused" and FEATURES[feature] in res.get("message", ""))
                    fe["max_s"] = max(fe["max_s"], res.get("seconds") or res.get("refused_s") or 0.0)
                    fe["alloc"] = max(fe["alloc"], (res.get("peak") or res.get("refused_peak") or 0)
                                      / max(dst.stat().st_size, 1))
                if res.get("peak") is not None:
                    ratio = res["peak"] / max(dst.stat().st_size, 1)
                    ratios.append(ratio)
                    if res["peak"] > MEMORY_FACTOR * dst.stat().st_size + MEMORY_SLACK:
                        counts["over_memory_bound"] += 1
                if outcome == "refused" and not res.get("one_line", True):
                    counts["multi_line_message"] += 1
                if outcome == "other":
                    others[res["type"]] += 1
                if outcome in ("other", "crash", "hang", "misread") and outcome not in examples:
                    keep = Path(tmp).parent / f"arsurf-fuzz-{outcome}-{name}-{k}{src.suffix}"
                    shutil.copy(dst, keep)
                    examples[outcome] = {"mutation": label, "result": res, "kept": str(keep)}
                if peer_name is not None:
                    pres = peer.run({**req, "reader": peer_name}, args.timeout)
                    peer_counts[pres["outcome"]] += 1
                    peer_times.append(pres.get("seconds"))
                    if pres.get("peak") is not None:
                        peer_ratios.append(pres["peak"] / max(dst.stat().st_size, 1))
                dst.unlink(missing_ok=True)
                bar.update(1)
            totals.update(counts)
            entry = {
                "mutants": args.mutants, **{o: counts.get(o, 0) for o in counted},
                "by_kind": {kd: dict(c) for kd, c in by_kind.items()},
                "other_types": dict(others), "examples": examples,
                "max_alloc_per_file_byte": float(max(ratios)) if ratios else None,
                "median_s_per_read": _median(times),
            }
            if features:  # per HDF5 feature: outcomes, refusals naming it, slowest read (s)
                entry["hdf5_features"] = {f: {"outcomes": dict(v["outcomes"]), "refusals_naming_it": v["named"],
                                              "max_s_per_read": v["max_s"], "max_alloc_per_file_byte": v["alloc"]}
                                          for f, v in sorted(features.items())}
            if peer_name is not None:
                entry["peer"] = {"reader": peer_name, **dict(peer_counts), "median_s_per_read": _median(peer_times),
                                 "max_alloc_per_file_byte": float(max(peer_ratios)) if peer_ratios else None}
            report["files"][name] = entry
    bar.close()
    ours.stop()
    peer.stop()
    report["total"] = {o: totals.get(o, 0) for o in counted}
    report["total"]["mutants"] = sum(totals[o] for o in (*OUTCOMES, "followed", "other", "crash", "hang"))
    report["seconds"] = time.perf_counter() - t_all
    report["python"] = sys.version.split()[0]
    print(json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
