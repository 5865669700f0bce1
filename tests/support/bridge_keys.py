"""Key files of the UDP bridge that a second user could have planted or could read (for the key
refusal tests of the Python and C bridges; planting as another user needs root)."""
from __future__ import annotations

import os

KEY = bytes(range(32))


def _planted_key_files(tmp_path, key: bytes = KEY):
    """Key files a second user could have planted or could read: (path, what the refusal names)."""
    key_hex = key.hex() + "\n"
    tmp_path.mkdir(exist_ok=True)
    foreign = tmp_path / "foreign.key"  # mode 0600 but owned by another user (uid 65534, nobody)
    foreign.write_text(key_hex)
    os.chmod(foreign, 0o600)
    os.chown(foreign, 65534, -1)
    shared_dir = tmp_path / "shared"  # a folder others can write to (even with the sticky bit, as /tmp)
    shared_dir.mkdir()
    os.chmod(shared_dir, 0o1777)
    in_shared = shared_dir / "k"
    in_shared.write_text(key_hex)
    os.chmod(in_shared, 0o600)
    other_dir = tmp_path / "others"  # a folder owned by another user
    other_dir.mkdir(mode=0o755)
    (other_dir / "k").write_text(key_hex)
    os.chmod(other_dir / "k", 0o600)
    os.chown(other_dir, 65534, -1)
    link = tmp_path / "link.key"  # a link to a good key file
    good = tmp_path / "good.key"
    good.write_text(key_hex)
    os.chmod(good, 0o600)
    link.symlink_to(good)
    directory = tmp_path / "dir.key"
    directory.mkdir(mode=0o700)
    fifo = tmp_path / "fifo.key"  # would block a plain open() forever
    os.mkfifo(fifo, 0o600)
    return [(foreign, "owned by uid 65534"), (in_shared, "writ"), (other_dir / "k", "uid 65534"),
            (link, "symbolic link"), (directory, "not a regular file"), (fifo, "not a regular file")]
