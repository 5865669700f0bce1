"""Files arsurf reads and writes: regular files only in, writes that cannot be redirected out.

Every file arsurf reads as a whole (HDF5 scans and sessions, :mod:`arsurf._h5safe`) is opened
by :func:`read_regular` and every file it writes goes through :func:`atomic_write`: one place
states the rules (docs/safety.rst).

**Reading.** The file is opened ``O_RDONLY | O_NONBLOCK`` (a FIFO with no writer then opens at
once instead of blocking forever) and checked with ``fstat`` on the open descriptor: a FIFO, a
device, a socket or a directory is refused before a byte is read, and the size read is the
size of the file that was checked (no race between a ``stat`` and an ``open``).

**Writing.** A second user of a shared folder can plant a symbolic link where a program will
write (``run.h5.part -> victim``); a program that opens that name for writing then overwrites
the victim. :func:`atomic_write` never opens a name it did not create:

1. the target is refused when it is a symbolic link, or exists and is not a regular file;
2. the data go to a temporary created in the target's folder with
   ``O_CREAT | O_EXCL | O_NOFOLLOW`` under an unpredictable name (``.<name>.<64 random
   bits>.tmp<suffix>``): ``O_EXCL`` fails on any existing name, planted link included;
3. the temporary is flushed, fsynced, and renamed over the target (``os.replace`` replaces a
   directory entry, it never writes through a link), then the folder is fsynced. On any error
   the temporary is removed and the target is left as it was.

A reader of the target sees either the old file or the complete new one, never a part.

Examples
--------
>>> import tempfile, os
>>> d = tempfile.mkdtemp()
>>> with atomic_write(os.path.join(d, "out.txt"), "w") as fh:
...     _ = fh.write("hello")
>>> open(os.path.join(d, "out.txt")).read()
'hello'
>>> os.symlink(os.path.join(d, "out.txt"), os.path.join(d, "link.txt"))
>>> with atomic_write(os.path.join(d, "link.txt"), "w") as fh:
...     pass
Traceback (most recent call last):
...
arsurf.errors.UnsafeFile: ... is a symbolic link; arsurf does not write through links ...
"""
from __future__ import annotations

import contextlib
import errno
import hashlib
import io
import os
import secrets
import stat
from pathlib import Path
from typing import Iterator

from arsurf.errors import ArsurfError, UnsafeFile

__all__ = ["read_regular", "check_regular", "atomic_write", "write_bytes", "write_text", "check_target", "fsync_dir",
           "sha256_file"]

_KINDS = {stat.S_IFIFO: "a FIFO (named pipe)", stat.S_IFCHR: "a character device", stat.S_IFBLK: "a block device",
          stat.S_IFSOCK: "a socket", stat.S_IFDIR: "a directory", stat.S_IFLNK: "a symbolic link"}


def _kind(mode: int) -> str:
    return _KINDS.get(stat.S_IFMT(mode), "not a regular file")


def read_regular(path: str | os.PathLike, what: str = "file", *, error: type[ArsurfError] = UnsafeFile,
                 limit: int | None = None) -> bytes:
    """The bytes of the regular file ``path``; anything else is refused without blocking.

    Parameters
    ----------
    path : path-like
    what : str
        Word for the file in messages (``"session"``, ``"scan file"``).
    error : type
        The :class:`~arsurf.errors.ArsurfError` subclass raised for a file that is not regular
        (the caller's family: ``CorruptScan``, ``SessionError``).
    limit : int, optional
        Largest size accepted, bytes.

    Raises
    ------
    FileNotFoundError, PermissionError
        As ``open`` raises them.
    error
        A FIFO, device, socket or directory; a file over ``limit``; a file that changed size
        while it was read.
    """
    p = os.fspath(path)
    fd = os.open(p, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0) | getattr(os, "O_BINARY", 0))
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise error(f"{what} {p!r} is {_kind(st.st_mode)}, not a regular file; arsurf reads only regular files "
                        "(copy the data into a file)")
        if limit is not None and st.st_size > limit:
            raise error(f"{what} {p!r} has {st.st_size} bytes, more than the {limit} accepted")
        with os.fdopen(os.dup(fd), "rb") as fh:
            data = fh.read(st.st_size + 1)
    finally:
        os.close(fd)
    if len(data) != st.st_size:
        raise error(f"{what} {p!r} changed while it was read ({len(data)} bytes read, {st.st_size} expected)")
    return data


def check_regular(path: str | os.PathLike, what: str = "file", *, error: type[ArsurfError] = UnsafeFile) -> int:
    """Refuse ``path`` unless it is a regular file (following links, without opening it, so a FIFO
    never blocks); return its size. For a file another process will read (the isolated reader)."""
    st = os.stat(path)
    if not stat.S_ISREG(st.st_mode):
        raise error(f"{what} {os.fspath(path)!r} is {_kind(st.st_mode)}, not a regular file; arsurf reads only "
                    "regular files (copy the data into a file)")
    return st.st_size


def check_target(path: str | os.PathLike, what: str = "output", *, error: type[ArsurfError] = UnsafeFile) -> Path:
    """Refuse a write target that is a symbolic link or exists and is not a regular file.

    Returns the target as a :class:`~pathlib.Path`.
    """
    p = Path(path)
    try:
        st = os.lstat(p)
    except FileNotFoundError:
        return p
    if stat.S_ISLNK(st.st_mode):
        raise error(f"{what} {str(p)!r} is a symbolic link; arsurf does not write through links (a link planted "
                    "in a shared folder would redirect the write): remove it or choose another name")
    if not stat.S_ISREG(st.st_mode):
        raise error(f"{what} {str(p)!r} exists and is {_kind(st.st_mode)}; choose a file name")
    return p


def fsync_dir(path: str | os.PathLike) -> None:
    """fsync the folder ``path`` so a rename in it survives a power loss (where the OS allows)."""
    try:
        fd = os.open(os.fspath(path) or ".", os.O_RDONLY)
    except OSError:  # pragma: no cover - Windows cannot open folders
        return
    try:
        os.fsync(fd)
    except OSError:  # pragma: no cover - some file systems refuse fsync on folders
        pass
    finally:
        os.close(fd)


def _create_temp(folder: Path, name: str) -> tuple[int, Path]:
    flags = os.O_RDWR | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0) \
        | getattr(os, "O_BINARY", 0)
    for _ in range(16):
        tmp = folder / f".{name[:80]}.{secrets.token_hex(8)}.tmp{Path(name).suffix[:16]}"  # the suffix tells writers the type
        try:
            return os.open(tmp, flags, 0o666), tmp
        except FileExistsError:  # 2**-64 per try, or a name planted on purpose: draw again
            continue
    raise FileExistsError(errno.EEXIST, "no free temporary name after 16 draws", str(folder))


class AtomicFile(io.BufferedRandom):
    """The temporary behind :func:`atomic_write`: a binary file object; ``temp`` is its path and
    ``target`` the file it becomes (a library that writes only by name writes to ``temp``)."""

    temp: Path
    target: Path


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike, mode: str = "wb", *, what: str = "output",
                 error: type[ArsurfError] = UnsafeFile, encoding: str = "utf-8",
                 newline: str | None = None) -> Iterator:
    """Write ``path`` through an exclusive temporary in its folder, fsynced and renamed over it.

    Parameters
    ----------
    path : path-like
        The target. A symbolic link or a non-regular file there is refused (``error``).
    mode : {"wb", "w"}
        Binary (the yielded object is an :class:`AtomicFile`: readable and seekable too, as
        h5py and zip writers need, with ``temp`` and ``target``) or text (a text wrapper over
        it; ``encoding``, ``newline`` as :func:`open`).
    what : str
        Word for the file in messages.
    error : type
        The :class:`~arsurf.errors.ArsurfError` subclass for a refused target.

    Yields
    ------
    file object
        Write into it (or, binary mode, to its ``temp`` path); at the end of the block it
        replaces the target. If the block raises, the temporary is removed and the target kept.
    """
    if mode not in ("wb", "w"):
        raise ValueError(f"atomic_write mode must be 'wb' or 'w' (got {mode!r})")
    target = check_target(path, what, error=error)
    folder = target.parent
    fd, tmp = _create_temp(folder, target.name)
    fh = AtomicFile(io.FileIO(fd, "r+b", closefd=True))
    fh.temp, fh.target = tmp, target
    out = io.TextIOWrapper(fh, encoding=encoding, newline=newline) if mode == "w" else fh
    ok = False
    try:
        yield out
        out.flush()
        if not fh.closed:
            fh.flush()
            os.fsync(fh.fileno())
        else:  # a library closed it: reopen the temporary we created (and own) to fsync it
            with open(tmp, "rb") as again:
                os.fsync(again.fileno())
        ok = True
    finally:
        with contextlib.suppress(Exception):
            out.close()
        if ok:
            try:
                check_target(target, what, error=error)  # a link planted while we wrote is refused too
                os.replace(tmp, target)
            except BaseException:
                with contextlib.suppress(OSError):
                    os.unlink(tmp)
                raise
            fsync_dir(folder)
        else:
            with contextlib.suppress(OSError):
                os.unlink(tmp)


def write_bytes(path: str | os.PathLike, data: bytes, *, what: str = "output",
                error: type[ArsurfError] = UnsafeFile) -> Path:
    """Write ``data`` to ``path`` atomically (:func:`atomic_write`); return the path."""
    with atomic_write(path, "wb", what=what, error=error) as fh:
        fh.write(data)
    return Path(path)


def write_text(path: str | os.PathLike, text: str, *, what: str = "output", encoding: str = "utf-8",
               error: type[ArsurfError] = UnsafeFile) -> Path:
    """Write ``text`` to ``path`` atomically (:func:`atomic_write`); return the path."""
    return write_bytes(path, text.encode(encoding), what=what, error=error)


def sha256_file(path: str | os.PathLike) -> str:
    """The SHA-256 hex digest of a file's bytes, read in 1 MiB blocks (the caller checks it exists)."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()
