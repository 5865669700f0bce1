"""Fuzz: truncated and bit-flipped copies of every real file must give a ScanError or a valid Scan.

Never a raw exception from a parser, never a hang, never invented data (a truncated file that
still loads must give the original pixels): each real file gets 20 damaged variants
(fixed seed) written to tmp_path: truncations, bit flips in the header and in the whole file,
overwritten byte runs and header numbers made huge, negative, zero or NaN. The loader must
raise only :class:`arsurf.errors.ScanError` subclasses (or return a Scan whose heights are 2-D float64 with at least one finite pixel and
whose spacings are positive).
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from conftest import real_scan_path

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
DATA = Path(__file__).resolve().parent / "data"
#: the bundled samples of the readers of issue #14 section 3 (tests/data/SOURCES.md)
DATA_FILES = [
    "nanosurf_wavemode_excerpt.nhf",
    "ntmdt_mda_excerpt.mdt",
    "synthetic_scanned.mdt",
    "synthetic_v0.asd",
    "synthetic_v1.asd",
    "synthetic_v2.asd",
]
VARIANTS = 20
#: fewer copies of the 33.6 MB PeakForce file (each one is written and read whole); bench/fuzz_readers.py
#: runs thousands of mutants of every file in isolated worker processes
VARIANTS_BY_FILE = {"sample_0.spm": 12}


KINDS = 5
_NUM = re.compile(rb"(?<![\w.])[-+]?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")


def damaged(data: bytes, rng: np.random.Generator, k: int) -> bytes:
    b = bytearray(data)
    kind = k % KINDS
    if kind == 0:  # truncation anywhere
        return bytes(b[: int(rng.integers(0, len(b)))])
    if kind == 1:  # bit flips in the header (first 4 KiB)
        for _ in range(int(rng.integers(1, 8))):
            i = int(rng.integers(0, min(len(b), 4096)))
            b[i] ^= 1 << int(rng.integers(0, 8))
    elif kind == 2:  # bit flips anywhere
        for _ in range(int(rng.integers(1, 32))):
            i = int(rng.integers(0, len(b)))
            b[i] ^= 1 << int(rng.integers(0, 8))
    elif kind == 3:  # a run of random bytes
        i, n = int(rng.integers(0, len(b))), int(rng.integers(1, 64))
        b[i : i + n] = rng.integers(0, 256, n, dtype=np.uint8).tobytes()
    else:  # a number in the first 64 KiB (a text header's field) made huge, negative, zero or NaN
        nums = list(_NUM.finditer(bytes(b[: 1 << 16])))
        if nums:
            m = nums[int(rng.integers(0, len(nums)))]
            b[m.start() : m.end()] = [b"999999999999", b"-1", b"0", b"nan", b"1e308"][int(rng.integers(0, 5))]
    return bytes(b)


@pytest.mark.parametrize("name", FILES + DATA_FILES)
def test_damaged_copies_raise_only_scan_errors(tmp_path, name):
    src = DATA / name if name in DATA_FILES else real_scan_path(name)
    data = src.read_bytes()
    rng = np.random.default_rng(sum(map(ord, name)))
    intact = load_scan(src).heights
    outcomes = {"ok": 0, "error": 0}
    for k in range(VARIANTS_BY_FILE.get(name, VARIANTS)):
        p = tmp_path / f"v{k}{src.suffix}"
        p.write_bytes(damaged(data, rng, k))
        try:
            scan = load_scan(p)
        except ScanError as exc:
            assert str(p) in str(exc) or p.name in str(exc), f"message does not name the file: {exc}"
            outcomes["error"] += 1
            continue
        assert isinstance(scan, Scan) and scan.heights.ndim == 2 and scan.heights.dtype == np.float64
        assert np.isfinite(scan.heights).any() and scan.dx > 0 and scan.dy > 0
        if k % KINDS == 0:
            # a truncated file may still hold the whole default channel (the tail was a note or
            # another channel), but a reader must never invent the missing bytes
            np.testing.assert_array_equal(scan.heights, intact)
        outcomes["ok"] += 1
    if name not in VARIANTS_BY_FILE:
        # in the 33.6 MB PeakForce file the header is 0.2 % of the bytes and most of its numbers are
        # unused, so a dozen random mutants can all be harmless; bench/fuzz_readers.py covers it at scale
        assert outcomes["error"] > 0
