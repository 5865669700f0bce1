"""Where the items of a batch run: local worker processes (with crash isolation) or a Dask cluster.

Both call ``func(*args)`` for every call and hand each result to ``on_result(i, value)`` in this
process as it finishes; a call whose worker died (a crash, the out-of-memory killer, a task the
cluster lost) goes to ``on_crash(i, reason)`` instead, and the others complete.
"""
from __future__ import annotations

from collections import deque
from typing import Any, Callable, Sequence

from arsurf.batch.table import one_line_reason
from arsurf.errors import BatchError, require

__all__ = ["execute_local", "execute_dask", "connect"]


def execute_local(func: Callable, calls: Sequence[tuple], workers: int, on_result: Callable[[int, Any], None],
                   on_crash: Callable[[int, str], None]) -> None:
    """Run ``func(*calls[i])`` for every i on ``workers`` processes, calling ``on_result(i, value)``
    as each finishes (in this process). A worker that dies breaks the pool: the calls it held run
    again one at a time in a fresh pool, and one that breaks it alone is given to ``on_crash``."""
    import multiprocessing
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
    from concurrent.futures.process import BrokenProcessPool

    if workers == 0:
        for i, args in enumerate(calls):
            on_result(i, func(*args))
        return
    context = multiprocessing.get_context("spawn")  # no fork of a process that holds threads (Dask, BLAS)
    pending = deque(range(len(calls)))
    suspects: deque[int] = deque()
    window = 2 * workers  # calls handed to the pool at once: the suspects if it breaks
    pool = None
    try:
        while pending or suspects:
            if pool is None:
                pool = ProcessPoolExecutor(max_workers=workers, mp_context=context)
            if suspects:  # after a break: one call at a time, so a call that breaks the pool alone is known
                i = suspects.popleft()
                try:
                    value = pool.submit(func, *calls[i]).result()
                except BrokenProcessPool:
                    on_crash(i, "the worker process died while running this item (a crash or the out-of-memory "
                                "killer)")
                    pool.shutdown(wait=True, cancel_futures=True)
                    pool = None
                    continue
                on_result(i, value)
                continue
            inflight: dict = {}
            broken = False
            while (pending or inflight) and not broken:
                while pending and len(inflight) < window:
                    i = pending.popleft()
                    try:
                        inflight[pool.submit(func, *calls[i])] = i
                    except BrokenProcessPool:
                        pending.appendleft(i)
                        broken = True
                        break
                if not inflight:
                    break
                done, _ = wait(list(inflight), return_when=FIRST_COMPLETED)
                for fut in done:
                    i = inflight.pop(fut)
                    try:
                        value = fut.result()
                    except BrokenProcessPool:
                        broken = True
                        suspects.append(i)
                        continue
                    on_result(i, value)
            if broken:  # the calls the broken pool held: not run, or not known to have run
                suspects.extend(sorted(inflight.values()))
                pool.shutdown(wait=True, cancel_futures=True)
                pool = None
    finally:
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)


def connect(scheduler, connect_timeout: float):
    """``(client, own)``: a ``distributed.Client`` for an address (``own``: close it after), or the client given."""
    distributed = require("distributed", "dask", "arsurf batch on a Dask cluster (--scheduler)")
    if isinstance(scheduler, distributed.Client):
        return scheduler, False
    try:
        return distributed.Client(scheduler, timeout=connect_timeout), True
    except (OSError, TimeoutError, ValueError, TypeError) as exc:
        raise BatchError(f"cannot reach the Dask scheduler at {scheduler!r} within {connect_timeout:g} s "
                         f"({one_line_reason(exc)}); start one with `dask scheduler` or check the address") from None


def execute_dask(func: Callable, calls: Sequence[tuple], client, on_result: Callable[[int, Any], None],
                  on_crash: Callable[[int, str], None]) -> None:
    """Run the calls on the Dask cluster of ``client``. A task that fails on the cluster (a worker
    killed three times running it: ``KilledWorker``) goes to ``on_crash``."""
    import distributed

    futures = [client.submit(func, *args, pure=False) for args in calls]
    index = {f.key: i for i, f in enumerate(futures)}
    try:
        for fut in distributed.as_completed(futures):
            i = index[fut.key]
            try:
                value = fut.result()
            except Exception as exc:  # noqa: BLE001 - the cluster lost the task; the others go on
                on_crash(i, f"the Dask cluster could not run this item ({one_line_reason(exc)})")
            else:
                on_result(i, value)
            fut.release()
    finally:
        client.cancel([f for f in futures if not f.done()])

