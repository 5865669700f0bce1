"""Writers of small files by the formats' own layouts, for the formats whose public real samples
cannot be bundled (see tests/support/data/SOURCES.md): NT-MDT scanned-image frames (no public sample
found; layout of Gwyddion's ``nt-mdt.c``) and high-speed AFM ``.asd`` versions 0, 1 and 2
(AFMReader's real samples are GPL and 16-37 MB; layout of libasd and AFMReader).

Each writer stores known raw values with known scales, so a test can compute the expected
physical values independently of the reader. ``python tests/support/format_samples.py`` rewrites the
synthetic samples of tests/support/data (``test_new_formats.py`` checks they are up to date).
"""
from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

DATA = Path(__file__).resolve().parent / "data"

#: asd channel kind codes
TP, ER, PH = 0x5054, 0x5245, 0x4850


def mdt_scanned_frame(raw: np.ndarray, *, title: str = "Height", x_step: float = 2.0, y_step: float = 2.0,
                      xy_unit: int = -1, z_offset: float = 0.0, z_step: float = 0.01, z_unit: int = -1,
                      adc: int = 0, var_size: int = 107, when=(2019, 5, 6, 7, 8, 9)) -> bytes:
    """One scanned-data frame (type 0): axis scales, ADC mode, sizes, int16 data bottom line
    first, cp1251 title. Units are NT-MDT codes (-1 nm, -2 um, 0 Angstrom, 2 V...)."""
    ny, nx = raw.shape
    var = bytearray(var_size)
    struct.pack_into("<ffhffhffh", var, 0, 0.0, x_step, xy_unit, 0.0, y_step, xy_unit, z_offset, z_step, z_unit)
    struct.pack_into("<BBHH", var, 30, adc, 1, nx, ny)
    mode = struct.pack("<4H", 0, nx, ny, 0)
    data = np.asarray(raw, dtype="<i2").tobytes()
    t = title.encode("cp1251")
    body = bytes(var) + mode + data + struct.pack("<I", len(t)) + t + struct.pack("<I", 0)
    size = 22 + len(body)
    head = struct.pack("<IH", size, 0) + bytes([1, 0]) + struct.pack("<6H", *when) + struct.pack("<H", var_size)
    return head + body


def mdt_text_frame(text: str = "synthetic") -> bytes:
    """A text frame (type 3): not an image, skipped by readers."""
    body = struct.pack("<I", 0) * 4 + text.encode("utf-16-le")
    var = 10
    return struct.pack("<IH", 22 + var + len(body), 3) + bytes([3, 7]) + struct.pack("<6H", 2020, 1, 1, 0, 0, 0) + \
        struct.pack("<H", var) + bytes(var) + body


def mdt_file(frames: list[bytes]) -> bytes:
    """An ``.mdt`` file: the 33-byte header (magic, size without header, last frame index) and the frames."""
    body = b"".join(frames)
    head = bytearray(33)
    head[:4] = b"\x01\xb0\x93\xff"
    struct.pack_into("<I", head, 4, len(body))
    struct.pack_into("<H", head, 12, len(frames) - 1)
    return bytes(head) + body


def asd_file(version: int, channels: list[tuple[int, list[np.ndarray]]], *, x_nm: int = 200, y_nm: int = 100,
             ad_range: int = 0x40000, bits: int = 12, z_gain: float = 2.0, z_extension: float = 45.0,
             error_sensitivity: float = 8.5, phase_sensitivity: float = 1.5, frame_time: float = 100.0,
             operator: bytes = b"arsurf", comment: bytes = b"synthetic sample", comment_offset: int = 16) -> bytes:
    """An ``.asd`` movie: ``channels`` = [(kind code, [frame int16 arrays (ny, nx)])]."""
    kinds = [k for k, _ in channels] + [0] * (2 - len(channels))
    frames0 = channels[0][1]
    ny, nx = frames0[0].shape
    nf = len(frames0)
    if version == 0:
        fixed = struct.pack("<ihhiiiiihhhhfffIi", 0, kinds[0], kinds[1], 0, 32, len(operator), comment_offset,
                            len(comment), nx, ny, x_nm, y_nm, frame_time, z_extension, z_gain, ad_range, bits)
        fixed += struct.pack("<?ih", True, 1, 0) + struct.pack("<h5BB", 2022, 7, 15, 16, 44, 10, 15)
        fixed += struct.pack("<ff3i", 9900.0, 4500.0, 0, 0, 0) + struct.pack("<iiih", nf, nf, 0, 1110)
        assert len(fixed) == 105
        head = fixed + operator + struct.pack("<ffi", error_sensitivity, phase_sensitivity, 0)
        head = head[:8] + struct.pack("<i", len(head)) + head[12:]
        head += bytes(comment_offset) + comment
    else:
        fixed = struct.pack("<i", version) + struct.pack("<15i", 0, 32, 932, len(operator), len(comment), kinds[0],
                                                         kinds[1], nf, nf, 1, 10, nx, ny, x_nm, y_nm)
        fixed += struct.pack("<?i6i2i", True, 1, 2021, 3, 5, 18, 28, 0, 10, 1)
        fixed += struct.pack("<fffi", frame_time, error_sensitivity, phase_sensitivity, 0) + bytes(12)
        fixed += struct.pack("<iIi", 2, ad_range, bits) + struct.pack("<6f", 867.0, 3345.0, 8.67, 33.45, z_extension,
                                                                       z_gain)
        assert len(fixed) == 165
        head = fixed + operator + comment
        if version == 2:
            head += struct.pack("<iiidii3i", nf, 0, 0, 0.0, 4095, 0, 1, 1, 1) + struct.pack("<6i", 0, 0, 0, 4095,
                                                                                             4095, 4095)
        head = head[:4] + struct.pack("<i", len(head)) + head[8:]
    out = bytearray(head)
    for _, frames in channels:
        for k, img in enumerate(frames):
            fr = np.asarray(img, dtype="<i2")
            out += struct.pack("<ihhhhff?bhii", k + 1, int(fr.max()), int(fr.min()), 0, 0, 0.0, 0.0, False, 0, 0, 0,
                               0)
            out += fr.tobytes()
    return bytes(out)


def asd_frames(nx: int = 24, ny: int = 16, nf: int = 3, seed: int = 7) -> list[np.ndarray]:
    """Frames of a tilted bump that moves, as 12-bit A/D levels."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:ny, 0:nx]
    out = []
    for k in range(nf):
        bump = 900.0 * np.exp(-((x - 6 - 4 * k) ** 2 + (y - 8) ** 2) / 12.0)
        out.append((1500 + 20 * x + 7 * y + bump + rng.integers(-3, 4, (ny, nx))).astype(np.int16))
    return out


def samples() -> dict[str, bytes]:
    """The synthetic samples kept in tests/support/data, by file name."""
    rng = np.random.default_rng(11)
    y, x = np.mgrid[0:40, 0:48]
    height = (300 * np.sin(x / 5.0) + 40 * y + rng.integers(-20, 21, (40, 48))).astype(np.int16)
    phase = (1000 * np.cos(y / 4.0)).astype(np.int16)
    mdt = mdt_file([mdt_text_frame(),
                    mdt_scanned_frame(height, title="Height", x_step=12.5, y_step=25.0, xy_unit=-1,
                                      z_offset=-50.0, z_step=0.02, z_unit=-1),
                    mdt_scanned_frame(phase, title="Phase", x_step=12.5, y_step=25.0, xy_unit=-1, z_offset=0.0,
                                      z_step=0.05, z_unit=5, adc=11)])
    tp, ph = asd_frames(), [f // 3 for f in asd_frames(seed=9)]
    return {
        "synthetic_scanned.mdt": mdt,
        "synthetic_v0.asd": asd_file(0, [(TP, tp), (PH, ph)]),
        "synthetic_v1.asd": asd_file(1, [(TP, tp), (ER, ph)]),
        "synthetic_v2.asd": asd_file(2, [(TP, tp)]),
    }


if __name__ == "__main__":
    for name, blob in samples().items():
        (DATA / name).write_bytes(blob)
        print(DATA / name, len(blob))
