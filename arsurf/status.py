"""Status codes of the compiled kernels: one table, one meaning per code, used by every module.

A kernel returns an ``int``: 0 when it answered normally, > 0 when it answered with a caveat
the caller may want to flag, < 0 when it could not answer (its outputs are then zeros or NaN and
must not be used). The Python API turns the negative codes into exceptions and the positive ones
into flags.

===================  =====  =================================================================
name                 code   meaning
===================  =====  =================================================================
``OK``               0      answered
``ITERATION_LIMIT``  1      the iteration limit was hit: the answer is the best point found
``DEGENERATE``       2      a geometric degeneracy (e.g. S_u x S_v = 0) handled by the
                            documented fallback
``NON_FINITE``       -1     NaN/inf in the data or the input: no answer
``BAD_INPUT``        -2     an input outside its domain (e.g. a radius <= 0): no answer
``NOT_CONVERGED``    -3     the solver did not meet its tolerance: no answer
===================  =====  =================================================================

Kernels with their own *non-negative* results (Maugis-Dugdale returns the branch: 0 contact,
1 cohesive, 2 separated) use only the negative codes of this table for their failures.

Examples
--------
>>> TEXT[NON_FINITE]
'non-finite data or input'
>>> sorted(TEXT) == [-3, -2, -1, 0, 1, 2]
True
"""
from __future__ import annotations

__all__ = ["BAD_INPUT", "DEGENERATE", "ITERATION_LIMIT", "NON_FINITE", "NOT_CONVERGED", "OK", "TEXT"]

OK = 0
ITERATION_LIMIT = 1
DEGENERATE = 2
NON_FINITE = -1
BAD_INPUT = -2
NOT_CONVERGED = -3

#: a short text for each code (error messages, reports)
TEXT = {
    OK: "ok",
    ITERATION_LIMIT: "iteration limit reached (best point returned)",
    DEGENERATE: "degenerate geometry (fallback used)",
    NON_FINITE: "non-finite data or input",
    BAD_INPUT: "input outside its domain",
    NOT_CONVERGED: "solver did not converge",
}
