"""Scale: time to the first ticks and memory per pixel, 256^2 to 8192^2, and ticks across tiles.

For each size N (one fresh process each, so memory is measured cleanly) a rough synthetic scan
(N x N pixels of 4 nm) is fitted, then timed:

* ``model_ready_s``: ``make_model`` (the AR model with its projector) on the fitted surface;
* ``first_1000_ticks_s``: model ready + 1000 compiled ticks of a tip tracing the surface;
* ``projector_bytes_per_pixel``: the projection structure's own arrays (tile pool or whole
  pyramid) per pixel; ``rss_delta_bytes_per_pixel``: the process's resident memory added by
  the model and the ticks, per pixel (includes the rest copy of the control net, 24 B/px);
* ``sweep``: 20,000 ticks of the tip moving in a straight line across ~40 tiles: median, p99 and
  max tick time (the max includes a tile built in a tick).

The peer, timed in the same run for the sizes where it is affordable (<= 2048^2): the whole
pyramid (``arsurf.contact.projection.Projector``), as every surface had before tiling.
Ratios are to 256^2. Prints JSON. Usage: ``python bench/scale.py [--max 8192]``.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _rss() -> int:
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def worker(n: int, whole: bool) -> dict:
    import numpy as np

    from arsurf.assembly import make_model
    from arsurf.contact import projection as pj
    from arsurf.scan.scan import Scan
    from arsurf.spline.fit import fit_surface

    # warm the compiled kernels on a small surface (compile time is not what is measured)
    default = pj.TILED_ABOVE
    rng = np.random.default_rng(0)
    h = 4e-9
    small = fit_surface(Scan(rng.normal(size=(64, 64)) * 1e-9, h, h))
    for tiled in (False, True):
        pj.TILED_ABOVE = 0 if tiled else 10**12
        m = make_model(small.copy(), tip_radius=20e-9, effective_modulus=10e9, work_of_adhesion=0.1, deform=False)
        m.tick((100e-9, 100e-9, 20e-9))
    pj.TILED_ABOVE = 10**12 if whole else default

    t0 = time.perf_counter()
    y = np.arange(n) * h
    z = (3e-9 * np.sin(y / 90e-9)[:, None] * np.cos(y / 130e-9)[None, :]).astype(np.float64)
    z += rng.normal(size=(n, n)) * 0.3e-9
    scan = Scan(z, h, h)
    del z
    surface = fit_surface(scan)
    del scan
    fit_s = time.perf_counter() - t0
    x0 = 0.5 * n * h
    xs = x0 + np.linspace(0.0, 200e-9, 1000)
    path = np.column_stack([xs, np.full_like(xs, x0), surface.evaluate(xs, np.full_like(xs, x0))[:, 2] + 18e-9])
    rss0 = _rss()
    t0 = time.perf_counter()
    model = make_model(surface, tip_radius=20e-9, effective_modulus=10e9, work_of_adhesion=0.1)
    ready = time.perf_counter() - t0
    for c in path:
        model.tick(c)
    first = time.perf_counter() - t0
    proj = pj.projector(model.rest_surface)
    proj_bytes = proj.nbytes if isinstance(proj, pj.TiledProjector) else int(
        sum(a.nbytes for a in (proj.tree.nodes, proj.tree.curv, proj.work, proj.tree.mu, proj.tree.mv)))
    # sweep across tiles: 20 000 ticks along x over ~40 tiles of 16 cells (2.6 um at 4 nm)
    ticks = []
    xs = x0 + np.linspace(-1.3e-6, 1.3e-6, 20000)
    zs = surface.evaluate(xs, np.full_like(xs, x0))[:, 2] + 18e-9
    clock = time.perf_counter_ns
    for x, zc in zip(xs, zs):
        t = clock()
        model.tick((x, x0, zc))
        ticks.append(clock() - t)
    ticks = np.array(ticks) / 1e3
    out = {"n": n, "whole_pyramid": whole, "fit_s": fit_s, "model_ready_s": ready, "first_1000_ticks_s": first,
           "projector_bytes_per_pixel": proj_bytes / n / n, "rss_delta_bytes_per_pixel": (_rss() - rss0) / n / n,
           "sweep_tick_us": {"median": float(np.median(ticks)), "p99": float(np.percentile(ticks, 99)),
                             "max": float(ticks.max()), "over_100us": int((ticks > 100).sum()),
                             "over_1ms": int((ticks > 1000).sum())}}
    if isinstance(proj, pj.TiledProjector):
        out["tiles"] = {"count": proj.tile_count, "built": proj.tiles_built, "builds": proj.builds}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--max", type=int, default=8192)
    ap.add_argument("--whole-max", type=int, default=2048, help="largest size timed with the whole pyramid")
    args = ap.parse_args()
    sizes = [n for n in (256, 512, 1024, 2048, 4096, 8192) if n <= args.max]
    results = []
    for whole in (False, True):
        for n in sizes:
            if whole and n > args.whole_max:
                continue
            code = f"import json, sys; sys.path.insert(0, {str(ROOT / 'bench')!r}); import scale; " \
                   f"print(json.dumps(scale.worker({n}, {whole})))"
            run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=1800)
            if run.returncode != 0:
                results.append({"n": n, "whole_pyramid": whole, "error": run.stderr.strip().splitlines()[-1:]})
                continue
            results.append(json.loads(run.stdout.strip().splitlines()[-1]))
    base = {r["whole_pyramid"]: r for r in results if r.get("n") == 256 and "error" not in r}
    for r in results:
        b = base.get(r["whole_pyramid"])
        if b and "error" not in r:
            r["first_1000_ticks_ratio_to_256"] = r["first_1000_ticks_s"] / b["first_1000_ticks_s"]
    tiled256 = base.get(False)
    if tiled256:
        for r in results:
            if "error" not in r:
                r["first_1000_ticks_ratio_to_tiled_256"] = r["first_1000_ticks_s"] / tiled256["first_1000_ticks_s"]
    print(json.dumps({"benchmark": "scale", "results": results}, indent=2))


if __name__ == "__main__":
    main()
