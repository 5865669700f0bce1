"""One unit convention in every file arsurf writes (arsurf.units): JSON keys and CSV columns end with
their unit, HDF5 datasets carry a ``units`` attribute. Checked on every JSON, CSV and HDF5 file that
any command writes, on small inputs: the demo and the material demo (each with its replay), the three
batch pipelines, ``arsurf verify``, ``arsurf convert`` (a ``.npy`` and its sidecar) and ``export``,
and the JSON that ``arsurf info --json`` (with ``--material``), ``fit --json`` and
``devices --json`` print (kept as files under ``stdout/``)."""
from __future__ import annotations

import contextlib
import csv
import io
import json
import math
from pathlib import Path

import numpy as np

import h5py
import pytest

from arsurf.batch import run_batch
from arsurf.data import bundled_scan
from arsurf.demo import run_demo
from arsurf.replay.replay import REPLAY_FIELDS
from arsurf.sessions.schema import TICK_FIELDS, SAFETY_FLAGS, TUBE_POSES
from arsurf.units import SCALED_SUFFIXES, SUFFIXES, summary_json, undeclared, unit_of, with_unit

ROOT = Path(__file__).resolve().parents[2]
FIELD_UNITS = {f.name: f.unit for f in (*TICK_FIELDS, *REPLAY_FIELDS, TUBE_POSES, SAFETY_FLAGS)}


def test_names_declare_their_units():
    assert unit_of("t_s") == "s" and unit_of("F_simulated_x_N") == "N" and unit_of("rate_Hz") == "Hz"
    assert unit_of("effective_modulus_Pa") == "Pa" and unit_of("friction_per_length_N_per_m") == "N/m"
    assert unit_of("items_per_s") == "1/s" and unit_of("passivity_damping_N_s_per_m") == "N s/m"
    for name in ("n_ticks", "ticks_in_contact", "inpainted_pixels", "friction_ratio", "slip_fraction", "friction",
                 "pushed_tube_index", "high_frequency_over_normal", "contact_mismatches", "maugis_lambda"):
        assert unit_of(name) == "1", name
    for name in ("duration", "peak_force", "rate_hz", "E*", "E*_GPa", "pull_off", "tick_compute_median_usec"):
        assert unit_of(name) is None, name  # no unit, or a spelling that is none
    for name, unit in (("max_depth_nm", "nm"), ("rotation_deg", "deg"), ("tick_compute_median_us", "us"),
                       ("effective_modulus_GPa", "GPa"), ("work_of_adhesion_mJ_per_m2", "mJ/m^2"),
                       ("masked_modulus_percent", "%"), ("pull_off_force_nN", "nN"), ("fit_time_ms", "ms")):
        assert unit_of(name) == unit, name  # a scaled unit, for people (arsurf info --json)


@pytest.mark.parametrize("unit", sorted(set(SUFFIXES.values())))
def test_with_unit_and_unit_of_agree(unit):
    assert unit_of(with_unit("quantity", unit)) == unit


@pytest.mark.parametrize("suffix", sorted(SCALED_SUFFIXES))
def test_a_scaled_suffix_is_read_as_its_unit_and_never_written_by_with_unit(suffix):
    assert unit_of(f"quantity_{suffix}") == SCALED_SUFFIXES[suffix]
    with pytest.raises(ValueError, match="has no name suffix"):
        with_unit("quantity", SCALED_SUFFIXES[suffix])  # the files of record stay in SI


def test_with_unit_refuses_a_unit_without_a_suffix():
    with pytest.raises(ValueError, match="unit 'furlong' has no name suffix"):
        with_unit("depth", "furlong")


def test_undeclared_follows_lists_statistics_and_nesting():
    doc = {"statistics": {"z_range_m": {"min": 1e-9, "max": 2e-9, "count": 3}, "peak": {"min": 1.0}},
           "tube": {"displacement_m": [1e-9, None], "rotation": [0.1]}, "errors": [{"item": "a", "reason": "b"}],
           "complete": True, "elapsed_s": None, "channel": None, "width": 3}
    assert sorted(undeclared(doc)) == ["statistics/peak/min", "tube/rotation[0]", "width"]


def test_summary_json_is_strict_json():
    text = summary_json({"settle_time_s": math.nan, "peak_N": [1.0, math.inf], "n": 2})
    assert json.loads(text, parse_constant=pytest.fail) == {"settle_time_s": None, "peak_N": [1.0, None], "n": 2}


# ---------------------------------------------------------------------------------------------
# every file the demo, the replay and a batch write


def _stdout_json(argv: list[str], path: Path) -> None:
    """Run ``arsurf ARGV`` in this process and keep the JSON it prints as ``path``."""
    from arsurf.cli import main

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert main(argv) == 0, argv
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(buf.getvalue(), encoding="utf-8")


@pytest.fixture(scope="module")
def outputs(tmp_path_factory):
    from arsurf.cli import main
    from arsurf.contact.material_conversion import MaterialConversion
    from arsurf.demo import run_material_demo
    from arsurf.verify.virtual import Case, run_experiment

    root = tmp_path_factory.mktemp("outputs")
    run_demo(root / "demo", seconds=3.0, images=False, progress=lambda line: None)  # session.h5, replay/, summary.json
    scans = [ROOT / "scans" / "sinusoid.npz", ROOT / "scans" / "grating_20nm.npz"]
    run_batch("process", scans, root / "process", options={"sigma": 1e-9, "export": [".gsf", ".stl"]}, workers=0,
              progress=False)
    run_batch("sweep", scans[:1], root / "sweep", options={"friction": [0.1, 0.3], "steps": 8}, workers=0,
              progress=False)
    run_batch("replay", [root / "demo" / "session.h5"], root / "replays", options={"scan": str(bundled_scan())},
              workers=0, progress=False)
    # the material demo on a small QNM-like map: soft and stiff halves, a sticky disc
    y, x = np.mgrid[0:80, 0:80] * 1e-9
    qnm = root / "qnm.npz"
    np.savez(qnm, Height=0.05e-9 * np.sin(x / 7e-9), DMTModulus=np.where(x < 40e-9, 0.3e9, 8e9),
             Adhesion=np.where(np.hypot(x - 20e-9, y - 55e-9) < 10e-9, 12e-9, 3e-9),
             arsurf_meta=np.array(json.dumps({"dx": 1e-9, "dy": 1e-9,
                                              "units": {"Height": "m", "DMTModulus": "Pa", "Adhesion": "N"}})))
    run_material_demo(root / "material", qnm, MaterialConversion(5e-9), images=False,
                      channels={"modulus": "DMTModulus", "adhesion": "Adhesion", "deformation": None,
                                "dissipation": None}, units={"modulus": "Pa", "adhesion": "N"})
    # arsurf verify on a virtual push (a session, the scan after it)
    e = run_experiment(Case(seed=3, tip_radius=8e-9, drift_rate=0.05e-9, noise=0.1e-9, push_at=0.85, push=40e-9),
                       tmp_path_factory.mktemp("experiment"))
    for folder in ("convert", "fit", "export"):
        (root / folder).mkdir()
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["verify", str(e.session), str(e.after), "--out", str(root / "verify")]) == 0
        assert main(["convert", str(scans[0]), "-o", str(root / "convert" / "sinusoid.npy")]) == 0
        assert main(["fit", str(scans[0]), "-o", str(root / "fit" / "sinusoid.npz")]) == 0
        assert main(["export", str(root / "fit" / "sinusoid.npz"), "-o", str(root / "export" / "sinusoid.gsf")]) == 0
    _stdout_json(["info", str(scans[0]), "--json"], root / "stdout" / "info.json")
    _stdout_json(["info", str(qnm), "--json", "--material", "--tip-radius-nm", "5"], root / "stdout" / "info_material.json")
    _stdout_json(["fit", str(scans[1]), "-o", str(root / "fit" / "grating.npz"), "--json"], root / "stdout" / "fit.json")
    _stdout_json(["devices", "--json"], root / "stdout" / "devices.json")
    _stdout_json(["info", str(root / "fit" / "sinusoid.npz"), "--json"], root / "stdout" / "info_surface.json")
    _stdout_json(["formats", "--json"], root / "stdout" / "formats.json")
    return root


def _files(root: Path, suffix: str) -> dict[str, Path]:
    return {p.relative_to(root).as_posix(): p for p in sorted(root.rglob(f"*{suffix}"))}


@pytest.mark.slow
def test_the_outputs_hold_every_kind_of_file(outputs):
    found = {*_files(outputs, ".json"), *_files(outputs, ".csv"), *_files(outputs, ".h5")}
    assert {"demo/summary.json", "demo/session.h5", "demo/replay/summary.json", "demo/replay/forces.csv",
            "demo/replay/replay.h5", "process/summary.json", "process/batch.json", "process/results.csv",
            "sweep/summary.json", "sweep/batch.json", "sweep/results.csv", "replays/results.csv",
            "replays/session.h5/forces.csv", "replays/session.h5/replay.h5", "replays/session.h5/summary.json",
            "replays/summary.json", "material/summary.json", "material/replay/forces.csv", "stdout/info.json",
            "stdout/info_material.json", "stdout/fit.json", "stdout/devices.json"} <= found
    assert any(name.startswith("verify/") for name in found), sorted(found)


@pytest.mark.slow
def test_every_json_is_strict_and_names_the_unit_of_every_number(outputs):
    files = _files(outputs, ".json")
    assert len(files) >= 14
    for name, path in files.items():
        doc = json.loads(path.read_text(encoding="utf-8"), parse_constant=lambda c: pytest.fail(f"{name}: {c}"))
        if name.endswith(".npy.json"):  # a scan's sidecar: its "metadata" is the source file's own, carried verbatim
            assert "dx_m" in doc and "dy_m" in doc, name
            doc = {k: v for k, v in doc.items() if k != "metadata"}
        assert undeclared(doc) == [], f"{name}: numbers whose key gives no unit"


def _number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


@pytest.mark.slow
def test_every_csv_column_of_numbers_names_its_unit(outputs):
    files = _files(outputs, ".csv")
    assert len(files) >= 5
    for name, path in files.items():
        with open(path, newline="", encoding="utf-8") as fh:
            header, *rows = list(csv.reader(fh))
        assert rows, name
        numeric = [c for k, c in enumerate(header) if any(_number(r[k]) for r in rows if len(r) == len(header))]
        assert numeric, name
        assert [c for c in numeric if unit_of(c) is None] == [], f"{name}: columns of numbers without a unit"
    with open(files["demo/replay/forces.csv"], encoding="utf-8") as fh:
        assert fh.readline().startswith("t_s,F_recorded_x_N,")


@pytest.mark.slow
def test_every_hdf5_dataset_carries_its_unit(outputs):
    files = _files(outputs, ".h5")
    files = {k: v for k, v in files.items() if v.is_file()}
    assert {"demo/session.h5", "demo/replay/replay.h5", "replays/session.h5/replay.h5", "material/session.h5",
            "material/replay/replay.h5"} <= set(files)
    for name, path in files.items():
        with h5py.File(path, "r") as f:
            assert f.attrs["units"] == "SI"
            datasets = {}
            f.visititems(lambda key, obj: datasets.__setitem__(key, obj) if isinstance(obj, h5py.Dataset) else None)
            assert len(datasets) >= 20, name
            for key, ds in datasets.items():
                unit = ds.attrs.get("units")
                assert unit == FIELD_UNITS[key.rsplit("/", 1)[-1]], f"{name}:/{key} has units {unit!r}"
                parts = unit.split(",")
                assert len(parts) == 1 or len(parts) == ds.shape[-1], f"{name}:/{key}: one unit per column"
            if name.startswith("demo/"):
                assert datasets["ticks/tube_poses"].attrs["units"] == "m,m,rad"
