"""The demos: the whole system on a scan, headless, scripted (no hand needed).

* :mod:`~arsurf.demo.nanotubes` - ``arsurf demo``: engage, a haptic session pushing a nanotube of
  the bundled scan, its replay, figures and views (:func:`run_demo`);
* :mod:`~arsurf.demo.material` - ``arsurf demo --material FILE``: pressing a QNM file's soft,
  stiff and sticky spots (:func:`run_material_demo`);
* :mod:`~arsurf.demo.scripted` - what both share (preset, recorded tick, snapshot, viewer);
* :mod:`~arsurf.demo.command` - the ``arsurf demo`` command (:func:`register`).
"""
from arsurf.demo.command import register
from arsurf.demo.material import pick_spots, press_measures, run_material_demo
from arsurf.demo.nanotubes import engage_at, hand_trajectory, plan_end_push, run_demo

__all__ = ["run_demo", "run_material_demo", "pick_spots", "press_measures", "engage_at", "hand_trajectory",
           "plan_end_push", "register"]
