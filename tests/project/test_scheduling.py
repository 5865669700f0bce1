"""The suite's order (tests.support.scheduling, applied in tests/conftest.py): the files holding a
``slow`` test first, each file whole and in its own order, which is what ``make test`` hands out to
its pytest-xdist workers one file at a time (docs/testing.rst)."""
from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

from tests.support.scheduling import machine_share, slow_files_first


def _item(path: str, name: str, slow: bool = False):
    return SimpleNamespace(path=Path(path), name=name,
                           get_closest_marker=lambda mark: object() if slow and mark == "slow" else None)


def test_slow_files_move_to_the_front_and_keep_their_order():
    items = [_item("a.py", "a1"), _item("a.py", "a2"), _item("b.py", "b1"), _item("b.py", "b2", slow=True),
             _item("c.py", "c1"), _item("d.py", "d1", slow=True), _item("d.py", "d2")]
    assert [i.name for i in slow_files_first(items)] == ["b1", "b2", "d1", "d2", "a1", "a2", "c1"]
    assert [i.name for i in slow_files_first(items[:2])] == ["a1", "a2"]  # nothing slow: unchanged


def test_the_collected_suite_runs_its_slow_files_first_each_file_whole(request):
    """On this run's own collection (the whole suite under ``make test``)."""
    order = [item.path for item in request.session.items]
    files = list(dict.fromkeys(order))
    assert [p for k, p in enumerate(order) if k and p != order[k - 1]] == files[1:]  # each file in one run
    slow = {item.path for item in request.session.items if item.get_closest_marker("slow") is not None}
    assert files[:len(slow)] == [p for p in files if p in slow]


def _can_lock(path: Path, how: int) -> bool:
    import fcntl

    with open(path, "a") as f:  # another open file description: conflicts like another worker
        try:
            fcntl.flock(f, how | fcntl.LOCK_NB)
        except BlockingIOError:
            return False
        return True


def test_a_realtime_test_holds_the_machine_alone_the_others_share_it(tmp_path):
    import fcntl

    running, gate = tmp_path / "running", tmp_path / "turnstile"
    with machine_share(tmp_path, alone=True):
        assert not _can_lock(running, fcntl.LOCK_SH)  # no other test runs beside it
        assert not _can_lock(gate, fcntl.LOCK_EX)  # and none starts
    with machine_share(tmp_path, alone=False):
        assert _can_lock(running, fcntl.LOCK_SH)  # another worker's ordinary test runs beside it
        assert not _can_lock(running, fcntl.LOCK_EX)  # a realtime one waits
        assert _can_lock(gate, fcntl.LOCK_EX)  # at the turnstile, so no new ordinary test starts meanwhile
    assert _can_lock(running, fcntl.LOCK_EX) and _can_lock(gate, fcntl.LOCK_EX)  # all released
    with machine_share(None, alone=True):  # a run in one process holds nothing
        assert _can_lock(running, fcntl.LOCK_EX) and _can_lock(gate, fcntl.LOCK_EX)
