"""Writers of small synthetic scan files in the NanoScope, WSxM and Nanosurf NID layouts (each
following the format's documented layout), for the readers' tests."""
from __future__ import annotations


import numpy as np


def write_nanoscope(path, raw_images, *, hard_value=41.60368, sens_nm_per_v=7.0, size_um=1.5, bpp=2,
                    names=("Height", "Amplitude"), directions=("Trace", "Retrace")):
    """A NanoScope v5-style file: header lists, then the images (bottom line first)."""
    ny, nx = raw_images[0].shape
    header_len = 8192
    lines = [
        "\\*File list", "\\Version: 0x05310001", "\\Date: 11:43:26 AM Wed Jun 22 2016",
        f"\\Data length: {header_len}", "\\*Equipment list", "\\Description: synthetic MultiMode",
        "\\*Scanner list", f"\\@Sens. Zscan: V {sens_nm_per_v:.6f} nm/V", "\\*Ciao scan list",
        f"\\Scan size: {size_um * 1000:.2f} nm", "\\Samps/line: %d" % nx, "\\Lines: %d" % ny,
    ]
    offset = header_len
    for img, name, d in zip(raw_images, names, directions):
        zs = (f"V [Sens. Zscan] (0.006539403 V/LSB) {hard_value:.5f} V" if name == "Height"
              else "V (0.0003051758 V/LSB) 2.500000 V")
        lines += [
            "\\*Ciao image list", f"\\Data offset: {offset}", f"\\Data length: {nx * ny * bpp}",
            f"\\Bytes/pixel: {bpp}", f"\\Samps/line: {nx}", f"\\Number of lines: {ny}",
            f"\\Scan size: {size_um} {size_um} ~m", f"\\Line direction: {d}",
            f'\\@2:Image Data: S [{name}] "{name}"', f"\\@2:Z scale: {zs}",
            "\\@2:Z offset: V [Sens. Zscan] (0.006539403 V/LSB)       0 V",
        ]
        offset += nx * ny * bpp
    lines.append("\\*File list end")
    head = ("\r\n".join(lines) + "\r\n").encode("latin-1") + b"\x1a"
    assert len(head) < header_len
    body = b"".join(np.asarray(img, dtype=f"<i{bpp}").tobytes() for img in raw_images)
    path.write_bytes(head.ljust(header_len, b"\x00") + body)


def write_wsxm(path, data, *, kind="double", zamp="12.5 nm", xamp="2 \u00b5m", yamp="1 \u00b5m"):
    ny, nx = data.shape
    body = ["[Control]", f"    X Amplitude: {xamp}", f"    Y Amplitude: {yamp}", "",
            "[General Info]", f"    Image Data Type: {kind}", f"    Number of columns: {nx}",
            f"    Number of rows: {ny}", f"    Z Amplitude: {zamp}", "    Acquisition channel: Topography", "",
            "[Header end]", ""]
    text = "\r\n".join(body)
    for size in range(len(text) + 100, len(text) + 200):
        head = f"WSxM file copyright UAM\r\nSxM Image file\r\nImage header size: {size}\r\n" + text
        raw = head.encode("latin-1")
        if len(raw) <= size:
            raw = raw.ljust(size, b" ")
            break
    dt = {"double": "<f8", "short": "<i2"}[kind]
    path.write_bytes(raw + np.asarray(data, dtype=dt).tobytes())


def write_nid(path, images, *, bits=16, zmin=-1e-6, zrange=2e-6, xr=5e-6, yr=4e-6):
    """images: list of (frame, channel, raw int array); one group per frame."""
    frames = []
    for f, _, _ in images:
        if f not in frames:
            frames.append(f)
    ds = ["[DataSet]", "Version=2", f"GroupCount={len(frames)}"]
    sections = []
    k = 0
    for g, f in enumerate(frames):
        members = [(c, a) for ff, c, a in images if ff == f]
        ds += [f"Gr{g}-Name={f}", f"Gr{g}-ID={g}", f"Gr{g}-Count={len(members)}"]
        for c_i, (c, a) in enumerate(members):
            key = f"DataSet-{g}:{c_i + 1}"
            ds.append(f"Gr{g}-Ch{c_i}={key}")
            ny, nx = a.shape
            sections.append([f"[{key}]", "Version=2", f"Points={nx}", f"Lines={ny}", f"Frame={f}",
                             f"SaveBits={bits}", "SaveSign=Signed", "Dim0Name=X*", "Dim0Unit=m", "Dim0Min=0",
                             f"Dim0Range={xr}", "Dim1Name=Y*", "Dim1Unit=m", "Dim1Min=0", f"Dim1Range={yr}",
                             f"Dim2Name={c}", "Dim2Unit=m", f"Dim2Min={zmin}", f"Dim2Range={zrange}"])
            k += 1
    text = "\r\n".join(ds) + "\r\n\r\n" + "\r\n\r\n".join("\r\n".join(s) for s in sections) + "\r\n\r\n"
    body = b"".join(np.asarray(a, dtype=f"<i{bits // 8}").tobytes() for _, _, a in images)
    path.write_bytes(text.encode("latin-1") + b"#!" + body)
