"""Fuzz: damaged copies of every real scan are refused or read right, and every outcome is counted.

Each real file gets damaged variants (fixed seed) written to tmp_path: truncations, bit flips in
the header and in the whole file, overwritten byte runs, numbers of a text header made huge,
negative, zero or NaN, and one digit of such a number changed (same length, plausible-looking). Every variant is read by :func:`arsurf.load_scan` and classified
(:func:`classify`) against the intact file's reading:

- ``refused``: an :class:`arsurf.errors.ScanError` naming the file (any other exception fails);
- ``equal``: the same channel, unit, shape, spacings and bit-identical pixels (the damage missed
  what this channel needs);
- ``damaged_pixels``: the same calibration, no more pixels changed than bytes were changed (the
  damaged values themselves, read as stored);
- ``rescaled``: the same calibration, the pixels changed by one affine map (a header scale or
  offset edited), within the plausibility rules;
- ``plausible``: anything else that was accepted (another shape, spacing, channel or unit) and
  passes the plausibility rules (:func:`violations`, checked here independently of the readers);
- ``misread``: a silent misread this test can detect: a truncated file read with other pixels
  than the intact one (invented data), values outside the plausibility rules, a non-length
  channel flagged as a height, or more pixels changed than bytes changed without one affine map
  explaining them (data read from the wrong place). The test fails on any.

Memory: the Python allocations of each read (tracemalloc peak) stay below
``MEMORY_FACTOR x file size + MEMORY_SLACK``: no header field sizes an allocation on its own.
``bench/fuzz_readers.py`` runs the same mutations and classification at scale in isolated workers.
"""
from __future__ import annotations

import re
import tracemalloc
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from tests.support.real_scans import real_scan_path

from arsurf.errors import ScanError
from arsurf.scan.io import load_scan
from arsurf.scan.scan import Scan

pytestmark = pytest.mark.realscan

FILES = [
    "2024-10-24_104052_PH_wg_wv_No3_15slits_pol45deg_anal90deg_fine.gwy",
    "2024-08-21_132732_PH_pmma_wedge_on_gold_thick_1600nm_Z_raw.gsf",
    "2022-04-28_1518_PH_trivial_dose1,1_FB_horizontal_interf_synchronize_nanoFTIR_Z.gsf",
    "STM_nanonis_generic_4_5.sxm",
    "AR_20211011.ibw",
    "sample_0.jpk",
    "Veeco_20160622.003",
    "Park_20210916_034.tiff",
    "sample_0.h5-jpk",
    "sample_0_1.topostats",
    "sample_0.spm",
]
DATA = Path(__file__).resolve().parents[1] / "support" / "data"
#: the bundled samples of the readers of issue #14 section 3 (tests/support/data/SOURCES.md)
DATA_FILES = [
    "nanosurf_wavemode_excerpt.nhf",
    "ntmdt_mda_excerpt.mdt",
    "synthetic_scanned.mdt",
    "synthetic_v0.asd",
    "synthetic_v1.asd",
    "synthetic_v2.asd",
]
VARIANTS = 24
#: fewer copies of the 33.6 MB PeakForce file (each one is written and read whole); bench/fuzz_readers.py
#: runs thousands of mutants of every file in isolated worker processes
VARIANTS_BY_FILE = {"sample_0.spm": 12}

KINDS = ("truncate", "header-bits", "bits", "byte-run", "header-number", "header-digit")
OUTCOMES = ("refused", "equal", "damaged_pixels", "rescaled", "plausible", "misread")
#: plausibility limits, restated from readers/_common.py's docstring (checked here independently)
PIXEL_RANGE = (1e-13, 1e-3)
HEIGHT_LIMIT = 1e-3
#: a read may allocate (tracemalloc peak) at most this multiple of the file size, plus the slack:
#: the file's bytes, their float64 copy and the orientation/scaling/Scan copies of one channel
MEMORY_FACTOR = 16
MEMORY_SLACK = 4 << 20
_NUM = re.compile(rb"(?<![\w.])[-+]?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")
_HOSTILE = (b"999999999999", b"-1", b"0", b"nan", b"1e308", b"-2147483648", b"4294967296")


def mutate(data: bytes, rng: np.random.Generator, kind: str) -> tuple[bytes, int]:
    """One damaged copy of ``data`` and the number of bytes the damage touched. An edit that
    changes the length counts every byte after it: in binary data a shift changes every later
    value, which no reader can tell from a real one (where the format fixes the header's size,
    GSF and NanoScope, the readers refuse such files; ``header-digit`` edits keep the length and
    so keep the count strict). ``kind`` is one of :data:`KINDS`."""
    b = bytearray(data)
    n = len(b)
    if kind == "truncate":
        cut = int(rng.integers(0, n))
        return bytes(b[:cut]), n - cut
    if kind in ("header-bits", "bits"):  # in the first 4 KiB, or anywhere
        span, most = (min(n, 4096), 8) if kind == "header-bits" else (n, 32)
        hit = set()
        for _ in range(int(rng.integers(1, most))):
            i = int(rng.integers(0, span))
            b[i] ^= 1 << int(rng.integers(0, 8))
            hit.add(i)
        return bytes(b), len(hit)
    if kind == "byte-run":
        i, k = int(rng.integers(0, n)), int(rng.integers(1, 64))
        b[i : i + k] = rng.integers(0, 256, k, dtype=np.uint8).tobytes()
        return bytes(b), k
    if kind in ("header-number", "header-digit"):  # a number in the first 64 KiB (a text header's field)
        nums = list(_NUM.finditer(bytes(b[: 1 << 16])))
        if not nums:
            return mutate(data, rng, "bits")
        m = nums[int(rng.integers(0, len(nums)))]
        if kind == "header-number":  # made huge, negative, zero or NaN
            new = _HOSTILE[int(rng.integers(0, len(_HOSTILE)))]
            b[m.start() : m.end()] = new
            shifted = len(new) != m.end() - m.start()
            return bytes(b), (len(b) - m.start()) if shifted else len(new)
        # one digit changed to another: the same length, a plausible-looking wrong value
        digits = [i for i in range(m.start(), m.end()) if chr(b[i]).isdigit()]
        i = digits[int(rng.integers(0, len(digits)))]
        b[i] = ord("0") + (b[i] - ord("0") + int(rng.integers(1, 10))) % 10
        return bytes(b), 1
    raise ValueError(kind)


def violations(scan: Scan) -> list[str]:
    """What makes ``scan`` impossible for an AFM reading (empty list: plausible)."""
    out = []
    h = scan.heights
    for name, v in (("dx", scan.dx), ("dy", scan.dy)):
        if not (np.isfinite(v) and PIXEL_RANGE[0] <= v <= PIXEL_RANGE[1]):
            out.append(f"{name} = {v!r} m")
    if h.ndim != 2 or h.dtype != np.float64:
        out.append(f"heights {h.dtype} of shape {h.shape}")
    if np.isinf(h).any():
        out.append("infinite pixels")
    if not np.isfinite(h).any():
        out.append("no finite pixel")
    unit = scan.metadata.get("z_unit")
    if unit == "m" and np.isfinite(h).any() and np.nanmax(np.abs(h)) > HEIGHT_LIMIT:
        out.append(f"|z| up to {np.nanmax(np.abs(h)):g} m")
    if unit != "m" and scan.metadata.get("height"):
        out.append(f"a channel in {unit!r} flagged as a height")
    return out


def _affine_outliers(a: np.ndarray, b: np.ndarray) -> int | None:
    """Pixels that do not follow one affine map b = s a + t (s != 0) fitted to the rest, or None
    when no such map exists (fewer than 2 distinct values)."""
    ok = np.isfinite(a) & np.isfinite(b)
    if np.count_nonzero(ok) < 2 or np.ptp(a[ok]) == 0:
        return None
    x, y = a[ok], b[ok]
    # a start that a few wild pixels cannot drag (Theil-Sen: median slope over pixel pairs), then
    # least squares on the pixels it explains, twice
    i = np.random.default_rng(0).integers(0, x.size, size=(2, min(4000, x.size * 4)))
    dx = x[i[0]] - x[i[1]]
    pick = dx != 0
    if not pick.any():
        return None
    s = float(np.median((y[i[0]] - y[i[1]])[pick] / dx[pick]))
    t = float(np.median(y - s * x))
    for _ in range(2):
        resid = np.abs(s * x + t - y)
        keep = resid <= 1e-9 * max(np.abs(y).max(), 1e-300) + 1e-9 * abs(t)
        if keep.sum() < 2:
            return None
        s, t = np.polyfit(x[keep], y[keep], 1)
    resid = np.abs(s * x + t - y)
    keep = resid <= 1e-9 * max(np.abs(y).max(), 1e-300) + 1e-9 * abs(t)
    if s == 0.0:
        return None
    return int(np.count_nonzero(~keep) + np.count_nonzero(np.isfinite(a) != np.isfinite(b)))


def classify_values(a: np.ndarray, b: np.ndarray, kind: str, changed: int) -> tuple[str, str]:
    """(outcome, reason) of values ``b`` read from a mutant whose intact reading is ``a`` (same
    shape, same calibration): ``equal``, ``damaged_pixels``, ``rescaled`` or ``misread``."""
    if np.array_equal(a, b, equal_nan=True):
        return "equal", ""
    if kind == "truncate":
        return "misread", "a truncated file was read with other values than the intact one (invented data)"
    differ = int(np.count_nonzero(~((a == b) | (np.isnan(a) & np.isnan(b)))))
    if differ <= changed:
        return "damaged_pixels", f"{differ} pixels changed by {changed} changed bytes"
    outliers = _affine_outliers(a, b)
    if outliers is not None and outliers <= changed:
        return "rescaled", f"one affine map, {outliers} other pixels"
    return "misread", f"{differ} pixels changed by only {changed} changed bytes, not by one scale (data read from " \
                      "the wrong place)"


def classify(original: Scan, scan: Scan, kind: str, changed: int) -> tuple[str, str]:
    """(outcome, reason) of an accepted mutant read as ``scan`` (see the module docstring)."""
    bad = violations(scan)
    if bad:
        return "misread", "implausible: " + ", ".join(bad)
    same = (scan.channel == original.channel and scan.shape == original.shape and scan.dx == original.dx
            and scan.dy == original.dy and scan.metadata.get("z_unit") == original.metadata.get("z_unit"))
    if same:
        return classify_values(original.heights, scan.heights, kind, changed)
    if kind == "truncate":
        return "misread", "a truncated file was read with another calibration than the intact one"
    return "plausible", "another calibration, within the plausibility rules"


def read_mutant(path, original: Scan, kind: str, changed: int) -> tuple[str, str, int]:
    """Read ``path`` and classify it: (outcome, reason, tracemalloc peak in bytes)."""
    tracemalloc.start()
    try:
        try:
            scan = load_scan(path)
        except ScanError as exc:
            assert str(path) in str(exc) or path.name in str(exc), f"message does not name the file: {exc}"
            assert "\n" not in str(exc), f"not one line: {exc}"
            return "refused", type(exc).__name__, tracemalloc.get_traced_memory()[1]
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    return (*classify(original, scan, kind, changed), peak)


@pytest.mark.slow
@pytest.mark.parametrize("name", FILES + DATA_FILES)
def test_damaged_copies_are_refused_or_read_right(tmp_path, name):
    src = DATA / name if name in DATA_FILES else real_scan_path(name)
    data = src.read_bytes()
    rng = np.random.default_rng(sum(map(ord, name)))
    intact = load_scan(src)
    counts: Counter = Counter()
    misreads, peaks = [], []
    for k in range(VARIANTS_BY_FILE.get(name, VARIANTS)):
        kind = KINDS[k % len(KINDS)]
        mutant, changed = mutate(data, rng, kind)
        p = tmp_path / f"v{k}{src.suffix}"
        p.write_bytes(mutant)
        outcome, reason, peak = read_mutant(p, intact, kind, changed)
        counts[outcome] += 1
        peaks.append(peak / max(len(mutant), 1))
        if outcome == "misread":
            misreads.append(f"variant {k} ({kind}): {reason}")
        assert peak <= MEMORY_FACTOR * len(mutant) + MEMORY_SLACK, \
            f"variant {k} ({kind}) allocated {peak} bytes for a {len(mutant)}-byte file"
        p.unlink()
    print(f"{name}: {dict(counts)}; max allocation {max(peaks):.2f} x file size")
    assert sum(counts.values()) == VARIANTS_BY_FILE.get(name, VARIANTS)
    assert not misreads, f"{name}: silent misreads: {misreads}"
    if name not in VARIANTS_BY_FILE:
        # in the 33.6 MB PeakForce file the header is 0.2 % of the bytes and most of its numbers are
        # unused, so a dozen random mutants can all be harmless; bench/fuzz_readers.py covers it at scale
        assert counts["refused"] > 0


def test_the_classification_catches_the_misreads_it_claims_to():
    """A shifted read, invented pixels and implausible values are 'misread'; a rescale, damaged
    pixels and an intact read are not."""
    rng = np.random.default_rng(3)
    h = rng.normal(size=(16, 16)) * 1e-9
    base = Scan(h, dx=1e-9, dy=1e-9, metadata={"z_unit": "m", "height": True})

    def variant(heights, **meta):
        return Scan(heights, dx=1e-9, dy=1e-9, metadata={"z_unit": "m", "height": True, **meta})

    assert classify(base, variant(h), "bits", 4)[0] == "equal"
    one = h.copy()
    one[3, 4] = 7e-9
    assert classify(base, variant(one), "bits", 1)[0] == "damaged_pixels"
    assert classify(base, variant(one), "truncate", 0)[0] == "misread"
    assert classify(base, variant(2.5 * h + 1e-9), "header-number", 3)[0] == "rescaled"
    assert classify(base, variant(np.roll(h, 1)), "header-bits", 2)[0] == "misread"
    assert classify(base, variant(h * 1e7), "header-number", 3)[0] == "misread"  # |z| ~ 0.03 m
    assert classify(base, variant(h, z_unit="V"), "bits", 1)[0] == "misread"  # volts flagged as a height
    assert classify(base, Scan(h, dx=2e-9, dy=1e-9, metadata={"z_unit": "m"}), "bits", 1)[0] == "plausible"


HDF5_FILES = ["sample_0_1.topostats", "sample_0.h5-jpk"]


@pytest.mark.parametrize("seed", range(4))
def test_hdf5_feature_mutants_are_refused_naming_the_feature(tmp_path, seed):
    """The HDF5-feature mutations of bench/fuzz_readers.py, a seeded small sample: a feature that
    reaches outside the file, planted in a random dataset of a random HDF5 scan, is refused."""
    import shutil

    import h5py
    from tests.support.hdf5_attacks import KINDS as FEATURES
    from tests.support.hdf5_attacks import plant

    rng = np.random.default_rng([20261127, seed])
    files = [real_scan_path(n) for n in HDF5_FILES] + [DATA / "nanosurf_wavemode_excerpt.nhf"]
    src = files[int(rng.integers(len(files)))]
    dst = tmp_path / src.name
    shutil.copy(src, dst)
    with h5py.File(dst, "r") as f:
        names: list[str] = []
        f.visititems(lambda n, o: names.append(n) if isinstance(o, h5py.Dataset) else None)
    feature = sorted(FEATURES)[int(rng.integers(len(FEATURES)))]
    if feature == "external_storage_fifo":
        feature = "external_storage"  # the FIFO case needs a guard process: tests/sessions/test_hdf5_safety.py has it
    words = plant(dst, names[int(rng.integers(len(names)))], feature, tmp_path)
    with pytest.raises(ScanError, match=words):
        load_scan(dst)
