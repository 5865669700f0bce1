r"""A scan - push - scan experiment on the virtual AFM, whose truth is known: for the benchmark and
the tests of ``arsurf verify``.

:func:`run_experiment` images a rough substrate with tubes (:mod:`arsurf.instrument.imaging`:
tip dilation, feedback lag, photodiode noise, a thermal drift new in every scan), records a
session whose model pushes one tube along a straight tip path (the model's
:class:`~arsurf.manipulation.scene.TubeScene`, possibly *wrong*: another middle band, so it
translates a tube that truly turns; or another friction, which changes the force and not the
motion), moves the real tubes with the true physics along the same path (carried into the
sample's frame by the scan before's true drift map; the tip's apex 0.5 nm below the
substrate's mean plane, so the model dents it), leaves a shallow dent where the tip pressed,
scans again, and returns the files and the truth: the map from the scan after's pixels
to the scan before's, and the tubes' true final poses in the scan before's frame (the frame of
the session).

:func:`session_sample` is the other direction: the sample a recorded session left as its model
sees it - the substrate it fitted, the dent the model made (the model re-run over the recorded
ticks, :math:`z_{now} - z_{rest}` of the live surface on the scan's pixels) and the tubes at
their last recorded poses - for the virtual AFM to image.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from arsurf.errors import VerifyError

__all__ = ["Case", "Experiment", "run_experiment", "true_map_error", "session_sample"]


@dataclass(frozen=True)
class Case:
    """One row of the table.

    Parameters
    ----------
    seed : int
    tip_radius : float, m
    drift_rate : float, m/s
        Standard deviation of each drift velocity component (x, y), new every scan.
    noise : float, m
        Height noise per pixel.
    push_at : float
        Contact arc-length along the pushed tube, as a fraction of its length.
    push : float, m
        How far the tip travels past the first contact.
    wrong : str
        ``""`` (the model is the truth), ``"pivot"`` (middle band 0.45: the model translates
        what turns) or ``"friction"`` (5 x the substrate resistance: another force, the same motion).
    """

    seed: int = 0
    tip_radius: float = 10e-9
    drift_rate: float = 0.05e-9
    noise: float = 0.2e-9
    push_at: float = 0.85
    push: float = 40e-9
    wrong: str = ""


@dataclass
class Experiment:
    """Files and truth of one :func:`run_experiment`."""

    case: Case
    before: Path
    after: Path
    session: Path
    true_affine: np.ndarray  # (2, 3): after pixel -> before pixel
    true_poses: np.ndarray  # (k, 3): x, y (m), angle (rad), the scan before's frame
    model_poses: np.ndarray  # (k, 3): the session's prediction
    pushed: int


_PIXELS, _PIXEL = 96, 8e-9
_TUBES = ((300e-9, 14e-9, 300e-9, 330e-9, 0.35), (220e-9, 12e-9, 560e-9, 520e-9, -1.0))


def _pixel_map(truth):
    m = truth.pixel_to_sample
    return m[:, :2], m[:, 2]


def run_experiment(case: Case, out_dir) -> Experiment:
    """Scan, push (the model and the truth), scan again (module docstring)."""
    from arsurf.assembly import LEVER, session_metadata
    from arsurf.instrument.imaging import Sample, ScanSettings, ScanTruth, ThermalDrift, TipShape
    from arsurf.instrument.instrument import VirtualAFM
    from arsurf.manipulation.nanotube import Nanotube
    from arsurf.manipulation.scene import FRICTION_PER_LENGTH, TubeScene
    from arsurf.sessions.writer import SessionWriter
    from arsurf.scan.io import save_scan
    from arsurf.scan.synthetic import rough

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng([case.seed, 11])
    n_sub = int(1.25 * _PIXELS * _PIXEL / 4e-9)
    substrate = rough((n_sub, n_sub), 4e-9, rms=0.4e-9, correlation_length=16e-9, seed=case.seed)
    jitter = rng.uniform(-20e-9, 20e-9, size=(len(_TUBES), 2))
    true = [Nanotube(L, d, x=x + 60e-9 + j[0], y=y + 60e-9 + j[1], angle=a + rng.uniform(-0.2, 0.2))
            for (L, d, x, y, a), j in zip(_TUBES, jitter)]
    settings = ScanSettings((_PIXELS, _PIXELS), (_PIXELS * _PIXEL,) * 2, origin=(60e-9, 60e-9), line_speed=4e-6,
                            feedback_bandwidth=2e3)
    from arsurf.instrument.instrument import PhotodiodeNoise

    # the photodiode noise that gives case.noise of height per pixel (sigma |S_n| / sqrt(n))
    samples = settings.pixel_time * 10e3
    sigma_signal = case.noise / 1117e-9 * math.sqrt(max(1.0, samples))
    from arsurf.instrument.instrument import expected_range

    noise = PhotodiodeNoise(peak_to_peak=max(sigma_signal, 1e-9) * expected_range(50_000))
    afm = VirtualAFM(substrate, probe_height=1e-6, tip_xy=(1e-7, 1e-7), noise=noise, keep_history=False,
                     sample=Sample(substrate, objects=true), imaging_tip=TipShape(case.tip_radius),
                     drift=ThermalDrift(rate_xy=case.drift_rate, rate_z=0.01e-9, seed=case.seed, offset=(
                         rng.uniform(-10e-9, 10e-9), rng.uniform(-10e-9, 10e-9), 0.0)),
                     scan_settings=settings, seed=case.seed)
    with afm:
        before = afm.scan_image()
        tb = ScanTruth.from_metadata(before.metadata["virtual_afm"])
        before_path = save_scan(before, out / "before.npz")
        mb, ob = _pixel_map(tb)
        dx, dy = before.dx, before.dy

        def to_sample(p):  # session frame (metres, x = ix dx) -> sample frame
            return mb @ np.array([p[0] / dx, p[1] / dy]) + ob

        def to_session(q):  # sample -> session frame (metres)
            f = np.linalg.solve(mb, np.asarray(q) - ob)
            return np.array([f[0] * dx, f[1] * dy])

        def pose_to_session(t):
            c = to_session((t.x, t.y))
            tip = to_session((t.x + math.cos(t.angle) * 1e-7, t.y + math.sin(t.angle) * 1e-7))
            return np.array([c[0], c[1], math.atan2(tip[1] - c[1], tip[0] - c[0])])

        start_poses = np.array([pose_to_session(t) for t in true])
        model_tubes = [Nanotube(t.length, t.diameter, x=p[0], y=p[1], angle=p[2]) for t, p in zip(true, start_poses)]
        k = 0
        band = 0.45 if case.wrong == "pivot" else 0.01
        friction = 5 * FRICTION_PER_LENGTH if case.wrong == "friction" else FRICTION_PER_LENGTH
        model = TubeScene(model_tubes, middle_band=band, friction_per_length=friction, substrate_margin=2 * _PIXEL)
        truth = TubeScene(true)
        # the tip path (session frame): beside the contact point, across the axis
        t0 = model_tubes[k]
        u = t0.direction
        nrm = np.array([-u[1], u[0]])
        c = t0.point_at(case.push_at * t0.length)[:2]
        reach = case.tip_radius + t0.radius
        start = c - (reach + 15e-9) * nrm
        travel = 15e-9 + case.push
        steps = max(2, int(travel / 0.5e-9))
        z = case.tip_radius - 0.5e-9  # the apex 0.5 nm under the substrate's mean plane: the model dents it
        path = np.array([[*(start + s * travel * nrm), z] for s in np.linspace(0.0, 1.0, steps)])
        meta = session_metadata(scan=before_path, tip_radius=case.tip_radius,
                                contact={"effective_modulus": 10e9, "work_of_adhesion": 0.1, "dugdale_stress": None},
                                cantilever=dict(LEVER), friction=0.2, level="plane", sigma=0.0,
                                tubes=model.to_metadata(), virtual_experiment={"wrong_model": case.wrong})
        prev_m, prev_t = None, None
        with SessionWriter(out / "session.h5", meta) as w:
            for i, p in enumerate(path):
                model.step(prev_m, p, case.tip_radius)
                q = np.array([*to_sample(p[:2]), z])
                truth.step(prev_t, q, case.tip_radius)
                prev_m, prev_t = p, q
                w.append(t=i * 1e-3, probe_position=p, tube_poses=model.poses)
        if not model.step(None, path[-1], case.tip_radius).touched.any() and np.allclose(model.poses, start_poses):
            raise VerifyError("the virtual push missed the tube")
        # the dent the tip left where it pressed at the end of the push (0.3 nm, Gaussian of R)
        yy, xx = np.mgrid[0:substrate.shape[0], 0:substrate.shape[1]]
        end = to_sample(path[-1, :2])
        dent = -0.3e-9 * np.exp(-((xx * substrate.dx - end[0]) ** 2 + (yy * substrate.dy - end[1]) ** 2)
                                / (2 * case.tip_radius**2))
        afm._imaging.sample = Sample(substrate, dent=dent, objects=truth.tubes)
        afm.time += 120.0  # two minutes between the frames (the manipulation)
        after = afm.scan_image()
        ta = ScanTruth.from_metadata(after.metadata["virtual_afm"])
        after_path = save_scan(after, out / "after.npz")
    ma, oa = _pixel_map(ta)
    lin = np.linalg.solve(mb, ma)
    off = np.linalg.solve(mb, oa - ob)
    true_affine = np.c_[lin, off]
    true_poses = np.array([pose_to_session(t) for t in truth.tubes])
    return Experiment(case, before_path, after_path, out / "session.h5", true_affine, true_poses,
                      model.poses.copy(), k)


def true_map_error(affine: np.ndarray, true_affine: np.ndarray, shape) -> float:
    """Largest distance (pixels) between two after -> before maps over the frame's corners (an
    affine error is largest at a corner)."""
    ny, nx = shape
    c = np.array([[0, 0, 1], [nx - 1, 0, 1], [0, ny - 1, 1], [nx - 1, ny - 1, 1]], dtype=np.float64).T
    return float(np.hypot(*((affine - true_affine) @ c)).max())


def session_sample(session_path, scan_path=None):
    """The sample a session left, as its model has it (module docstring): an
    :class:`~arsurf.instrument.imaging.Sample` on the session's processed scan (the substrate when
    it has tubes), with the model's dent and the tubes at their last recorded poses."""
    from arsurf.assembly import build_model
    from arsurf.instrument.imaging import Sample
    from arsurf.sessions.reader import load_session
    from arsurf.spline.surface import BSplineSurface

    session = load_session(session_path)
    setup = build_model(session.metadata, scan_path)
    model, scan = setup.model, setup.scan
    model.reset()
    pos = session.ticks["probe_position"]
    for k in range(session.n_ticks):  # the dent as the model made it (no signals: the simulated force)
        model.tick(pos[k], None)
    ny, nx = scan.shape
    yy, xx = np.mgrid[0:ny, 0:nx]
    surface = model.surface
    rest = BSplineSurface.construct_fast(np.array(surface.rest_control_points), np.array(surface.knots_u),
                                         np.array(surface.knots_v))
    dent = surface.evaluate(xx * scan.dx, yy * scan.dy)[..., 2] - rest.evaluate(xx * scan.dx, yy * scan.dy)[..., 2]
    objects = ()
    if setup.scene is not None:
        poses = session.ticks.get("tube_poses")
        last = poses[-1] if poses is not None and len(poses) else setup.scene.poses
        objects = tuple(t.with_pose(*map(float, p)) for t, p in zip(setup.scene.initial, last))
    return Sample(scan.with_heights(np.nan_to_num(scan.heights, nan=float(np.nanmedian(scan.heights)))),
                  dent=dent, objects=objects)
