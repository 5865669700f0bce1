"""Benchmark: the viewer's per-frame cost (in-place update, patch re-sampling, render).

Peers timed in the same run, interleaved: re-sampling the whole grid every frame (what a naive
viewer does: the view's own kernel over every sample, and the surface's parallel batch
evaluation with numpy normals, as the view did before its patch kernels) against
:class:`SurfaceView`'s local frame after a local dent; the render itself on the backend at hand
(llvmpipe software rendering when headless). The local dent is the haptic tick's: a 20 nm tip
2 nm deep (a = 8 nm, Dugdale zone 10 nm) sliding 0.5 nm per frame, recorded as the tick records
it (``record_dent_kernel``); the frame moves the net to it (``sync``), re-samples the patch,
finds the deformed samples and contours them (the colour limits stay). Each figure: median,
p90 and p99 in µs, as wall time and as this thread's CPU time (the parallel batch evaluation's
worker threads are not in its CPU figure); ``ratio_full_over_local``: the faster peer's median
over the local frame's.

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


def interleaved(fns: dict, rounds: int, per_round: dict, clock) -> dict:
    """Samples (s) of each function in ``fns``, taken in ``rounds`` alternating blocks of
    ``per_round[name]`` calls each (the machine's slow phases fall on every peer alike)."""
    out = {name: [] for name in fns}
    for name, fn in fns.items():  # warm-up
        fn()
    for _ in range(rounds):
        for name, fn in fns.items():
            for _ in range(per_round[name]):
                t0 = clock()
                fn()
                out[name].append(clock() - t0)
    return {name: np.array(v) * 1e-9 for name, v in out.items()}


def spread(samples_s: np.ndarray) -> dict:
    """Median, p90 and p99 in µs of samples in s (and their number)."""
    us = np.asarray(samples_s) * 1e6
    return {"median_us": float(np.median(us)), "p90_us": float(np.percentile(us, 90)),
            "p99_us": float(np.percentile(us, 99)), "n": int(us.size)}


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
        uu, vv = np.meshgrid(view._u, view._v)

        def press():  # what the haptic tick does between two frames: record its dent
            k[0] += 1
            x = centre[0] + 0.5e-9 * (k[0] % 40)
            z = float(rest.evaluate(x, centre[1])[2]) + 18e-9
            record_dent_kernel(dent.dent, ku, kv, x, centre[1], z, 20e-9, 0.0, 0.0, 1.0, 8e-9, 2e-9, 10e-9)

        def move_only():
            state.tip_center[0] += 1e-12
            view.update(state, render=False)

        def local_frame():  # the dent moves every frame, as under the sliding tip
            press()
            view.update(state, render=False)

        def full_resample():  # peer 1: the same dent, then every sample re-sampled by the view's kernel
            press()
            surface.sync()
            view._resample(0, view.resolution[0], 0, view.resolution[1])

        def full_batch_evaluate():  # peer 2: the same dent, the whole grid by the batch evaluation + numpy
            press()
            S, Su, Sv = surface.evaluate(uu, vv, 1)
            nrm = np.cross(Su, Sv)
            nrm /= np.maximum(np.linalg.norm(nrm, axis=-1, keepdims=True), 1e-300)
            pts = S * 1e9
            view._pts[...] = pts
            view._normals[...] = nrm
            view._height[...] = pts[..., 2]
            view._deform[...] = np.linalg.norm(pts - view._rest_points, axis=-1)
            view._resample(0, 0, 0, 0)

        fns = {"local": local_frame, "full": full_resample, "batch": full_batch_evaluate}
        per = {"local": 25, "full": 4, "batch": 4}
        wall = interleaved(fns, 8, per, time.perf_counter_ns)
        cpu = interleaved(fns, 8, per, time.thread_time_ns)
        t_move = time_calls(move_only, 60)
        view.screenshot()  # the first picture compiles the shaders; pyvista renders only after it
        t_render = time_calls(view.render, 10, warmup=2)
        t_shot = time_calls(view.screenshot, 10, warmup=1)
        dent.release()
        peer = min(("full", "batch"), key=lambda name: float(np.median(wall[name])))
        peer_cpu = min(("full", "batch"), key=lambda name: float(np.median(cpu[name])))
        results[f"grid_{res}x{res}"] = {
            "update_with_local_dent": spread(wall["local"]),
            "full_resample_peer": spread(wall["full"]),
            "full_batch_evaluate_peer": spread(wall["batch"]),
            "ratio_full_over_local": float(np.median(wall[peer]) / np.median(wall["local"])),
            "update_with_local_dent_cpu": spread(cpu["local"]),
            "full_resample_peer_cpu": spread(cpu["full"]),
            "full_batch_evaluate_peer_cpu": spread(cpu["batch"]),
            "ratio_full_over_local_cpu": float(np.median(cpu[peer_cpu]) / np.median(cpu["local"])),
            "update_tip_moves_only": stats(t_move),
            "render_960x720": stats(t_render),
            "screenshot_960x720": stats(t_shot),
            "backend": view.backend.name,
        }
        view.close()
    emit("viewer", results)


if __name__ == "__main__":
    main()
