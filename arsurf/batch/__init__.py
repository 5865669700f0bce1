"""Batch runs: one pipeline over many scans or sessions (:mod:`arsurf.batch.runner`)."""
from arsurf.batch.runner import (PIPELINES, BatchResult, Item, Pipeline, collect_inputs, make_items,  # noqa: F401
                                 read_results, run_batch)

__all__ = ["PIPELINES", "BatchResult", "Item", "Pipeline", "collect_inputs", "make_items", "read_results",
           "run_batch"]
