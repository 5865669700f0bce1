"""Benchmark: the viewer's per-frame cost (in-place update, patch re-sampling, render).

Peers timed in the same run: re-sampling the whole grid every frame (what a naive viewer does)
against :class:`SurfaceView`'s patch re-sampling after a local dent; the render itself on the
backend at hand (llvmpipe software rendering when headless). The local dent is the haptic
tick's: a 20 nm tip 2 nm deep (a = 8 nm, Dugdale zone 10 nm) sliding 0.5 nm per frame, recorded
as the tick records it (``record_dent_kernel``); the frame moves the net to it (``sync``),
re-samples the patch, and redraws the dent's contours and colour limits.

Run: .venv/bin/python bench/viewer.py   (prints JSON)
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _timing import emit, stats, time_calls  # noqa: E402

from arsurf.contact.deformation import Deformer, record_dent_kernel  # noqa: E402
from arsurf.spline.surface import BSplineSurface  # noqa: E402
from arsurf_viewer import SceneState, SurfaceView  # noqa: E402


def cpu_calls(fn, repeat: int) -> np.ndarray:
    """This thread's CPU time of each call, s: what the frame costs on a machine where no other
    process preempts it (the wall time on a shared machine adds the waits)."""
    fn()
    out = np.empty(repeat)
    for i in range(repeat):
        t0 = time.thread_time_ns()
        fn()
        out[i] = time.thread_time_ns() - t0
    return out * 1e-9


def main() -> None:
    n = 258  # the net of an interpolating fit of a 256 x 256 scan
    length = 1e-6
    x = np.linspace(0.0, length, n)
    z = 5e-9 * np.sin(2 * np.pi * x[:, None] / 200e-9) * np.cos(2 * np.pi * x[None, :] / 300e-9)
    surface = BSplineSurface.from_heights(z, (0.0, length), (0.0, length))
    results = {}
    for res in (128, 256):
        view = SurfaceView(surface, resolution=res, off_screen=True, window_size=(960, 720), anti_aliasing=None)
        rest = surface.copy()  # the rest surface: where the tip is pressed from
        dent = Deformer(surface)
        _, _, ku, kv = surface.kernel_arrays()
        centre = np.array([0.5 * length, 0.5 * length, 0.0])
        state = SceneState(surface, centre + [0, 0, 25e-9], 20e-9, force=(0, 0, 1e-9))
        k = [0]

        def press():  # what the haptic tick does between two frames: record its dent
            k[0] += 1
            x = centre[0] + 0.5e-9 * (k[0] % 40)
            z = float(rest.evaluate(x, centre[1])[2]) + 18e-9
            record_dent_kernel(dent.dent, ku, kv, x, centre[1], z, 20e-9, 0.0, 0.0, 1.0, 8e-9, 2e-9, 10e-9)

        def move_only():
            state.tip_center[0] += 1e-12
            view.update(state, render=False)

        def dent_and_move():  # the dent moves every frame, as under the sliding tip
            press()
            view.update(state, render=False)

        def full_resample():  # the peer: the same dent, then re-sample everything
            press()
            surface.sync()
            view._resample(0, view.resolution[0], 0, view.resolution[1])

        t_move = time_calls(move_only, 30)
        t_dent = time_calls(dent_and_move, 30)
        t_full = time_calls(full_resample, 15)
        c_dent = cpu_calls(dent_and_move, 30)
        c_full = cpu_calls(full_resample, 15)
        view.screenshot()  # the first picture compiles the shaders; pyvista renders only after it
        t_render = time_calls(view.render, 10, warmup=2)
        t_shot = time_calls(view.screenshot, 10, warmup=1)
        dent.release()
        results[f"grid_{res}x{res}"] = {
            "update_tip_moves_only": stats(t_move),
            "update_with_local_dent": stats(t_dent),
            "full_resample_peer": stats(t_full),
            "speedup_patch_vs_full": float(np.median(t_full) / np.median(t_dent)),
            "update_with_local_dent_cpu": stats(c_dent),
            "full_resample_peer_cpu": stats(c_full),
            "render_960x720": stats(t_render),
            "screenshot_960x720": stats(t_shot),
            "backend": view.backend.name,
        }
        view.close()
    emit("viewer", results)


if __name__ == "__main__":
    main()
