r"""HDF5 files read as their own bytes only: the one way arsurf opens an HDF5 file.

libhdf5 can make a small file stand for other data: *external storage* (a dataset whose values
are read from another file named in its header, ``/etc/passwd`` or a FIFO that blocks the reader
forever), *external links* and *virtual datasets* (objects or values taken from other HDF5 files),
soft links to wherever, filters loaded from plugins, and a dataset declaring billions of unwritten
elements that reading fills (a 2 kB file asking for 2 GB). Every HDF5 read of arsurf (scan
readers ``.topostats``, ``.nhf``, ``.h5-jpk``, sessions, replay outputs, batch runs) goes through
:func:`open_hdf5`, which:

1. reads the file with :func:`arsurf._files.read_regular` (a FIFO, device or directory is
   refused without blocking) and hands libhdf5 the *bytes in memory* (a file image for its core
   driver, ``backing_store`` off), so it parses exactly the bytes that were read and opens no file
   for them;
2. walks the whole tree, without following any link, before the caller sees the file
   (:func:`check_tree`), and refuses, naming the feature and the object:

   - an **external link** and any user-defined link class;
   - a **soft link** that leaves the expected tree (``tree``) or names nothing, or any soft link
     where the format has none (sessions: ``soft_links=False``);
   - a dataset with **external storage** or a **virtual** layout;
   - a dataset with a **filter** not in :data:`ALLOWED_FILTERS` (deflate, shuffle, fletcher32:
     what the supported formats use; anything else would make libhdf5 look for a plugin);
   - a dataset whose values are not all **stored** (``prod(shape) * itemsize`` above the bytes
     it stores, or above :data:`GZIP_LIMIT` times them when deflated): reading would fill
     elements that were never written, the way a 2 kB file asks for 2 GB;
   - **declared sizes** above ``max_expansion`` times the file's size: every dataset's
     ``prod(shape) * itemsize``, each and in total, so no read of the file allocates more than
     that (an attribute's value is stored whole in its object's header, bytes of the file, which
     libhdf5 bounds-checks when it decodes it). Scans use :data:`MAX_EXPANSION` (16x, the rule the binary readers follow,
     :mod:`arsurf.scan.readers._common`); sessions, whose unused columns are constant and
     gzip-compressed, allow :data:`GZIP_LIMIT` (a 100,000-tick session holding only times and
     positions declares 82x its file), still with every value stored.

Errors are raised as the caller's family (``error``: ``CorruptScan`` for scans, ``SessionError``
for sessions), one line naming the feature. The checks read only object headers: well under a
second for the files arsurf reads (docs/safety.rst gives the measured times).

Examples
--------
>>> import tempfile, os, h5py, numpy as np
>>> d = tempfile.mkdtemp()
>>> p = os.path.join(d, "ok.h5")
>>> with h5py.File(p, "w") as f:
...     _ = f.create_dataset("image", data=np.zeros((4, 4)))
>>> with open_hdf5(p, "scan") as f:
...     f["image"].shape
(4, 4)
>>> with h5py.File(p, "a") as f:
...     f["outside"] = h5py.ExternalLink("other.h5", "/image")
>>> open_hdf5(p, "scan")
Traceback (most recent call last):
...
arsurf.errors.UnsafeFile: scan ...: /outside is an HDF5 external link (to 'other.h5':/image); ...
"""
from __future__ import annotations

import os
import posixpath

from arsurf._files import read_regular
from arsurf.errors import ArsurfError, UnsafeFile, require

__all__ = ["open_hdf5", "check_tree", "MAX_EXPANSION", "GZIP_LIMIT", "ALLOWED_FILTERS"]

#: no dataset (each, and all together) may declare more bytes than this times the file
MAX_EXPANSION = 16
#: the HDF5 filters the supported formats use (HDF5 filter ids); any other is refused
ALLOWED_FILTERS = {1: "deflate (gzip)", 2: "shuffle", 3: "fletcher32"}
#: the most deflate (gzip) can inflate a stored byte (its limit is 1032:1)
GZIP_LIMIT = 1100
#: objects (groups, datasets, named types) one file may hold: each costs header bytes anyway
MAX_OBJECTS = 200_000


def _h5py():
    return require("h5py", "core", "HDF5 files")


def open_hdf5(source, what: str = "HDF5 file", *, error: type[ArsurfError] = UnsafeFile,
              soft_links: bool = True, tree: str = "/", max_expansion: float = MAX_EXPANSION,
              name: str | None = None):
    """Open an HDF5 file from its bytes in memory, after refusing what reaches outside them.

    Parameters
    ----------
    source : path-like or bytes
        The file (read whole by :func:`arsurf._files.read_regular`), or its bytes already read
        (a sealed session checked byte for byte).
    what : str
        Word for the file in messages (``"scan file"``, ``"session"``).
    error : type
        The :class:`~arsurf.errors.ArsurfError` subclass raised (the caller's family).
    soft_links : bool
        Whether the format may hold soft links at all (within ``tree``).
    tree : str
        The group soft links must stay inside (``"/"``: anywhere in the file).
    max_expansion : float
        Declared bytes allowed per file byte (:data:`MAX_EXPANSION`).
    name : str, optional
        The name shown in messages for bytes given directly.

    Returns
    -------
    h5py.File
        Open read-only on the in-memory bytes; use it in a ``with`` block.

    Raises
    ------
    error
        A non-regular file, or a refused HDF5 feature (the message names it and the object).
    OSError
        h5py could not parse the bytes as HDF5 (the caller names the damage).
    """
    h5py = _h5py()
    if isinstance(source, (bytes, bytearray, memoryview)):
        data, shown = bytes(source), name or what
    else:
        shown = f"{what} {os.fspath(source)!r}"
        data = read_regular(source, what, error=error)
    f = _from_image(data, h5py)
    try:
        check_tree(f, len(data), shown, error=error, soft_links=soft_links, tree=tree, max_expansion=max_expansion)
    except BaseException:
        f.close()
        raise
    return f


def _from_image(data: bytes, h5py):
    """The file opened read-only from ``data`` by HDF5's core driver given a file image: libhdf5
    reads the image in memory and opens no file (the name is only a label)."""
    fapl = h5py.h5p.create(h5py.h5p.FILE_ACCESS)
    fapl.set_fapl_core(backing_store=False)
    fapl.set_file_image(data)
    return h5py.File(h5py.h5f.open(b"arsurf in-memory image", h5py.h5f.ACC_RDONLY, fapl=fapl))


def _declared(shape, itemsize: int) -> int:
    n = 1
    for d in shape or ():
        n *= int(d)
    return n * int(itemsize)


def _check_dataset(ds, path: str, shown: str, error, budget: float, max_expansion: float, h5py) -> int:
    """Refuse external storage, a virtual layout or an unexpected filter; the declared bytes."""
    dcpl = ds.id.get_create_plist()
    if dcpl.get_external_count():
        target = dcpl.get_external(0)[0]
        target = target.decode("utf-8", "replace") if isinstance(target, bytes) else str(target)
        raise error(f"{shown}: {path} uses HDF5 external storage (its values would be read from the file "
                    f"{target!r}); arsurf reads only the file's own bytes, so the file is refused")
    if dcpl.get_layout() == h5py.h5d.VIRTUAL:
        raise error(f"{shown}: {path} is an HDF5 virtual dataset (its values come from other datasets or files); "
                    "arsurf reads only the file's own bytes, so the file is refused")
    for i in range(dcpl.get_nfilters()):
        code, _, _, fname = dcpl.get_filter(i)
        if code not in ALLOWED_FILTERS:
            fname = fname.decode("utf-8", "replace") if isinstance(fname, bytes) else str(fname)
            raise error(f"{shown}: {path} uses HDF5 filter {code} ({fname or 'unnamed'}), not one arsurf expects "
                        f"({', '.join(ALLOWED_FILTERS.values())}); the file is refused")
    declared = _declared(ds.id.shape, ds.id.dtype.itemsize)
    stored = ds.id.get_storage_size()
    deflated = any(dcpl.get_filter(i)[0] == 1 for i in range(dcpl.get_nfilters()))
    if declared and (declared > GZIP_LIMIT * stored if deflated else stored < declared):
        raise error(f"{shown}: {path} declares {declared} bytes of data but stores {stored}"
                    f"{' compressed' if deflated else ''} (elements never written, which a read would fill); "
                    "the file is damaged or crafted and is refused")
    if declared > budget:
        raise error(f"{shown}: {path} declares {declared} bytes of data, more than {max_expansion:g}x the file's "
                    f"size ({budget:.0f} bytes allowed); the file is damaged or crafted and is refused")
    return declared


def check_tree(f, size: int, shown: str, *, error: type[ArsurfError] = UnsafeFile, soft_links: bool = True,
               tree: str = "/", max_expansion: float = MAX_EXPANSION) -> None:
    """Walk every object of the open file ``f`` (``size`` bytes) by hard links; raise ``error`` on
    a refused feature (see the module). Links are read, never followed, until all are checked."""
    h5py = _h5py()
    budget = float(max_expansion) * max(int(size), 0)
    tree = posixpath.normpath("/" + tree.strip("/"))
    total = 0
    seen: set = set()
    soft: list[tuple[str, str]] = []
    root = f["/"]
    stack = [root]
    seen.add(h5py.h5o.get_info(root.id).addr)
    while stack:
        g = stack.pop()
        base = g.name or "/"
        for name in g:  # H5Literate: link names, nothing resolved
            path = posixpath.join(base, name)
            link = g.get(name, getlink=True)
            if isinstance(link, h5py.ExternalLink):
                raise error(f"{shown}: {path} is an HDF5 external link (to {link.filename!r}:{link.path}); "
                            "arsurf reads only the file's own bytes, so the file is refused")
            if isinstance(link, h5py.SoftLink):
                if not soft_links:
                    raise error(f"{shown}: {path} is an HDF5 soft link (to {link.path}), which this format never "
                                "holds; the file is refused")
                target = posixpath.normpath(posixpath.join(base, str(link.path)))
                if not (tree == "/" or target == tree or target.startswith(tree + "/")):
                    raise error(f"{shown}: {path} is a soft link to {target}, outside {tree}; the file is refused")
                soft.append((path, target))
                continue
            if not isinstance(link, h5py.HardLink):
                raise error(f"{shown}: {path} is a user-defined HDF5 link; the file is refused")
            obj = g[name]
            addr = h5py.h5o.get_info(obj.id).addr
            if addr in seen:
                continue
            seen.add(addr)
            if len(seen) > MAX_OBJECTS:
                raise error(f"{shown} holds more than {MAX_OBJECTS} HDF5 objects; the file is refused")
            if isinstance(obj, h5py.Group):
                stack.append(obj)
            elif isinstance(obj, h5py.Dataset):
                total += _check_dataset(obj, path, shown, error, budget, max_expansion, h5py)
            if total > budget:
                raise error(f"{shown} declares {total} bytes of data up to {path}, more than "
                            f"{max_expansion:g}x the file's size ({budget:.0f} bytes allowed); the file is refused")
    for path, target in soft:  # every link is known to stay in the file: resolving is safe now
        try:
            found = f.get(target)
        except Exception:  # noqa: BLE001 - a chain of soft links too long or circular
            found = None
        if found is None:
            raise error(f"{shown}: {path} is a soft link to {target}, which does not resolve to an object; the file is refused")
