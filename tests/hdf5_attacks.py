"""HDF5 features that make a small file stand for other data, planted with h5py as an attacker would.

Used by tests/test_hdf5_safety.py and the HDF5-feature mutations of bench/fuzz_readers.py and
bench/fuzz_sessions.py. :func:`plant` rewrites one dataset of a file in place (its user block,
so a session's seal slot, is kept); :func:`reseal_session` then redoes a session's checksums and
seal over what the planted dataset reads as, so only the content rules can refuse it.
"""
from __future__ import annotations

import json
import os
from pathlib import Path

import h5py
import numpy as np

#: kind -> the words the refusal must contain (the feature named)
KINDS = {
    "external_storage": "external storage",
    "external_storage_fifo": "external storage",
    "external_link": "external link",
    "virtual_dataset": "virtual dataset",
    "huge_declared": "declares",
    "dangling_soft_link": "soft link",
    "unexpected_filter": "filter",
}
#: a file outside the one read, that every Unix system has
OUTSIDE = "/etc/passwd"


def _other_file(workdir: Path, shape, dtype) -> Path:
    other = Path(workdir) / "other.h5"
    with h5py.File(other, "w") as g:
        g.create_dataset("data", data=np.full(shape, 7, dtype=dtype))
    return other


def make_fifo(workdir: Path) -> Path:
    fifo = Path(workdir) / "pipe"
    if not fifo.exists():
        os.mkfifo(fifo)
    return fifo


def plant(path: str | os.PathLike, target: str, kind: str, workdir: str | os.PathLike) -> str:
    """Replace dataset ``target`` of the HDF5 file ``path`` by the feature ``kind`` (same name,
    shape and dtype where the feature allows); return the words its refusal must contain."""
    workdir = Path(workdir)
    with h5py.File(path, "r+") as f:
        ds = f[target]
        shape, dtype = ds.shape or (1,), ds.dtype  # a scalar becomes one element: h5py stores no scalar externally
        old = np.asarray(ds[()]).reshape(shape)
        attrs = {k: v for k, v in ds.attrs.items()}
        del f[target]
        if kind in ("external_storage", "external_storage_fifo"):
            src = OUTSIDE if kind == "external_storage" else str(make_fifo(workdir))
            new = f.create_dataset(target, shape=shape, dtype=dtype, external=[(src, 0, h5py.h5f.UNLIMITED)])
        elif kind == "external_link":
            f[target] = h5py.ExternalLink(str(_other_file(workdir, shape, dtype)), "/data")
            new = None
        elif kind == "virtual_dataset":
            layout = h5py.VirtualLayout(shape=shape, dtype=dtype)
            layout[...] = h5py.VirtualSource(str(_other_file(workdir, shape, dtype)), "data", shape=shape)
            new = f.create_virtual_dataset(target, layout)
        elif kind == "huge_declared":  # unwritten elements: a read fills them, the file holds none
            row = int(np.prod(shape[1:], dtype=np.int64)) * dtype.itemsize if len(shape) > 1 else dtype.itemsize
            n = max(1 << 28, 64 * os.path.getsize(path)) // max(row, 1)
            new = f.create_dataset(target, shape=(n, *shape[1:]), dtype=dtype)
        elif kind == "dangling_soft_link":
            f[target] = h5py.SoftLink("/nowhere/at/all")
            new = None
        elif kind == "unexpected_filter":  # scale-offset (HDF5 filter 6): built in, but no format of ours uses it
            data = np.asarray(old)
            chunks = tuple(max(1, min(s, 64)) for s in shape)
            new = f.create_dataset(target, data=data, chunks=chunks,
                                   scaleoffset=0 if dtype.kind in "iu" else 6)
        else:
            raise ValueError(f"unknown kind {kind!r}; kinds: {sorted(KINDS)}")
        if new is not None:
            for k, v in attrs.items():
                new.attrs[k] = v
    return KINDS[kind]


def set_recorded_scan(path: str | os.PathLike, scan: str) -> None:
    """Make a session name another scan file (its metadata edited, checksums and seal redone)."""
    with h5py.File(path, "r+") as f:
        meta = json.loads(f["metadata"].attrs["scan"])
        meta["path"] = scan
        f["metadata"].attrs["scan"] = json.dumps(meta, sort_keys=True)
    reseal_session(path)


def reseal_session(path: str | os.PathLike) -> None:
    """Redo a session's checksums (its metadata, and what each dataset reads as where it can be read
    without blocking or allocating gigabytes) and its seal: the bytes are then 'intact'."""
    from arsurf.sessions.sealed import seal_file
    from arsurf.sessions.schema import _array_digest, _canonical, _sha

    with h5py.File(path, "r+") as f:
        sums = json.loads(f.attrs["checksums"])
        texts = {k: v.decode() if isinstance(v, bytes) else str(v) for k, v in f["metadata"].attrs.items()}
        sums["metadata"] = _sha(_canonical(texts))
        for name in f["ticks"]:
            link = f["ticks"].get(name, getlink=True)
            obj = f["ticks"].get(name)
            if obj is None or not isinstance(link, (h5py.HardLink, h5py.ExternalLink)):
                continue
            plist = obj.id.get_create_plist()
            fifo = plist.get_external_count() and "pipe" in str(plist.get_external(0)[0])
            if fifo or obj.size * obj.dtype.itemsize > (1 << 26):
                continue
            sums[f"ticks/{name}"] = _array_digest(np.asarray(obj[()]))
        f.attrs["checksums"] = json.dumps(sums, sort_keys=True)
    seal_file(path)
