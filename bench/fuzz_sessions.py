"""Fuzz the session readers at scale: every mutant must load exactly as written or be refused.

Mutants (fixed seed; the operators of tests/test_session_fuzz.py: bit flips, byte overwrites,
truncations, extensions, zeroed / copied / inserted blocks) of

* ``sealed``    - a small session file as :class:`SessionWriter` writes it (format 2, sealed),
  read with :func:`load_session` (``isolate="auto"``, the default);
* ``resealed``  - the same file damaged in its HDF5 structures (the first 8 kB past the seal)
  and sealed again, i.e. a file crafted to pass the seal, read with ``isolate=True`` (what
  ``arsurf replay`` does) and, as the peer, with ``isolate=False`` (libhdf5 in the process:
  what happens without the isolation);
* ``version1``  - a session in the old format (no seal, no checksums), ``isolate="auto"``
  (which isolates it);
* ``journal``   - a killed recording's journal, ``allow_incomplete=True`` (a prefix of the
  ticks is the right answer there);
* ``hdf5_feature`` - the sealed file with an HDF5 feature reaching outside it planted in a
  random ``/ticks`` dataset (tests/hdf5_attacks.py: external storage on /etc/passwd or on a
  FIFO, external link, virtual dataset, huge unwritten size, dangling soft link, unexpected
  filter), checksums and seal redone: must be ``refused`` (in-process, ``isolate="auto"``).

Each mutant is read in a worker process that the driver watches with a per-file time limit:
outcomes ``identical`` (or ``prefix`` for journals), ``refused`` (SessionError), ``crash`` (the
worker died from a signal), ``hang`` (time limit), ``other`` (another exception class),
``altered`` (loaded, said verified, but different: the failure that must never happen) and
``altered_unverified`` (a version-1 file, which has no checksums: loaded different, with
``Session.verified`` False and a note saying its content cannot be verified).
``isolated_child_peak_rss_kb``: the largest peak resident memory of an isolated reader child
(its address space is capped by ``RLIMIT_AS``). ``peak_rss_growth`` is the largest growth of a worker's
peak resident memory caused by one mutant, against the file size.

Usage: ``python bench/fuzz_sessions.py [--sealed 10000] [--resealed 300] [--version1 200]
[--journal 2000] [--hdf5-features 140] [--timeout 20] [--workers 2]``. Prints one JSON document.
"""
from __future__ import annotations

import argparse
import json
import os
import queue
import select
import subprocess
import sys
import tempfile
import threading
import time
import zlib
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))
from _timing import emit  # noqa: E402
from test_session_fuzz import _meta, _record, mutate  # noqa: E402
from test_session import _write_v1  # noqa: E402
from hdf5_attacks import KINDS as FEATURES  # noqa: E402
from hdf5_attacks import plant, reseal_session  # noqa: E402

from arsurf.sessions.sealed import SEAL_SIZE, seal_bytes  # noqa: E402
from arsurf.sessions.journal import journal_path  # noqa: E402
from arsurf.sessions.writer import SessionWriter  # noqa: E402

WORKER = r"""
import json, resource, sys, numpy as np
from arsurf.errors import SessionError
from arsurf.sessions.reader import load_session
refs = {}
def same(a, b, prefix):
    if a.metadata != b.metadata or a.ticks.keys() != b.ticks.keys():
        return False
    n = a.n_ticks
    if prefix:
        if n > b.n_ticks:
            return False
        return all(a.ticks[k].tobytes() == b.ticks[k][:n].tobytes() for k in a.ticks)
    return a.n_ticks == b.n_ticks and a.attrs == b.attrs and all(
        a.ticks[k].dtype == b.ticks[k].dtype and a.ticks[k].tobytes() == b.ticks[k].tobytes() for k in a.ticks)
for line in sys.stdin:
    job = json.loads(line)
    iso = {"auto": "auto", "isolated": True, "inproc": False}[job["mode"]]
    journal = job["kind"] == "journal"
    key = (job["ref"], journal)
    if key not in refs:
        refs[key] = load_session(job["ref"], allow_incomplete=True, isolate=False)
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    child_before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    try:
        s = load_session(job["path"], allow_incomplete=journal, isolate=iso)
        ok = same(s, refs[key], journal)
        out = (("prefix" if journal and s.n_ticks < refs[key].n_ticks else "identical") if ok
               else "altered" if s.verified else "altered_unverified")
        err = ""
    except SessionError as exc:
        out, err = "refused", str(exc)[:200]
    except BaseException as exc:
        out, err = "other", f"{type(exc).__name__}: {exc}"[:300]
    after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    child = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    print(json.dumps({"outcome": out, "error": err, "rss_growth_kb": after - before,
                      "isolated_child_peak_kb": child if child > child_before else 0}), flush=True)
"""


class Worker:
    """A reader process; restarted after a crash or a hang."""

    def __init__(self):
        self.proc = None
        self.start()

    def start(self):
        env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
        self.proc = subprocess.Popen([sys.executable, "-c", WORKER], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=subprocess.DEVNULL, env=env, text=True, bufsize=1)

    def run(self, job: dict, timeout: float) -> dict:
        t0 = time.perf_counter()
        try:
            self.proc.stdin.write(json.dumps(job) + "\n")
            self.proc.stdin.flush()
        except BrokenPipeError:
            pass
        ready, _, _ = select.select([self.proc.stdout], [], [], timeout)
        line = self.proc.stdout.readline() if ready else ""
        if line:
            res = json.loads(line)
            res["seconds"] = time.perf_counter() - t0
            return res
        if not ready:  # time limit
            self.proc.kill()
            self.proc.wait()
            self.start()
            return {"outcome": "hang", "error": f"> {timeout} s", "rss_growth_kb": 0, "seconds": timeout,
                    "isolated_child_peak_kb": 0}
        code = self.proc.wait()
        self.start()
        return {"outcome": "crash", "error": f"exit {code}", "rss_growth_kb": 0, "seconds": time.perf_counter() - t0,
                "isolated_child_peak_kb": 0}

    def close(self):
        self.proc.stdin.close()
        self.proc.wait()


def _resealed(data: bytes, rng) -> bytes:
    b = bytearray(data)
    for at in rng.integers(SEAL_SIZE, min(len(b), SEAL_SIZE + 8192), size=int(rng.integers(1, 4))):
        b[int(at)] ^= 1 << int(rng.integers(8))
    return bytes(b)


def _featured(data: bytes, rng, i: int, path: Path, workdir: Path) -> bytes:
    """The session with the HDF5 feature ``FEATURES[i % 7]`` planted in a random /ticks dataset,
    checksums and seal redone (tests/hdf5_attacks.py): only the content rules can refuse it."""
    import h5py

    path.write_bytes(data)
    with h5py.File(path, "r") as f:
        names = sorted(f["ticks"])
    feature = sorted(FEATURES)[i % len(FEATURES)]
    plant(path, "ticks/" + names[int(rng.integers(len(names)))], feature, workdir)
    reseal_session(path)
    return path.read_bytes()


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--sealed", type=int, default=10000)
    ap.add_argument("--resealed", type=int, default=300)
    ap.add_argument("--version1", type=int, default=200)
    ap.add_argument("--journal", type=int, default=2000)
    ap.add_argument("--hdf5-features", type=int, default=140, help="sessions with a planted HDF5 feature")
    ap.add_argument("--timeout", type=float, default=20.0)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--seed", type=int, default=20261121)
    args = ap.parse_args()
    d = Path(tempfile.mkdtemp(prefix="arsurf-fuzz-"))
    sealed = d / "sealed.h5"
    with SessionWriter(sealed, _meta(), created="2026-01-01T00:00:00+00:00") as w:
        _record(w, 40, np.random.default_rng(1))
    v1 = _write_v1(d / "v1.h5", n=40)
    jbase = d / "j.h5"
    w = SessionWriter(jbase, _meta(), capacity=8, when_full="wait")
    _record(w, 80, np.random.default_rng(2))
    w._stream.stop()
    w._file.close()
    w._closed = True
    journal = journal_path(jbase)

    jobs = []
    for i in range(args.sealed):
        jobs.append(("sealed", "auto", sealed, "h5", i))
    for i in range(args.resealed):
        jobs.append(("resealed_isolated", "isolated", sealed, "h5", i))
        jobs.append(("resealed_in_process_peer", "inproc", sealed, "h5", i))
    for i in range(args.version1):
        jobs.append(("version1", "auto", v1, "h5", i))
    for i in range(args.journal):
        jobs.append(("journal", "auto", journal, "journal", i))
    for i in range(args.hdf5_features):
        jobs.append(("hdf5_feature", "auto", sealed, "h5", i))
    originals = {p: p.read_bytes() for p in (sealed, v1, journal)}
    # the mutant of each job, from a per-job generator: the same mutants whatever the worker count
    work: queue.Queue = queue.Queue()
    for j in jobs:
        work.put(j)
    results: dict = {}
    lock = threading.Lock()

    def drive(k: int):
        wk = Worker()
        while True:
            try:
                group, mode, base, kind, i = work.get_nowait()
            except queue.Empty:
                break
            gkey = "resealed" if group.startswith("resealed") else group  # both readers get the same mutants
            r = np.random.default_rng([args.seed, zlib.crc32(gkey.encode()), i])
            data = originals[base]
            if group == "hdf5_feature":
                mutant = _featured(data, r, i, d / f"f{k}.h5", d)
            else:
                mutant = seal_bytes(_resealed(data, r)) if group.startswith("resealed") else mutate(data, r)
            target = d / f"w{k}.{'h5.journal' if kind == 'journal' else 'h5'}"
            target.write_bytes(mutant)
            res = wk.run({"path": str(target), "ref": str(base), "mode": mode, "kind": kind}, args.timeout)
            res["size"] = len(mutant)
            with lock:
                results.setdefault(group, []).append(res)
        wk.close()

    t0 = time.perf_counter()
    threads = [threading.Thread(target=drive, args=(k,)) for k in range(args.workers)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    wall = time.perf_counter() - t0

    def summary(rs):
        counts = {}
        for r in rs:
            counts[r["outcome"]] = counts.get(r["outcome"], 0) + 1
        secs = np.array([r["seconds"] for r in rs])
        growth = max(rs, key=lambda r: r["rss_growth_kb"])
        examples = sorted({r["error"] for r in rs if r["outcome"] in ("crash", "hang", "other")})[:5]
        refusals = {}
        for r in rs:
            if r["outcome"] == "refused":
                key = r["error"].split(": ")[-1][:70] if "damaged" not in r["error"] else r["error"].split(
                    " is damaged")[-1][:70]
                refusals[key] = refusals.get(key, 0) + 1
        top = dict(sorted(refusals.items(), key=lambda kv: -kv[1])[:4])
        return {"mutants": len(rs), "outcomes": counts, "median_ms": float(np.median(secs) * 1e3),
                "max_ms": float(secs.max() * 1e3), "peak_rss_growth_kb": int(growth["rss_growth_kb"]),
                "isolated_child_peak_rss_kb": int(max(r["isolated_child_peak_kb"] for r in rs)),
                "file_kb": round(growth["size"] / 1024, 1), "bad_examples": examples, "top_refusals": top}

    out = {"seed": args.seed, "timeout_s": args.timeout, "workers": args.workers, "wall_s": round(wall, 1),
           "file_bytes": {"sealed": len(originals[sealed]), "version1": len(originals[v1]),
                          "journal": len(originals[journal])},
           "groups": {g: summary(rs) for g, rs in sorted(results.items())}}
    bad = {g: {k: v for k, v in s["outcomes"].items() if k in ("crash", "hang", "other", "altered")}
           for g, s in out["groups"].items() if g != "resealed_in_process_peer"}
    out["totals_excluding_peer"] = {
        "mutants": sum(s["mutants"] for g, s in out["groups"].items() if g != "resealed_in_process_peer"),
        "crash": sum(b.get("crash", 0) for b in bad.values()), "hang": sum(b.get("hang", 0) for b in bad.values()),
        "other_exception": sum(b.get("other", 0) for b in bad.values()),
        "silently_altered": sum(b.get("altered", 0) for b in bad.values()),
        "altered_flagged_unverified_version1": out["groups"].get("version1", {}).get("outcomes", {}).get(
            "altered_unverified", 0)}
    emit("fuzz_sessions", out)


if __name__ == "__main__":
    main()
