"""The engage procedure of [Alabdulmuhsin] (Sec. 3.4, Fig. 3.10): bring the tip into contact safely.

Starting with the sample a few micrometres below the tip, the procedure repeats:

1. read the vertical photodiode signal; if its change from the free-lever baseline has reached
   the set point, the tip is engaged: stop;
2. otherwise, if the nano stage is below its sweep range (0.2 um), raise it by one small step
   (1 nm);
3. otherwise lower the nano stage back to 0 and raise the micro stage by 0.16 um (80 % of the
   nano sweep).

Every move goes through the stage's LSPB profile (:mod:`arsurf.instrument.lspb`). The coarse
step is smaller than the fine sweep, so after each coarse step the fine sweep re-covers the
last 0.04 um it already checked: no height is skipped and the surface can never come closer
than it was at the previous (checked) fine step. The micro stage's 0.05 um resolution turns the
0.16 um steps into 0.15 and 0.20 um ones around the commanded staircase; 0.20 um still equals
the sweep, so the guarantee holds. The lever therefore bends by at most the set point plus one
fine step (plus the noise on the detection) before the procedure stops.

A safety layer watches the force estimated from every sample of the signal ([Alabdulmuhsin] Eq. 7,
``k S_n (V - V_0)``) and aborts, retracting the fine stage, if it exceeds ``force_limit``.

Examples
--------
>>> from arsurf.instrument.instrument import VirtualAFM
>>> afm = VirtualAFM(surface=0.0, probe_height=0.5e-6, seed=3)
>>> result = engage(afm, setpoint=0.05, force_limit=25e-9)
>>> result.engaged, bool(result.max_force < 25e-9)
(True, True)
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from arsurf._logging import progress
from arsurf.errors import InstrumentError

#: what the procedure drives: the stages of a virtual AFM (:class:`~arsurf.instrument.instrument.VirtualAFM`)
_STAGED = ("stages", "position", "dwell", "move", "history", "rate", "deflection_sensitivity", "spring_constant")


@dataclass(frozen=True)
class EngageResult:
    """Outcome of :func:`engage`.

    Attributes
    ----------
    engaged : bool
    reason : str
        ``"setpoint"`` (engaged), ``"force_limit"`` (aborted by the safety layer) or
        ``"out_of_travel"`` (the micro stage ran out of range, or ``max_micro_steps`` was reached).
    baseline : float
        Free-lever signal measured before approaching.
    signal : float
        Signal change (averaged) at the last check.
    fine_steps, coarse_steps : int
        Nano-stage steps and micro-stage steps made.
    max_force : float, newtons
        Largest true force on the tip during the whole run (from the history).
    history : InstrumentHistory
        Every simulated sample (time, stage positions, gap, deflection, force, signal).
    """

    engaged: bool
    reason: str
    baseline: float
    signal: float
    fine_steps: int
    coarse_steps: int
    max_force: float
    history: "InstrumentHistory"  # noqa: F821 - arsurf.instrument.instrument, which calls this module

    @property
    def duration(self) -> float:
        """Simulated time of the run, seconds."""
        return float(self.history.time[-1]) if len(self.history) else 0.0


def engage(afm, setpoint: float, *, fine_step: float = 1e-9, fine_range: float = 0.2e-6,
           coarse_step: float = 0.16e-6, fine_stage: str = "nano", coarse_stage: str = "micro",
           samples_per_check: int = 10, baseline_time: float = 0.05, force_limit: float | None = None,
           max_coarse_steps: int | None = None) -> EngageResult:
    """Engage the tip with the sample ([Alabdulmuhsin] Fig. 3.10) on a :class:`VirtualAFM`.

    Parameters
    ----------
    afm : VirtualAFM
        The instrument, with the tip out of contact.
    setpoint : float
        Change of the normalised vertical signal that means contact, in signal units; its sign is
        taken from the detector (``afm.deflection_sensitivity``), so pass a magnitude.
    fine_step, fine_range : float, metres
        Nano-stage step (1 nm) and sweep (0.2 um), [Alabdulmuhsin].
    coarse_step : float, metres
        Micro-stage step (0.16 um = 80 % of the sweep), [Alabdulmuhsin]. Must not exceed ``fine_range``.
    fine_stage, coarse_stage : str
        ``"nano"``/``"micro"``; [Alabdulmuhsin] notes the PicoCube can replace the nano stage
        (``fine_stage="pico"``).
    samples_per_check : int
        Signal samples averaged at each check (one per loop tick: 10 ticks = 1 ms at 10 kHz).
    baseline_time : float, seconds
        Dwell over which the free-lever signal is averaged first.
    force_limit : float, newtons, optional
        Abort when the force estimated from any signal sample exceeds it.
    max_coarse_steps : int, optional
        Give up after this many coarse steps (default: the coarse stage's travel).

    Returns
    -------
    EngageResult

    Raises
    ------
    InstrumentError
        Invalid settings, or the lever already in contact (the signal at the start is beyond the
        set point).
    """
    if not all(hasattr(afm, a) for a in _STAGED):
        raise InstrumentError(f"afm must be a VirtualAFM, whose stages this procedure drives (got "
                              f"{type(afm).__name__}); a controller engages with its own Instrument.engage()")
    sp = float(setpoint)
    if not (math.isfinite(sp) and 0.0 < abs(sp) < 1.0):
        raise InstrumentError(f"setpoint must be a signal change in (0, 1) (got {setpoint!r}); e.g. 0.05")
    sp = abs(sp)
    for name, v in (("fine_step", fine_step), ("fine_range", fine_range), ("coarse_step", coarse_step)):
        if not (math.isfinite(v) and v > 0.0):
            raise InstrumentError(f"{name} must be positive, in metres (got {v!r})")
    if coarse_step > fine_range:
        raise InstrumentError(
            f"coarse_step ({coarse_step:g} m) must not exceed fine_range ({fine_range:g} m): a larger "
            "coarse step would skip heights the fine sweep never checked and could crash the tip"
        )
    for name in (fine_stage, coarse_stage):
        if name not in afm.stages:
            raise InstrumentError(f"stage must be one of {sorted(afm.stages)} (got {name!r})")
    if fine_stage == coarse_stage:
        raise InstrumentError("fine_stage and coarse_stage must be different stages")
    if int(samples_per_check) < 1:
        raise InstrumentError(f"samples_per_check must be >= 1 (got {samples_per_check!r})")
    if force_limit is not None and not (math.isfinite(force_limit) and force_limit > 0.0):
        raise InstrumentError(f"force_limit must be positive, in newtons (got {force_limit!r})")
    polarity = math.copysign(1.0, afm.deflection_sensitivity)
    check_time = int(samples_per_check) / afm.rate
    k_s = afm.spring_constant * abs(afm.deflection_sensitivity)

    base = float(np.mean(afm.dwell(baseline_time)))

    def change(sig: np.ndarray) -> np.ndarray:
        return polarity * (sig - base)

    def unsafe(sig: np.ndarray) -> bool:
        return force_limit is not None and bool(np.any(k_s * change(sig) > force_limit))

    fine_home = afm.position[fine_stage]
    coarse_start = afm.position[coarse_stage]
    travel = afm.stages[coarse_stage].travel
    cap = max_coarse_steps if max_coarse_steps is not None else int(travel / coarse_step) + 1
    n_fine = int(round(fine_range / fine_step))
    fine = coarse = 0
    sweep = 0  # fine steps in the current sweep
    reason = "out_of_travel"
    engaged = False
    last = 0.0
    bar = progress(desc="engage", unit="step")  # ~6000 steps, a few seconds, count unknown in advance
    while True:
        bar.update(1)
        sig = afm.dwell(check_time)
        last = float(np.mean(change(sig)))
        if unsafe(sig):
            reason = "force_limit"
            break
        if last >= sp:
            reason, engaged = "setpoint", True
            break
        if sweep < n_fine:
            sweep += 1
            fine += 1
            sig = afm.move(fine_stage, fine_home + sweep * fine_step)
        else:
            if coarse >= cap:
                break
            target = coarse_start + (coarse + 1) * coarse_step  # the commanded staircase
            if not (-0.5 * afm.stages[coarse_stage].resolution <= target <= travel):
                break
            sig = afm.move(fine_stage, fine_home)
            if unsafe(sig):
                reason = "force_limit"
                break
            coarse += 1
            sweep = 0
            sig = afm.move(coarse_stage, target)
        if unsafe(sig):
            reason = "force_limit"
            break
    bar.close()
    if reason == "force_limit":
        afm.move(fine_stage, fine_home)  # retract the fine stage
    hist = afm.history()
    return EngageResult(engaged, reason, base, last, fine, coarse, float(hist.force.max(initial=0.0)), hist)
