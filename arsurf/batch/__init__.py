r"""Batch runs: one pipeline over many scans or sessions, on local processes or a Dask cluster.

:func:`run_batch` (and ``arsurf batch PIPELINE INPUT... --out DIR``) applies one of three
pipelines to every file of a folder, a glob or a list of files:

===========  =====================================================================================
pipeline     what each item does
===========  =====================================================================================
``process``  load, inpaint, level, smooth (:func:`arsurf.scan.prepare.prepare_scan`), fit a bicubic
             B-spline (:func:`arsurf.spline.fit.fit_surface`), save it (``<item>.surface.npz``,
             :func:`arsurf.spline.storage.save_surface`) and export it if asked (mesh: STL/PLY/GLB by
             :func:`arsurf.export.export_surface`; height map: .gwy/.gsf/.npz/.npy, as ``arsurf export``)
``replay``   replay a recorded session (:func:`arsurf.replay.replay.replay`) into ``<item>/``
``sweep``    a contact sweep over a grid of friction coefficient x tip radius x effective modulus on
             each scan: one item per scan and grid point (below)
===========  =====================================================================================

Execution: local worker processes by default (:class:`concurrent.futures.ProcessPoolExecutor`,
``workers``; 0 runs the items in this process), or the workers of a Dask cluster when a scheduler
address is given (``dask.distributed``, the optional extra ``arsurf[dask]``; the workers must
have arsurf installed and see ``out_dir`` and the input files on a shared file system). Whichever
runs them, the items give the same results: the sweep and the fit are deterministic.

Errors of one item never stop the batch: the item gets a row with ``status`` = ``error`` and a
one-line reason (``CorruptScan: ...``). A worker process that dies (a crash, the OOM killer) breaks
the local pool: the items it held are rerun one at a time in a fresh pool, so the one that kills
its worker is found and reported, and the others complete.

Files written to ``out_dir``:

=================  ===============================================================================
``results.csv``    one row per finished item, appended and flushed (``fsync``) as each finishes; the
                   columns carry their unit (``rms_roughness_m``, ``fit_time_s``, ``peak_load_N``;
                   counts and ratios have none). Floats are written with ``repr`` (exact round trip),
                   ``nan`` where a value does not exist, empty cells in the rows of failed items
``batch.json``     the pipeline and its options (SI, each named with its unit: ``sigma_m``,
                   ``tip_radius_m``; :mod:`arsurf.units`), written at the start; a resumed batch must
                   have the same
``summary.json``   counts (ok, failed, skipped), the failures with their reasons, ``elapsed_s``,
                   ``items_per_s``, and min / median / max of every numeric column over the items
                   that succeeded (under the column's name, so in its unit); rewritten at the end
                   (``"complete": false`` when interrupted)
per item           ``process``: ``<item>.surface.npz`` (+ exports), ``replay``: ``<item>/``
=================  ===============================================================================

``<item>`` is the input's path relative to the common folder of all inputs, with ``/`` written
``__``. Each row lists the files its item wrote with their size and SHA-256 (``output_files``,
``name|size_bytes|sha256;...``). With ``resume``, an item is skipped only when its latest row says
``ok``, parses, and every file it lists is there with that size and SHA-256; the others (failed,
never finished, a row that does not parse, an output deleted or changed) run again. Each item has
a time limit (``item_timeout``, :data:`ITEM_TIMEOUT`). ``replay`` without a ``scan`` option reads
each session through the checked, isolated reader first and uses the scan it recorded only when
that lies under the batch's inputs: a session cannot make the batch open or hash another file. A row is written only after an item's files are complete,
and a torn last line (the batch killed while writing it) is cut off before appending, so the table
stays valid whatever moment the batch was stopped.

Sweep (one item per scan x friction x tip radius x modulus; the scan prepared and fitted as the
``preset`` says, once per worker): on the fitted surface at ``at`` (default the middle of the
scan), with the preset's work of adhesion, cantilever and deformation, the tip centre is driven in
three straight legs of ``steps`` ticks each through the :class:`~arsurf.model.ARModel`:

1. **press**: from 2 nm above contact down to the indentation ``depth`` (on the rest surface);
2. **slide**: ``slide`` metres along +x at that centre height (the depth follows the topography);
3. **retract**: straight up to 10 nm above the start of contact.

The row gives the largest depth and load and the contact radius at the largest load
(Maugis-Dugdale, :mod:`arsurf.contact.maugis_dugdale`), the pull-off force (the most tensile load
while retracting), and the friction during the slide: the mean tangential force
:math:`|F - P n|` and the mean ratio :math:`|F_t| / N` over the ticks where the friction proxy
slipped, :math:`N = P + |P_c|` under the default adhesive friction law (:mod:`arsurf.contact.friction`;
on a flat surface it equals the kinetic coefficient).
The motion is scripted, without a hand, device or haptic loop, so the answers depend only on the
contact physics being swept (:mod:`arsurf.feel_scenarios` scores the feel through the whole loop);
it is :func:`arsurf.manipulation.press_slide.press_slide_retract`.

Modules: :mod:`~arsurf.batch.inputs` (files and items), :mod:`~arsurf.batch.options` (option
checks), :mod:`~arsurf.batch.pipelines` (the three pipelines and the work of one item),
:mod:`~arsurf.batch.table` (``results.csv``), :mod:`~arsurf.batch.executors` (local processes,
Dask) and :mod:`~arsurf.batch.runner` (:func:`run_batch`: settings, execution, summary).

Examples
--------
>>> # run_batch("process", ["scans/"], "out", options={"sigma": 1e-9, "export": [".stl"]}, workers=4)
>>> # run_batch("sweep", ["scan.gsf"], "out", options={"friction": [0.1, 0.3], "tip_radius": [10e-9, 20e-9],
>>> #           "effective_modulus": [1e9, 1e10]}, scheduler="tcp://10.0.0.5:8786")
>>> sorted(PIPELINES)
['process', 'replay', 'sweep']
>>> PIPELINES["sweep"].columns[4:7]
('friction', 'tip_radius_m', 'effective_modulus_Pa')
"""
from arsurf.batch.inputs import Item, collect_inputs
from arsurf.batch.pipelines import PIPELINES, Pipeline, make_items
from arsurf.batch.runner import BatchResult, run_batch
from arsurf.batch.table import read_results

__all__ = ["PIPELINES", "BatchResult", "Item", "Pipeline", "collect_inputs", "make_items", "read_results",
           "run_batch"]
