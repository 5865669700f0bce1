"""Benchmark: robustness under faults, in one JSON - recordings killed, sessions mutated, the bridge
attacked, the server's tick given faults.

Runs the three focused benches (``robustness_recording.py``: SIGKILL/SIGTERM/SIGINT during a real
recording; ``fuzz_sessions.py``: bit flips, truncations and crafted session files;
``robustness_bridge.py``: hijacks, forged/replayed/reordered/oversized packets, NaN and huge
forces) as subprocesses and merges their JSON, then injects faults into the server's tick itself:
a hand pressing a virtual Touch X into a surface at 1 kHz (direct coupling, 25 mN), and at tick
500 one fault - an exception in the step (the live loop's servo thread), a NaN or ±1.7e308 stylus
reading, a sample stale or stamped ahead of the clock, malformed buttons, a stalled clock, a
10 kN force request - held for 50 ticks. For each: the largest force commanded after the fault,
the ticks until it is zero (or back within the device limit), and whether anything non-finite or
above the limit reached the device.

Run: .venv/bin/python bench/robustness.py [--quick]   (prints JSON)
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
FAULTS = ("exception", "nan_position", "huge_position", "stale", "future", "bad_buttons", "clock_stall",
          "huge_force")


def _sub(script: str, *args: str) -> dict:
    r = subprocess.run([sys.executable, str(HERE / script), *args], capture_output=True, text=True, timeout=3600)
    if r.returncode != 0:
        return {"error": (r.stderr.strip().splitlines() or ["failed"])[-1]}
    return json.loads(r.stdout)


def server_faults() -> dict:
    from arsurf.assembly import make_model
    from arsurf.haptics.device import DeviceState
    from arsurf.haptics.loop import HapticLoop
    from arsurf.haptics.virtual_device import HandModel, VirtualDevice
    from arsurf.spline.surface import BSplineSurface

    R = 20e-9
    rows = {}
    for fault in FAULTS:
        s = BSplineSurface.from_heights(np.zeros((40, 40)), (0.0, 37 * 4e-9), (0.0, 37 * 4e-9))
        model = make_model(s, tip_radius=R, effective_modulus=10e9, work_of_adhesion=0.1)
        dev = VirtualDevice(dt=1e-3, hand=HandModel(lambda t: [0.0, 0.0, -1e-3])).open()
        loop = HapticLoop.direct(model, dev.info, (70e-9, 70e-9, R + 2e-9), ramp_time=0.05)
        limit = dev.info.max_force
        forces = []
        now = 0.0
        for k in range(700):
            st = dev.read_state()
            now = st.timestamp if not (fault == "clock_stall" and 500 <= k < 550) else now
            pos, vel, buttons, stamp = st.position.copy(), st.velocity.copy(), st.buttons, st.timestamp
            active = 500 <= k < 550
            if active and fault == "nan_position":
                pos[0] = np.nan
            elif active and fault == "huge_position":
                pos[:] = 1.7e308
            elif active and fault == "stale":
                stamp -= 1.0
            elif active and fault == "future":
                stamp += 1.0
            elif active and fault == "bad_buttons":
                buttons = 2 ** 64
            if active and fault == "exception":
                f = np.zeros(3)  # the live loop's servo thread commands zero from its except clause
            else:
                if active and fault == "huge_force":  # a 10 kN request: the force gain scaled up 5e5x
                    gain = loop._gain.copy()
                    loop._gain[:] = 5e10
                f = np.array(loop.step(DeviceState(pos, vel, buttons, stamp), now), dtype=float)
                if active and fault == "huge_force":
                    loop._gain[:] = gain
            dev.command_force(f)
            forces.append(f)
        dev.close()
        F = np.linalg.norm(np.array(forces), axis=1)
        after = F[500:550]
        zero_at = next((i for i, x in enumerate(after) if x == 0.0), None)
        rows[fault] = {"force_before_N": float(F[499]), "worst_force_after_N": float(after.max()),
                       "ticks_until_zero": zero_at, "worst_force_overall_N": float(F.max()),
                       "nonfinite_commanded": int((~np.isfinite(np.array(forces))).any()),
                       "above_limit": int((F > limit * (1 + 1e-12)).sum()), "device_limit_N": limit,
                       "recovered_N": float(F[-1])}
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small counts (a smoke run)")
    args = ap.parse_args()
    q = args.quick
    out = {
        "recording_kills": _sub("robustness_recording.py", *(["--kills", "5", "--terms", "1", "--ints", "1"] if q else [])),
        "session_mutants": _sub("fuzz_sessions.py", *(["--sealed", "300", "--resealed", "20", "--version1", "20",
                                                       "--journal", "100"] if q else [])),
        "bridge_attacks": _sub("robustness_bridge.py", *(["--n", "20"] if q else [])),
        "server_faults": server_faults(),
    }
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
