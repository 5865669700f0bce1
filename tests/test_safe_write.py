"""Files arsurf writes cannot be redirected: a link a second user plants in a shared folder is
never written through (arsurf/_files.py, docs/safety.rst).

The "second user" is simulated in a sticky, world-writable folder (as /tmp is): the link is
planted where arsurf will write (the target, or the fixed temporary names older versions used)
and points at a victim file that must come out unchanged.
"""
from __future__ import annotations

import os
import stat

import numpy as np
import pytest

from arsurf import _files
from arsurf._files import atomic_write, read_regular, write_bytes
from arsurf.errors import ArsurfError, UnsafeFile

VICTIM = b"the victim's own data\n"


@pytest.fixture
def shared(tmp_path):
    """A shared folder (mode 1777, like /tmp) and a victim file outside it."""
    d = tmp_path / "shared"
    d.mkdir()
    d.chmod(0o1777)
    victim = tmp_path / "victim.txt"
    victim.write_bytes(VICTIM)
    return d, victim


def test_a_symlinked_target_is_refused_and_the_victim_kept(shared):
    d, victim = shared
    os.symlink(victim, d / "out.bin")
    with pytest.raises(UnsafeFile, match="symbolic link"):
        write_bytes(d / "out.bin", b"data")
    assert victim.read_bytes() == VICTIM
    assert os.path.islink(d / "out.bin")
    assert sorted(os.listdir(d)) == ["out.bin"]  # no temporary left


def test_the_temporary_is_exclusive_and_its_name_unpredictable(shared, monkeypatch):
    """A link planted at the temporary's name (guessed: the draw is fixed here) is not opened:
    O_EXCL | O_NOFOLLOW fails on it and another name is drawn."""
    d, victim = shared
    draws = iter(["0" * 16, "1" * 16])
    monkeypatch.setattr(_files.secrets, "token_hex", lambda n: next(draws))
    os.symlink(victim, d / f".out.bin.{'0' * 16}.tmp.bin")
    write_bytes(d / "out.bin", b"data")
    assert victim.read_bytes() == VICTIM
    assert (d / "out.bin").read_bytes() == b"data"
    st = os.lstat(d / "out.bin")
    assert stat.S_ISREG(st.st_mode) and st.st_mode & 0o777 == 0o666 & ~_umask()


def _umask() -> int:
    m = os.umask(0)
    os.umask(m)
    return m


def test_an_error_while_writing_keeps_the_old_file_and_leaves_no_temporary(tmp_path):
    p = tmp_path / "out.txt"
    p.write_text("old")
    with pytest.raises(RuntimeError):
        with atomic_write(p, "w") as fh:
            fh.write("half")
            raise RuntimeError("disk trouble")
    assert p.read_text() == "old"
    assert os.listdir(tmp_path) == ["out.txt"]


def test_reading_a_fifo_is_refused_without_blocking(tmp_path):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    with pytest.raises(UnsafeFile, match="FIFO"):
        read_regular(fifo, "scan file")


def _surface():
    from arsurf.spline.surface import BSplineSurface

    y, x = np.mgrid[0:12, 0:12]
    return BSplineSurface.from_heights(1e-9 * np.sin(x / 3.0) * np.cos(y / 4.0), (0, 1e-7), (0, 1e-7))


def _scan():
    from arsurf.scan.scan import Scan

    y, x = np.mgrid[0:8, 0:8]
    return Scan(heights=1e-9 * (x + y).astype(float), dx=1e-8, dy=1e-8)


def _export(path):
    from arsurf.export import export_surface

    export_surface(_surface(), path, 8)


def _figure(path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from arsurf.replay.plots import save_figure

    fig = plt.figure()
    save_figure(fig, path)
    plt.close(fig)


def _save_scan(path):
    from arsurf.scan.io import save_scan

    save_scan(_scan(), path)


def _save_surface(path):
    from arsurf.spline.storage import save_surface

    save_surface(_surface(), path)


WRITERS = {"export mesh.stl": ("mesh.stl", _export), "figure.png": ("figure.png", _figure),
           "convert scan.gwy": ("scan.gwy", _save_scan), "convert scan.gsf": ("scan.gsf", _save_scan),
           "convert scan.npz": ("scan.npz", _save_scan), "convert scan.npy": ("scan.npy", _save_scan),
           "fit surface.npz": ("surface.npz", _save_surface)}


@pytest.mark.parametrize("name", sorted(WRITERS))
def test_no_writer_follows_a_planted_link(shared, name):
    """The planted link at the target is refused (one line); at the old fixed temporary name
    (``<name>.part``) it is simply never used."""
    d, victim = shared
    fname, write = WRITERS[name]
    target = d / fname
    os.symlink(victim, d / (fname + ".part"))
    write(target)
    assert victim.read_bytes() == VICTIM
    assert target.is_file() and not target.is_symlink()
    target.unlink()
    os.symlink(victim, target)
    with pytest.raises(ArsurfError, match="symbolic link") as info:
        write(target)
    assert "\n" not in str(info.value)
    assert victim.read_bytes() == VICTIM


def test_the_code_of_the_safety_page_runs(capsys):
    """Every python block of docs/safety.rst runs as written."""
    import re
    import textwrap
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "docs" / "safety.rst").read_text()
    blocks = re.findall(r"\.\. code-block:: python\n\n((?:   .*\n|\n)+)", text)
    assert blocks
    for block in blocks:
        exec(compile(textwrap.dedent(block), "docs/safety.rst", "exec"), {})
    assert "symbolic link" in capsys.readouterr().out
