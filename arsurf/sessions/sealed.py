r"""Sealed HDF5 files and an isolated reader: libhdf5 never parses bytes nobody vouched for.

libhdf5 (through h5py) trusts the file it parses: a flipped bit in a B-tree address or a
dataspace can make it segfault, loop for minutes or allocate gigabytes. This module keeps
corrupt bytes away from it in two ways.

**The seal.** Files written by :func:`arsurf.sessions.writer.write_h5` reserve the 512-byte
HDF5 *user block* (which libhdf5 skips) and write in it, after the file is complete:

======  ======  ===========================================================================
offset  bytes   content
======  ======  ===========================================================================
0       8       magic ``b"\x89ARSURF\n"``
8       4       seal version (uint32 little-endian, 1)
12      8       length L of the HDF5 part (uint64 LE): the file is exactly 512 + L bytes
20      32      SHA-256 of the whole file with these 32 bytes set to zero
52      460     zeros
======  ======  ===========================================================================

:func:`read_sealed` reads the file into memory, checks the length and the SHA-256 and the
HDF5 superblock (signature at 512, end-of-file address = file size), and only then hands the
*in-memory* bytes to h5py, so the bytes libhdf5 parses are exactly the ones that were checked.
The seal says the bytes are intact, not that their content is harmless: a sealed file is opened
through :func:`arsurf._h5safe.open_hdf5` like any other (no external storage, links or virtual
datasets, every value stored) and its ticks are checked for plausibility.
Any bit flip, truncation, overwrite or extension of a sealed file is refused before libhdf5
sees it (SHA-256: a random change passes with probability :math:`2^{-256}`).

**Isolation.** A file nobody sealed (an older session, a file from elsewhere) or one crafted
to carry a valid seal can still crash libhdf5. :func:`run_isolated` runs the reading code in a
child Python process with a memory limit (``RLIMIT_AS``) and a time limit: a segfault, an abort,
a hang or a runaway allocation there becomes a :class:`~arsurf.errors.SessionError` here, and
the parent only ever reads the child's answer (a ``.npz`` of plain arrays, parsed by numpy with
``allow_pickle=False``, and a JSON text).

Examples
--------
>>> import tempfile, os, h5py
>>> p = os.path.join(tempfile.mkdtemp(), "x.h5")
>>> with h5py.File(p, "w", userblock_size=SEAL_SIZE) as f:
...     f.attrs["answer"] = 42
>>> seal_file(p)
>>> data = read_sealed(p)
>>> len(data) == os.path.getsize(p)
True
"""
from __future__ import annotations

import hashlib
import os
import signal
import struct
import subprocess
import sys
from pathlib import Path

from arsurf._files import read_regular
from arsurf.errors import IsolatedReadFailure, SessionError

__all__ = ["SEAL_SIZE", "seal_file", "seal_open", "seal_bytes", "read_sealed", "is_sealed_header", "check_superblock", "run_isolated"]

#: size of the HDF5 user block that holds the seal (HDF5 needs a power of two >= 512)
SEAL_SIZE = 512
SEAL_MAGIC = b"\x89ARSURF\n"
SEAL_VERSION = 1
_SEAL = struct.Struct("<8sIQ32s")  # magic, version, HDF5 length, SHA-256
_DIGEST_AT = 20
HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"
_BLOCK = 1 << 20


def _digest(head: bytes, rest) -> bytes:
    """SHA-256 of the file with the digest field zeroed: ``head`` is the first 512 bytes."""
    h = hashlib.sha256()
    h.update(head[:_DIGEST_AT])
    h.update(bytes(32))
    h.update(head[_DIGEST_AT + 32:SEAL_SIZE])
    for block in rest:
        h.update(block)
    return h.digest()


def seal_file(path: str | os.PathLike) -> None:
    """Write the seal into the 512-byte user block of a closed HDF5 file (in place, fsynced).

    The file must have been created with ``userblock_size=SEAL_SIZE`` (h5py), so its first 512
    bytes are free.
    """
    with open(Path(path), "r+b") as fh:
        seal_open(fh, str(path))


def seal_open(fh, name: str = "the file") -> None:
    """:func:`seal_file` on a binary file object open for reading and writing (flushed, fsynced)."""
    fh.flush()
    fh.seek(0)
    head = fh.read(SEAL_SIZE)
    if len(head) != SEAL_SIZE or fh.read(8) != HDF5_SIGNATURE:
        raise SessionError(f"{name!r} has no {SEAL_SIZE}-byte user block before its HDF5 superblock; "
                           "create it with userblock_size=SEAL_SIZE")
    size = os.fstat(fh.fileno()).st_size
    head = _SEAL.pack(SEAL_MAGIC, SEAL_VERSION, size - SEAL_SIZE, bytes(32)) + bytes(SEAL_SIZE - _SEAL.size)
    fh.seek(SEAL_SIZE)

    def blocks():
        while True:
            b = fh.read(_BLOCK)
            if not b:
                return
            yield b

    digest = _digest(head, blocks())
    fh.seek(0)
    fh.write(head[:_DIGEST_AT] + digest + head[_DIGEST_AT + 32:])
    fh.flush()
    os.fsync(fh.fileno())


def seal_bytes(data: bytes) -> bytes:
    """``data`` (a file with a free 512-byte user block) with a valid seal over whatever it holds.

    Unlike :func:`seal_file` it does not look at the HDF5 part: tests and fuzzers use it to
    craft files whose seal is valid but whose HDF5 structures are damaged, the case the seal
    cannot catch and the isolated reader must.
    """
    if len(data) < SEAL_SIZE:
        raise SessionError(f"a sealed file has at least {SEAL_SIZE} bytes (got {len(data)})")
    head = _SEAL.pack(SEAL_MAGIC, SEAL_VERSION, len(data) - SEAL_SIZE, bytes(32)) + bytes(SEAL_SIZE - _SEAL.size)
    digest = _digest(head, [memoryview(data)[SEAL_SIZE:]])
    return head[:_DIGEST_AT] + digest + head[_DIGEST_AT + 32:] + data[SEAL_SIZE:]


def is_sealed_header(head: bytes) -> bool:
    """True when ``head`` (the first bytes of a file) starts with the seal magic."""
    return head[:len(SEAL_MAGIC)] == SEAL_MAGIC


def check_superblock(data, offset: int, what: str, size: int | None = None) -> None:
    """Check the HDF5 superblock at ``offset`` of ``data`` (bytes) without libhdf5.

    Checks the signature, the superblock version (0-3), the sizes of offsets and lengths
    (2, 4 or 8 bytes) and that the end-of-file address it records is not past the end of the
    file (a truncated file). ``data`` is the whole file, or its first bytes with ``size`` the
    file's length. Raises :class:`SessionError` naming the problem.
    """
    n = len(data) if size is None else int(size)
    if n < offset + 8 or bytes(data[offset:offset + 8]) != HDF5_SIGNATURE:
        raise SessionError(f"{what} has no HDF5 signature at byte {offset} (not HDF5, or damaged)")
    if min(n, len(data)) < offset + 48:
        raise SessionError(f"{what} is truncated inside its HDF5 superblock ({n} bytes)")
    version = data[offset + 8]
    if version in (0, 1):
        size_off, size_len = data[offset + 13], data[offset + 14]
        at = offset + 24 + (4 if version == 1 else 0)
    elif version in (2, 3, 4):
        size_off, size_len = data[offset + 9], data[offset + 10]
        at = offset + 12
    else:
        raise SessionError(f"{what} has HDF5 superblock version {version}, which no HDF5 library writes "
                           "(the file is damaged)")
    if size_off not in (2, 4, 8) or size_len not in (2, 4, 8):
        raise SessionError(f"{what} has a damaged HDF5 superblock (sizes of offsets/lengths {size_off}/{size_len})")
    fmt = {2: "H", 4: "I", 8: "Q"}[size_off]
    need = at + 3 * size_off
    if min(n, len(data)) < need:
        raise SessionError(f"{what} is truncated inside its HDF5 superblock ({n} bytes)")
    base, _, eof = struct.unpack_from("<3" + fmt, data, at)
    undefined = (1 << (8 * size_off)) - 1
    if eof != undefined and eof > n and base + eof > n:
        raise SessionError(f"{what} is truncated: its HDF5 superblock says the file ends at byte {eof}, "
                           f"but it has {n} bytes")


def read_sealed(path: str | os.PathLike, what: str = "file") -> bytes | None:
    """The bytes of a sealed file, checked; ``None`` for an unsealed HDF5 file.

    Parameters
    ----------
    path : path-like
    what : str
        Word for the file in messages (``"session"``, ``"replay"``).

    Returns
    -------
    bytes or None
        The whole file (seal included) when its seal is intact; None when the file starts with
        the HDF5 signature (no seal: written by an older version or by another program).

    Raises
    ------
    SessionError
        A seal that does not match (the message says how: length, version, digest), a file
        that is neither sealed nor HDF5, an HDF5 superblock that does not match the file.
    """
    p = Path(path)
    name = f"{what} {str(p)!r}"
    data = read_regular(p, what, error=SessionError)  # a FIFO or a device is refused, never waited on
    size = len(data)
    head = data[:SEAL_SIZE]
    if head[:8] == HDF5_SIGNATURE:
        return None
    if not is_sealed_header(head):
        raise SessionError(f"{name} is not a readable HDF5 {what} file (truncated, corrupt or another format): "
                           f"it starts with neither the arsurf seal nor the HDF5 signature")
    if len(head) < SEAL_SIZE:
        raise SessionError(f"{name} is truncated ({size} bytes, less than its {SEAL_SIZE}-byte seal)")
    _, version, length, digest = _SEAL.unpack_from(head)
    if version != SEAL_VERSION:
        raise SessionError(f"{name} has seal version {version}, which this arsurf cannot check "
                           f"(it knows {SEAL_VERSION}); the file is damaged or from a newer arsurf")
    if size != SEAL_SIZE + length:
        raise SessionError(f"{name} is damaged: its seal says {SEAL_SIZE + length} bytes but the file has {size} "
                           f"({'truncated' if size < SEAL_SIZE + length else 'extended, or the seal is corrupt'})")
    if _digest(head, [memoryview(data)[SEAL_SIZE:]]) != digest:
        raise SessionError(f"{name} is damaged: its SHA-256 does not match its seal (a bit flip, an overwrite or an "
                           "edit after writing); the file is refused rather than read with altered values")
    check_superblock(data, SEAL_SIZE, name)
    return data


# ---------------------------------------------------------------------------------------------
# isolation


def _child_prelude(memory_limit: int | None) -> str:
    lines = ["import sys"]
    if memory_limit:
        lines += ["try:", "    import resource",
                  f"    resource.setrlimit(resource.RLIMIT_AS, ({int(memory_limit)}, {int(memory_limit)}))",
                  "except (ImportError, ValueError, OSError):", "    pass"]
    return "\n".join(lines) + "\n"


def _signal_name(code: int) -> str:
    try:
        return signal.Signals(code).name
    except ValueError:
        return f"signal {code}"


def run_isolated(code: str, args: list[str], *, timeout: float, memory_limit: int | None, what: str) -> str:
    """Run Python ``code`` in a child process; return its stdout, or raise if it failed.

    Parameters
    ----------
    code : str
        Program text; it sees ``sys.argv[1:] == args``. Exit status 0: success (its stdout is
        returned); 3: a refusal, whose message is the last line of its stderr.
    args : list of str
    timeout : float, s
        The child is killed after this long.
    memory_limit : int or None, bytes
        ``RLIMIT_AS`` of the child (address space), set before it imports anything else.
    what : str
        What was being done, for the messages ("reading session 'x.h5'").

    Raises
    ------
    IsolatedReadFailure
        The child died from a signal (segfault, abort), was killed at ``timeout``, ran out of
        memory or exited with another status.
    SessionError
        The child refused (status 3); the message is the child's.

    Examples
    --------
    >>> run_isolated("import sys; print(sys.argv[1])", ["hello"], timeout=30, memory_limit=None, what="a test").strip()
    'hello'
    """
    import arsurf

    env = dict(os.environ)
    root = str(Path(arsurf.__file__).resolve().parents[1])
    env["PYTHONPATH"] = root + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    env.pop("PYTHONSTARTUP", None)
    # the child must not wait on numba threads or a GPU: plain and single-threaded
    env.setdefault("OMP_NUM_THREADS", "1")
    env.setdefault("OPENBLAS_NUM_THREADS", "1")
    program = _child_prelude(memory_limit) + code
    try:
        proc = subprocess.run([sys.executable, "-c", program, *args], capture_output=True, timeout=timeout,
                              env=env, stdin=subprocess.DEVNULL)
    except subprocess.TimeoutExpired:
        raise IsolatedReadFailure(f"{what} did not finish within {timeout:.0f} s (the HDF5 library hung on the file, "
                              "which is damaged); the file is refused") from None
    err = proc.stderr.decode("utf-8", "replace").strip()
    if proc.returncode == 0:
        return proc.stdout.decode("utf-8", "replace")
    if proc.returncode == 3:
        raise SessionError(err.splitlines()[-1] if err else f"{what} failed")
    if proc.returncode < 0:
        raise IsolatedReadFailure(f"{what} crashed the HDF5 library ({_signal_name(-proc.returncode)}) in the isolated "
                              "reader; the file is damaged and is refused (this process is unaffected)")
    if "MemoryError" in err:
        raise IsolatedReadFailure(f"{what} needed more than {memory_limit} bytes of memory in the isolated reader; "
                              "the file is damaged (it claims impossibly large data) and is refused")
    tail = err.splitlines()[-1] if err else ""
    raise IsolatedReadFailure(f"{what} failed in the isolated reader (exit status {proc.returncode}: {tail}); "
                          "the file is refused")
