"""The batch runner, :func:`run_batch`: checks the request, writes ``batch.json`` (the settings a
resumed batch must share), runs the items that are not done on an executor
(:mod:`arsurf.batch.executors`), appends each row to ``results.csv`` (:mod:`arsurf.batch.table`)
and writes ``summary.json``. The files and the pipelines are described in :mod:`arsurf.batch`.
"""
from __future__ import annotations

import json
import logging
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from arsurf._files import check_target, write_text
from arsurf._logging import progress as progress_bar
from arsurf.batch.executors import connect, execute_dask, execute_local
from arsurf.batch.inputs import Item, collect_inputs
from arsurf.batch.pipelines import Pipeline, _row_stands, get_pipeline, make_items, run_item
from arsurf.batch.table import BASE_COLUMNS, TABLE, ResultTable, cell, read_results, repair_table
from arsurf.errors import BatchError, require
from arsurf.units import summary_json, with_unit

log = logging.getLogger(__name__)

__all__ = ["BatchResult", "run_batch"]

SUMMARY = "summary.json"
SETTINGS = "batch.json"
BATCH_FORMAT = "arsurf-batch"
#: 2: batch.json's options carry their unit in their names (``sigma_m``), summary.json ``items_per_s``;
#: 3: every row lists its output files with size and SHA-256 (``output_files``), re-checked on resume
BATCH_FORMAT_VERSION = 3
#: default time limit of one item, s (``run_batch(item_timeout=...)``, ``--item-timeout``)
ITEM_TIMEOUT = 3600.0
#: the SI unit of each option in batch.json (:mod:`arsurf.units`); the others are dimensionless or text
_OPTION_UNITS = {"sigma": "m", "dx": "m", "dy": "m", "tip_radius": "m", "effective_modulus": "Pa", "depth": "m",
                 "slide": "m", "at": "m"}


@dataclass(frozen=True)
class BatchResult:
    """What :func:`run_batch` did (times in s).

    ``total`` items in the batch, ``ran`` in this call, ``skipped`` (done before: ``resume``),
    ``ok`` and ``failed`` over the whole table (this call and the earlier ones), ``errors``:
    ``((item, reason), ...)`` of the failed ones, ``elapsed`` wall time of this call and
    ``items_per_second`` (items run by this call / elapsed), ``not_inputs``: the files of the named
    folders that were not taken (neither a scan nor of the pipeline's kind), relative to the inputs' folder.
    """

    out_dir: Path
    table: Path
    summary: Path
    total: int
    ran: int
    skipped: int
    ok: int
    failed: int
    errors: tuple[tuple[str, str], ...]
    elapsed: float
    items_per_second: float
    not_inputs: tuple[str, ...] = ()


class _Progress:
    """Items done as a tqdm bar on stderr (:func:`arsurf._logging.progress`: on a terminal, unless
    ``-q``), failures in its postfix; the resume note is logged (INFO)."""

    def __init__(self, total: int, skipped: int, enabled: bool):
        self.failed = 0
        if enabled and skipped:
            log.info("batch: %d of %d items already done (resume)", skipped, total)
        self.bar = progress_bar(total=total, initial=skipped, desc="batch", unit="item", enabled=enabled)

    def update(self, ok: bool) -> None:
        self.bar.update(1)
        if not ok:
            self.failed += 1
            self.bar.set_postfix(failed=self.failed, refresh=False)

    def close(self) -> None:
        self.bar.close()


def _settings(pipeline: Pipeline, options: dict, version: int = BATCH_FORMAT_VERSION) -> dict:
    """batch.json: from version 2 each option named with its SI unit (``sigma_m``); version 1 (an older
    arsurf's batch, for resuming it) named them as the API does."""
    if version >= 2:
        options = {with_unit(k, _OPTION_UNITS.get(k, "")): v for k, v in options.items()}
    return {"format": BATCH_FORMAT, "version": version, "pipeline": pipeline.name,
            "options": options, "columns": list(pipeline.columns)}


def _check_out_dir(out: Path, pipeline: Pipeline, options: dict, resume: bool) -> None:
    settings = _settings(pipeline, options)
    table = out / TABLE
    if out.exists() and not out.is_dir():
        raise BatchError(f"output path {str(out)!r} is a file, not a folder")
    if table.exists() and not resume:
        raise BatchError(f"{str(table)!r} exists: pass --resume (resume=True) to continue that batch, or choose "
                         "another output folder")
    path = out / SETTINGS
    if resume and path.exists():
        try:
            old = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise BatchError(f"{str(path)!r} is not readable JSON ({exc}); it holds the settings of the batch to "
                             "resume") from None
        if old.get("version") == 2:
            raise BatchError(f"the batch in {str(out)!r} was written by an older arsurf, whose rows do not record "
                             "their output files' SHA-256; it cannot be verified, so not resumed: choose another "
                             "output folder")
        was = old.get("version") if old.get("version") in (1, BATCH_FORMAT_VERSION) else BATCH_FORMAT_VERSION
        if old != _settings(pipeline, options, was):
            mine = _settings(pipeline, options, was)["options"]
            api = dict(zip(mine, options))  # the file's option names -> the API's (as the user gave them)
            diff = sorted(api.get(k, k) for k in set(old.get("options", {})) | set(mine)
                          if old.get("options", {}).get(k) != mine.get(k))
            what = f"options {diff}" if old.get("pipeline") == pipeline.name else f"pipeline {old.get('pipeline')!r}"
            raise BatchError(f"cannot resume the batch in {str(out)!r} with other settings ({what} differ); "
                             "rerun it with the same ones, or choose another output folder")
    out.mkdir(parents=True, exist_ok=True)
    write_text(path, json.dumps(settings, indent=2, sort_keys=True) + "\n", what="batch settings", error=BatchError)


def _summary(pipeline: Pipeline, items: Sequence[Item], rows: Mapping[str, Mapping], ran: int, skipped: int,
             elapsed: float, complete: bool, not_inputs: Sequence[str] = ()) -> dict:
    mine = [rows[it.key] for it in items if it.key in rows]
    ok = [r for r in mine if r.get("status") == "ok"]
    failed = [(r["item"], r.get("error", "")) for r in mine if r.get("status") != "ok"]
    stats = {}
    for col in pipeline.columns[len(BASE_COLUMNS):]:
        try:
            values = np.array([float(r[col]) for r in ok if r.get(col, "") != ""], dtype=float)
        except ValueError:
            continue  # a text column
        values = values[np.isfinite(values)]
        if values.size:
            stats[col] = {"min": float(values.min()), "median": float(np.median(values)), "max": float(values.max()),
                          "count": int(values.size)}
    return {"format": BATCH_FORMAT, "version": BATCH_FORMAT_VERSION, "pipeline": pipeline.name,
            "complete": complete, "items": len(items), "ok": len(ok), "failed": len(failed),
            "not_run": len(items) - len(mine), "ran_this_time": ran, "skipped_as_done": skipped,
            "elapsed_s": elapsed, "items_per_s": ran / elapsed if elapsed > 0 else None,
            "errors": [{"item": k, "reason": v} for k, v in failed], "statistics": stats,
            "not_inputs": list(not_inputs)}


def run_batch(pipeline: str, inputs: Sequence[str | os.PathLike], out_dir: str | os.PathLike, *,
              options: Mapping | None = None, workers: int | None = None, scheduler=None, resume: bool = False,
              progress: bool = True, connect_timeout: float = 10.0,
              item_timeout: float | None = ITEM_TIMEOUT) -> BatchResult:
    """Run a pipeline over many files; write ``results.csv``, ``batch.json``, ``summary.json`` and the item outputs.

    Parameters
    ----------
    pipeline : {"process", "replay", "sweep"}
        See the module docstring.
    inputs : sequence of path-like or str
        Files, folders and glob patterns (:func:`collect_inputs`).
    out_dir : path-like
        Output folder (created). It must not hold a results table unless ``resume``.
    options : mapping, optional
        SI options of the pipeline. ``process``: ``channel``, ``level`` (default ``"plane"``),
        ``sigma`` (m, 0), ``inpaint`` (True), ``control_shape`` ((nu, nv) or None: interpolate),
        ``smoothing`` (0), ``export`` (extensions: ``.stl .ply .glb .gwy .gsf .npz .npy``),
        ``resolution`` ((nu, nv) export samples), ``solid``, ``dx``/``dy`` (m) and ``z_unit`` for
        bare matrices. ``replay``: ``scan`` (default: each session's recorded scan). ``sweep``:
        ``friction``, ``tip_radius`` (m), ``effective_modulus`` (Pa) (lists: the grid; default the
        preset's value), ``preset`` (``"demo"``), ``depth`` (m, 2e-9), ``slide`` (m, 20e-9),
        ``steps`` (40 per leg), ``at`` ((x, y) m; default the middle).
    workers : int, optional
        Local worker processes (default: the CPU count; 0: run in this process).
    scheduler : str or distributed.Client, optional
        A Dask scheduler address (``tcp://host:8786``) or client: run on that cluster instead.
    resume : bool
        Skip the items whose latest row in an existing table has ``status`` ``ok``.
    progress : bool
        A counter on stderr.
    connect_timeout : float, s
        How long to wait for the Dask scheduler.
    item_timeout : float or None, s
        Time limit of one item (:data:`ITEM_TIMEOUT` by default; None: none): an item past it is an
        ``error`` row and the batch goes on (local workers; Dask workers keep the cluster's limits).

    Returns
    -------
    BatchResult

    Raises
    ------
    BatchError
        No input, a bad option, an existing table without ``resume``, a table or settings of another
        batch with ``resume``, both ``workers`` and ``scheduler``, an unreachable scheduler.
    MissingDependency
        ``scheduler`` without ``dask.distributed`` installed (``pip install 'arsurf[dask]'``).
    """
    t0 = time.perf_counter()
    p = get_pipeline(pipeline)
    if scheduler is not None and workers is not None:
        raise BatchError("give the local worker count or a Dask scheduler, not both (--workers or --scheduler)")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, (int, np.integer))
                                or not 0 <= workers <= 4096):
        raise BatchError(f"workers must be an integer in [0, 4096] (got {workers!r}); 0 runs in this process")
    if isinstance(scheduler, str) and not scheduler.strip():
        raise BatchError("the Dask scheduler address is empty; give tcp://HOST:PORT")
    if not (isinstance(connect_timeout, (int, float)) and math.isfinite(connect_timeout) and connect_timeout > 0):
        raise BatchError(f"connect_timeout must be a positive number of seconds (got {connect_timeout!r})")
    if item_timeout is not None and not (isinstance(item_timeout, (int, float)) and not isinstance(item_timeout, bool)
                                         and math.isfinite(item_timeout) and item_timeout > 0):
        raise BatchError(f"item_timeout must be a positive number of seconds or None (got {item_timeout!r})")
    if scheduler is not None:
        require("distributed", "dask", "arsurf batch on a Dask cluster (--scheduler)")
    opts = json.loads(json.dumps(p.check(dict(options or {}))))  # JSON-normal: tuples -> lists
    out = Path(out_dir)
    files, root, left = collect_inputs(inputs, p.suffixes, exclude=out)
    items = make_items(p, files, root, opts)
    not_inputs = tuple(os.path.relpath(f, root) for f in left)
    if len({it.key for it in items}) != len(items):
        raise BatchError("two inputs give the same item name; rename one of them")
    client, own = connect(scheduler, float(connect_timeout)) if scheduler is not None else (None, False)
    try:
        return _run(p, items, opts, out, workers, client, resume, progress, t0, item_timeout, not_inputs)
    finally:
        if own:
            client.close()


def _run(p: Pipeline, items: list[Item], opts: dict, out: Path, workers, client, resume: bool, progress: bool,
         t0: float, item_timeout: float | None = ITEM_TIMEOUT, not_inputs: tuple[str, ...] = ()) -> BatchResult:
    """The part of :func:`run_batch` after every check: the table, the execution, the summary."""
    _check_out_dir(out, p, opts, resume)
    table_path = check_target(out / TABLE, "results table", error=BatchError)  # not a planted link
    repair_table(table_path)
    rows = read_results(table_path, p.columns) if resume else {}
    todo = [it for it in items if not _row_stands(rows.get(it.key), p.columns, out)]
    skipped = len(items) - len(todo)
    table = ResultTable(table_path, p.columns)
    bar = _Progress(len(items), skipped, progress)
    ran = 0

    def record(i: int, row: Mapping) -> None:
        nonlocal ran
        table.append(row)
        rows[row["item"]] = {c: cell(row.get(c)) for c in p.columns}
        ran += 1
        bar.update(row["status"] == "ok")

    def crashed(i: int, reason: str) -> None:
        record(i, {"item": todo[i].key, "status": "error", "error": reason})

    calls = [(p.name, it, opts, str(out.resolve()), item_timeout) for it in todo]
    complete = False
    try:
        if not calls:
            pass
        elif client is not None:
            execute_dask(run_item, calls, client, record, crashed)
        else:
            n = (os.cpu_count() or 1) if workers is None else int(workers)
            execute_local(run_item, calls, min(n, len(calls)), record, crashed)
        complete = True
    finally:
        table.close()
        bar.close()
        elapsed = time.perf_counter() - t0
        summary = _summary(p, items, rows, ran, skipped, elapsed, complete, not_inputs)
        write_text(out / SUMMARY, summary_json(summary), what="batch summary", error=BatchError)
    return BatchResult(out_dir=out, table=table_path, summary=out / SUMMARY, total=len(items), ran=ran,
                       skipped=skipped, ok=summary["ok"], failed=summary["failed"],
                       errors=tuple((e["item"], e["reason"]) for e in summary["errors"]), elapsed=elapsed,
                       items_per_second=summary["items_per_s"] or 0.0, not_inputs=not_inputs)
