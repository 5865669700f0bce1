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

Kernels with their own *non-negative* results use only the negative codes of this table for their
failures. The contact-mechanics kernels (Maugis-Dugdale, and the virtual coupling and the model tick
that call it) return the **branch** of the equilibrium curve they answered on
(:class:`arsurf.contact.mechanics.Branch` is its enum):

=============  =====  =========================================================================
branch         code   meaning
=============  =====  =========================================================================
``CONTACT``    0      the surfaces touch over a disk of radius a >= 0
``COHESIVE``   1      no contact (a = 0), but the adhesive (Dugdale) zone still pulls: tensile load
``SEPARATED``  2      no interaction: radius 0, load 0
=============  =====  =========================================================================

A nano-object push (:mod:`arsurf.manipulation.nanotube`) answers with a caveat code of the first
table's kind: ``PUSH_OK`` (0), ``PUSH_SUBSTEP_CAP`` (1, the displacement needed more sub-steps than
allowed: coarser but still valid), ``PUSH_FALLBACK`` (2, the model's motion family could not clear
the tip: cleared by translation); :data:`PUSH_NAMES` names them in results.

The stages of the haptic loop (position scaling, coupling, safety) return **flag bits**; each bit
means one thing wherever it appears, so the words of several stages can be OR-ed and read with
one table:

======================  ======  =====================================================================
flag                    bit     meaning
======================  ======  =====================================================================
``SATURATED``           1       force norm clamped to the device's maximum
``RATE_LIMITED``        2       force change limited to the rate limit
``RAMPING``             4       engagement gain between 0 and 1 (start-up ramp or fault fade-out)
``STALE``               8       device sample older than the staleness limit
``WATCHDOG``            16      the loop missed its deadlines repeatedly
``DISENGAGED``          32      disengage button held
``NONFINITE``           64      NaN/inf met in an input: the stage's safe output instead
``CLUTCHED``            128     clutch held: the probe (or slave) frozen
``CLAMPED``             256     probe (or slave) clamped to its range
``MASTER_OUTSIDE``      512     master outside its workspace box
``BAD_BUTTONS``         1024    the device reported a malformed button word: taken as no press
``PASSIVITY``           2048    the passivity controller added damping (the loop had generated energy)
``SAMPLE_MALFORMED``    4096    device sample wrongly shaped, typed or not finite: zero force (fault)
``SAMPLE_OUTSIDE``      8192    device sample outside the device workspace plus margin: zero force (fault)
``SAMPLE_TOO_FAST``     16384   device sample moved faster than a stylus can: zero force (fault)
``TIME_BACKWARDS``      32768   the sample's stamp or the loop clock went backwards: zero force (fault)
``BEYOND_MODEL``        65536   the model tick's contact is wider than its contact law holds for
                                (a > :data:`~arsurf.contact.mechanics.SMALL_CONTACT_LIMIT` R; the
                                law assumes a << R): the force is an extrapolation (not a fault)
======================  ======  =====================================================================

The model tick sets ``BEYOND_MODEL`` in its own flag word (``model_flags`` of
:class:`arsurf.model.ModelTick`); the haptic loop ORs that word into the tick's flags, which a
session records (``safety_flags``) and the viewer's HUD names.

The decoupling's bits (:class:`arsurf.force.decoupling.DecouplingFlag`) are a word of their own,
recorded as such in session files.

Examples
--------
>>> TEXT[NON_FINITE]
'non-finite data or input'
>>> sorted(TEXT) == [-3, -2, -1, 0, 1, 2]
True
>>> BRANCH_NAMES[SEPARATED]
'separated'
"""
from __future__ import annotations

__all__ = ["BAD_BUTTONS", "BAD_INPUT", "BRANCH_NAMES", "CLAMPED", "CLUTCHED", "COHESIVE", "CONTACT",
           "DEGENERATE", "DISENGAGED", "FLAG_NAMES", "ITERATION_LIMIT", "MASTER_OUTSIDE", "NONFINITE",
           "NON_FINITE", "NOT_CONVERGED", "OK", "PASSIVITY", "PUSH_FALLBACK", "PUSH_NAMES", "PUSH_OK",
           "PUSH_SUBSTEP_CAP", "RAMPING", "RATE_LIMITED", "SAMPLE_MALFORMED", "SAMPLE_OUTSIDE", "SAMPLE_TOO_FAST",
           "SATURATED", "SEPARATED", "STALE", "TEXT", "TIME_BACKWARDS", "WATCHDOG", "BEYOND_MODEL",
           "flag_names"]

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
    BAD_INPUT: "input outside its domain (e.g. a non-finite point or a radius <= 0)",
    NOT_CONVERGED: "solver did not converge",
}

# branches of the contact-mechanics kernels (their non-negative results)
CONTACT = 0
COHESIVE = 1
SEPARATED = 2
#: the branches' names, by code
BRANCH_NAMES = ("contact", "cohesive", "separated")

# codes of a nano-object push
PUSH_OK = OK
PUSH_SUBSTEP_CAP = 1
PUSH_FALLBACK = 2
#: the push codes' names, by code
PUSH_NAMES = {PUSH_OK: "ok", PUSH_SUBSTEP_CAP: "substep_cap", PUSH_FALLBACK: "fallback"}

# flag bits of the haptic-loop stages
SATURATED = 1
RATE_LIMITED = 2
RAMPING = 4
STALE = 8
WATCHDOG = 16
DISENGAGED = 32
NONFINITE = 64
CLUTCHED = 128
CLAMPED = 256
MASTER_OUTSIDE = 512
BAD_BUTTONS = 1024
PASSIVITY = 2048
SAMPLE_MALFORMED = 4096
SAMPLE_OUTSIDE = 8192
SAMPLE_TOO_FAST = 16384
TIME_BACKWARDS = 32768
BEYOND_MODEL = 65536
#: names of the flag bits, lowest bit first
FLAG_NAMES = ("SATURATED", "RATE_LIMITED", "RAMPING", "STALE", "WATCHDOG", "DISENGAGED", "NONFINITE", "CLUTCHED",
              "CLAMPED", "MASTER_OUTSIDE", "BAD_BUTTONS", "PASSIVITY", "SAMPLE_MALFORMED", "SAMPLE_OUTSIDE",
              "SAMPLE_TOO_FAST", "TIME_BACKWARDS", "BEYOND_MODEL")


def flag_names(flags: int) -> list[str]:
    """The names of the bits set in ``flags``.

    Examples
    --------
    >>> flag_names(SATURATED | CLUTCHED)
    ['SATURATED', 'CLUTCHED']
    """
    return [name for bit, name in enumerate(FLAG_NAMES) if int(flags) >> bit & 1]
