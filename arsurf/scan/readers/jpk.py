"""JPK NanoWizard image (``.jpk``, a TIFF) reader.

Library: ``tifffile`` for the TIFF structure (pages, tags, strips); the JPK layer on top is
ours because no maintained Python package reads it correctly and lightly: AFMReader pulls in
a whole stack (TopoStats dependencies) for a dozen tags, ``afmformats`` reads force curves only
and rejects ``.jpk`` images. The tag numbers follow Gwyddion's ``jpkscan.c``/``jpk.h``.

Layout: page 0 is a thumbnail and carries the grid: tags 32834/32835 (u/v length, m) and
32838/32839 (pixels). Every further 16/32-bit greyscale page is a channel: 32848 is its name,
32850 its fancy name, 32851 a property list with ``retrace : true|false``.
Calibration slots: 32896 is the number of slots, 32897 names the default one; slot ``i``
starts at tag ``32912 + 48 i``: name (+0), type (+1), parent (+2), encoder unit (+18),
scaling type (+19), multiplier (+20), offset (+21). The default slot's multiplier and offset
apply to the raw integers directly (they are not chained through the parent slots):
``z = raw * multiplier + offset`` in the slot's unit (checked in the tests: the summed
``height`` trace is 219 242 202.8 nm, AFMReader's expected value).

Orientation: TIFF rows are stored bottom line first unless the grid-reflect tag 32837 is set
(Gwyddion's reader reverses them for its top-first display), so rows are kept: row 0 = bottom.
Pixel spacing: ``dx = ulength / ilength`` (Gwyddion's convention).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from arsurf.errors import CorruptScan, require
from arsurf.scan.readers._common import (
    Channel,
    check_scale,
    check_shape,
    check_tiff_chain,
    flip_rows,
    make_scan,
    quiet_logger,
    select_channel,
    tiff_first_ifd_tags,
)

EXTENSIONS = (".jpk", ".jpk-qi-image")
FORMAT = "jpk"
TAG_ULENGTH, TAG_VLENGTH, TAG_REFLECT = 32834, 32835, 32837
TAG_ILENGTH, TAG_JLENGTH = 32838, 32839
TAG_CHANNEL, TAG_FANCY, TAG_PROPS = 32848, 32850, 32851
TAG_NSLOTS, TAG_DEFAULT_SLOT, TAG_SLOT0 = 32896, 32897, 32912


def sniff(head: bytes) -> bool:
    """True for a TIFF whose first directory has the JPK grid tags (u/v length, channel name)."""
    tags = tiff_first_ifd_tags(head)
    return TAG_ULENGTH in tags and TAG_VLENGTH in tags and (TAG_CHANNEL in tags or 32768 in tags)


def _tag(page, code, default=None):
    t = page.tags.get(code)
    return default if t is None else t.value


def _slot(path, page) -> tuple[str, float, float, str]:
    """(slot name, multiplier, offset, unit) of the page's default calibration slot."""
    n = _tag(page, TAG_NSLOTS, 0)
    default = _tag(page, TAG_DEFAULT_SLOT)
    n = int(n) if isinstance(n, (int, np.integer)) else 0
    if not (0 < n <= 64) or not isinstance(default, str):
        raise CorruptScan(f"{path}: a JPK channel page lacks its calibration slots (tags 32896/32897)")
    for i in range(n):
        base = TAG_SLOT0 + 48 * i
        if _tag(page, base) == default:
            scaling = _tag(page, base + 19, "NullScaling")
            if scaling == "NullScaling":
                return default, 1.0, 0.0, str(_tag(page, base + 18, ""))
            if scaling != "LinearScaling":
                raise CorruptScan(f"{path}: JPK slot {default!r} uses unsupported scaling {scaling!r}")
            mult, off = _tag(page, base + 20), _tag(page, base + 21, 0.0)
            if not isinstance(mult, (float, int)) or not isinstance(off, (float, int)):
                raise CorruptScan(f"{path}: JPK slot {default!r} has no numeric multiplier/offset")
            off = float(off)
            if not np.isfinite(off):
                raise CorruptScan(f"{path}: JPK slot {default!r} has offset {off!r}")
            return default, check_scale(path, mult, f"the multiplier of JPK slot {default!r}"), off, \
                str(_tag(page, base + 18, ""))
    raise CorruptScan(f"{path}: the default JPK calibration slot {default!r} is not among the {n} slots")


def read(path: Path | str, channel: str | None = None):
    """Read one channel of a JPK image (default: ``height (trace)``, else the retrace).

    Channel names are the JPK channel names with ``" (trace)"`` or ``" (retrace)"``, e.g.
    ``"height (retrace)"``, ``"measuredHeight (trace)"``.
    """
    tifffile = require("tifffile", "formats", "reading JPK .jpk images")
    check_tiff_chain(path, path)
    with quiet_logger("tifffile"), tifffile.TiffFile(str(path)) as tif:
        pages = list(tif.pages)
        if len(pages) < 2:
            raise CorruptScan(f"{path}: a JPK image needs a thumbnail page and at least one channel page")
        p0 = pages[0]
        ulen, vlen = _tag(p0, TAG_ULENGTH), _tag(p0, TAG_VLENGTH)
        if not isinstance(ulen, float) or not isinstance(vlen, float):
            raise CorruptScan(f"{path}: page 0 lacks the JPK grid size tags 32834/32835")
        chans: list[Channel] = []
        for idx, page in enumerate(pages[1:], start=1):
            name = _tag(page, TAG_CHANNEL)
            if not isinstance(name, str) or page.dtype is None or page.dtype.kind not in "iu" or len(page.shape) != 2:
                continue
            props = _tag(page, TAG_PROPS, "")
            retrace = "retrace : true" in props if isinstance(props, str) else False
            direction = "backward" if retrace else "forward"
            unit = "m" if "height" in name.lower() else ""
            chans.append(Channel(f"{name} ({'retrace' if retrace else 'trace'})", key=idx, unit=unit,
                                 direction=direction, extra={"fancy": _tag(page, TAG_FANCY)}))
        chan = select_channel(path, chans, channel)
        page = pages[chan.key]
        slot, mult, off, unit = _slot(path, page)
        ny, nx = page.shape
        check_shape(path, int(nx), int(ny))
        # tifffile fills strips that lie past the end of a truncated file with zeros: refuse
        size = tif.filehandle.size
        ends = [o + c for o, c in zip(page.dataoffsets, page.databytecounts)]
        if not ends or max(ends) > size or sum(page.databytecounts) < nx * ny * page.dtype.itemsize:
            raise CorruptScan(
                f"{path}: channel {chan.name!r} needs bytes up to {max(ends, default=0)} but the file has "
                f"{size} (truncated)"
            )
        raw = page.asarray().astype(np.float64)
        reflect = bool(_tag(p0, TAG_REFLECT, 0))
        info = {
            "software": "JPK " + str(_tag(p0, 32768, "")), "date": _tag(p0, 32771),
            "settings": _tag(p0, 32772), "mode": _tag(p0, 32816),
        }
    chan.unit = unit or chan.unit
    data = raw * mult + off
    if reflect:
        data = flip_rows(data)
    return make_scan(
        path, FORMAT, data, ulen / nx, vlen / ny, chan, chans, rows_flipped=reflect,
        instrument=info, extra={"calibration_slot": slot, "multiplier": mult, "offset": off},
    )
