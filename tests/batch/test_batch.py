"""Batch runs (arsurf.batch, ``arsurf batch``): a folder of tiny synthetic scans with one corrupt file.

The same batch on local processes and on a Dask cluster gives the same table and files; a corrupt
file is one row with its reason, not the end of the batch; an interrupted or resumed batch runs
only what is not done; the sweep's contact answers agree with the contact law it sweeps; a worker
that dies is found and reported; bad arguments are one line and exit status 2.
"""
from __future__ import annotations

import csv
import json
import os
import sys
from pathlib import Path

import numpy as np
import pytest

from arsurf.batch import executors, table
from arsurf.batch import PIPELINES, collect_inputs, read_results, run_batch
from arsurf.cli import main
from arsurf.contact.maugis_dugdale import MaugisDugdale
from arsurf.errors import BatchError, MissingDependency
from arsurf.scan.io import load_scan, save_scan
from arsurf.scan.scan import Scan
from arsurf.spline.storage import load_surface
from tests.support.batch_inputs import _scan, _session, folder  # noqa: F401 - the fixture

PROCESS_COLUMNS = PIPELINES["process"].columns
#: dimensionless columns (counts, ratios, names); every other value column carries a unit suffix
UNITLESS = {"item", "status", "error", "format", "scan", "outputs", "output_files", "inpainted_pixels", "control_nu", "control_nv",
            "n_ticks", "contact_mismatches", "collision_failures", "friction", "friction_ratio", "slip_fraction"}


def _table_lines(out: Path) -> list[list[str]]:
    with open(out / "results.csv", newline="") as fh:
        return list(csv.reader(fh))


def _comparable(out: Path) -> dict:
    """The table without timings, and the fitted control nets."""
    rows = {k: {c: v for c, v in r.items() if not c.endswith("_time_s")} for k, r in read_results(out).items()}
    nets = {p.name: load_surface(p).control_points for p in sorted(out.glob("*.surface.npz"))}
    return {"rows": rows, "nets": nets}


def test_columns_carry_units():
    for p in PIPELINES.values():
        assert p.columns[:3] == ("item", "status", "error")
        for c in p.columns:
            assert c in UNITLESS or c.endswith(("_m", "_s", "_N", "_Pa", "_px", "_J_per_m2")), (p.name, c)


def test_a_corrupt_file_is_one_row_not_the_end_of_the_batch(folder, tmp_path):
    out = tmp_path / "out"
    r = run_batch("process", [folder], out, workers=0, progress=False, options={"export": ["gsf"]})
    rows = read_results(out, PROCESS_COLUMNS)
    assert sorted(rows) == ["broken.gsf", "s0.gsf", "s1.npz", "s2.gwy"]  # notes.md is not a scan
    assert (r.total, r.ok, r.failed) == (4, 3, 1)
    bad = rows["broken.gsf"]
    assert bad["status"] == "error" and bad["error"].startswith("CorruptScan: ") and "\n" not in bad["error"]
    assert r.errors == (("broken.gsf", bad["error"]),)
    for k, name in enumerate(("s0.gsf", "s1.npz", "s2.gwy")):
        row = rows[name]
        assert row["status"] == "ok" and row["error"] == ""
        assert row["outputs"].split(";") == [f"{name}.surface.npz", f"{name}.gsf"]
        # the interpolating fit passes through the levelled pixels: residual at rounding level
        assert float(row["max_residual_m"]) < 1e-6 * float(row["z_range_m"])
        assert (int(row["nx_px"]), int(row["ny_px"]), float(row["dx_m"])) == (18, 14, 5e-9)
        # Rq of the plane-levelled map: the residual of a least-squares plane, solved here
        z = _scan(k).heights
        yy, xx = np.indices(z.shape)
        a = np.column_stack([np.ones(z.size), xx.ravel(), yy.ravel()])
        levelled = z.ravel() - a @ np.linalg.lstsq(a, z.ravel(), rcond=None)[0]
        assert float(row["rms_roughness_m"]) == pytest.approx(np.sqrt(np.mean(levelled ** 2)), rel=1e-6)
        exported = load_scan(out / f"{name}.gsf")
        assert exported.shape == (14, 18)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["complete"] and (summary["ok"], summary["failed"]) == (3, 1)
    assert summary["errors"] == [{"item": "broken.gsf", "reason": bad["error"]}]
    assert summary["statistics"]["nx_px"] == {"min": 18.0, "median": 18.0, "max": 18.0, "count": 3}
    assert json.loads((out / "batch.json").read_text())["options"]["export"] == [".gsf"]


def test_local_processes_and_a_dask_cluster_give_the_same_outputs(folder, tmp_path):
    distributed = pytest.importorskip("distributed")
    grid = {"friction": [0.1, 0.4], "tip_radius": [10e-9, 20e-9], "effective_modulus": [2e9]}
    local = run_batch("process", [folder], tmp_path / "local", workers=2, progress=False)
    sweep_local = run_batch("sweep", [folder / "s0.gsf"], tmp_path / "sweep-local", workers=0, progress=False,
                            options=grid)
    with distributed.LocalCluster(processes=False, n_workers=1, threads_per_worker=2, dashboard_address=None) as cl:
        dask = run_batch("process", [folder], tmp_path / "dask", scheduler=cl.scheduler_address, progress=False)
        with distributed.Client(cl) as client:
            sweep_dask = run_batch("sweep", [folder / "s0.gsf"], tmp_path / "sweep-dask", scheduler=client,
                                   progress=False, options=grid)
    assert (local.ok, local.failed) == (dask.ok, dask.failed) == (3, 1)
    a, b = _comparable(tmp_path / "local"), _comparable(tmp_path / "dask")
    assert a["rows"] == b["rows"]
    assert a["nets"].keys() == b["nets"].keys() and len(a["nets"]) == 3
    for name in a["nets"]:
        np.testing.assert_array_equal(a["nets"][name], b["nets"][name])
    assert sweep_local.ok == sweep_dask.ok == 4
    assert _comparable(tmp_path / "sweep-local")["rows"] == _comparable(tmp_path / "sweep-dask")["rows"]


def test_resume_skips_the_finished_items(folder, tmp_path):
    out = tmp_path / "out"
    run_batch("process", [folder], out, workers=0, progress=False)
    before = {p.name: p.stat().st_mtime_ns for p in out.glob("*.surface.npz")}
    save_scan(_scan(3), folder / "s3.gsf")  # a scan arrives; the broken one is still broken
    with pytest.raises(BatchError, match="pass --resume"):
        run_batch("process", [folder], out, workers=0, progress=False)
    r = run_batch("process", [folder], out, workers=0, progress=False, resume=True)
    assert (r.total, r.skipped, r.ran, r.ok, r.failed) == (5, 3, 2, 4, 1)
    keys = [row[0] for row in _table_lines(out)[1:]]
    assert sorted(keys) == sorted(["s0.gsf", "s1.npz", "s2.gwy", "broken.gsf", "broken.gsf", "s3.gsf"])
    assert {p.name: p.stat().st_mtime_ns for p in out.glob("*.surface.npz") if p.name in before} == before
    assert (out / "s3.gsf.surface.npz").exists()
    with pytest.raises(BatchError, match=r"other settings \(options \['sigma'\]"):
        run_batch("process", [folder], out, workers=0, progress=False, resume=True, options={"sigma": 1e-9})


def test_an_interrupted_batch_resumes_where_it_stopped(folder, tmp_path, monkeypatch):
    out = tmp_path / "out"
    append = table.ResultTable.append
    written = []

    def interrupt_after_two(self, row):
        if len(written) == 2:
            raise KeyboardInterrupt
        append(self, row)
        written.append(row["item"])

    monkeypatch.setattr(table.ResultTable, "append", interrupt_after_two)
    with pytest.raises(KeyboardInterrupt):
        run_batch("process", [folder], out, workers=0, progress=False)
    monkeypatch.setattr(table.ResultTable, "append", append)
    summary = json.loads((out / "summary.json").read_text())
    assert not summary["complete"] and summary["not_run"] == 2
    # the process was killed in the middle of writing a third row: a torn line without its newline
    with open(out / "results.csv", "a") as fh:
        fh.write("s2.gwy,ok,,gs")
    r = run_batch("process", [folder], out, workers=0, progress=False, resume=True)
    # the items run in sorted order: broken.gsf (an error: run again) and s0.gsf were written
    assert written == ["broken.gsf", "s0.gsf"]
    assert (r.skipped, r.ran, r.ok, r.failed) == (1, 3, 3, 1)
    lines = _table_lines(out)
    assert all(len(line) == len(PROCESS_COLUMNS) for line in lines)
    assert [line[0] for line in lines[1:]] == ["broken.gsf", "s0.gsf", "broken.gsf", "s1.npz", "s2.gwy"]
    assert json.loads((out / "summary.json").read_text())["complete"]


def test_sweep_agrees_with_the_contact_law_on_a_flat_scan(tmp_path):
    flat = Scan(np.zeros((12, 12)), dx=10e-9, dy=10e-9, source="flat")
    save_scan(flat, tmp_path / "flat.npz")
    out = tmp_path / "sweep"
    grid = {"friction": [0.1, 0.3], "tip_radius": [10e-9, 30e-9], "effective_modulus": [1e9, 1e10]}
    r = run_batch("sweep", [tmp_path / "flat.npz"], out, workers=0, progress=False,
                  options={**grid, "depth": 1.5e-9, "slide": 15e-9, "steps": 60})
    assert (r.total, r.ok) == (8, 8)
    rows = [{k: (float(v) if k not in ("item", "status", "error", "scan", "output_files") else v) for k, v in row.items()}
            for row in read_results(out).values()]
    w = 0.1  # the demo preset's work of adhesion
    for row in rows:
        md = MaugisDugdale(row["tip_radius_m"], row["effective_modulus_Pa"], w)
        state = md.contact_state(depth=row["max_depth_m"])
        assert row["max_depth_m"] == pytest.approx(1.5e-9, rel=1e-6)
        assert row["peak_load_N"] == pytest.approx(float(state.load), rel=1e-6)
        assert row["contact_radius_m"] == pytest.approx(float(state.radius), rel=1e-6)
        # sliding on a plane the proxy slips on the edge of the cone: |F_t| = mu_k N, N = P + |P_c|
        assert row["friction_ratio"] == pytest.approx(row["friction"], rel=1e-9)
        assert 0.0 < row["slip_fraction"] <= 1.0
        # displacement-controlled retract samples the tensile branch: at most the pull-off force
        assert 0.5 * -md.pull_off_force() < row["pull_off_force_N"] <= -md.pull_off_force() * (1 + 1e-9)
        assert row["work_of_adhesion_J_per_m2"] == w
    by = {(row["friction"], row["tip_radius_m"], row["effective_modulus_Pa"]): row for row in rows}
    for mu in grid["friction"]:
        assert by[(mu, 10e-9, 1e10)]["peak_load_N"] > by[(mu, 10e-9, 1e9)]["peak_load_N"]
        assert by[(mu, 30e-9, 1e9)]["contact_radius_m"] > by[(mu, 10e-9, 1e9)]["contact_radius_m"]
        # the contact does not depend on friction; the friction force grows with it
        assert by[(0.3, 30e-9, 1e9)]["mean_friction_force_N"] > by[(0.1, 30e-9, 1e9)]["mean_friction_force_N"]
    assert by[(0.1, 10e-9, 1e9)]["peak_load_N"] == by[(0.3, 10e-9, 1e9)]["peak_load_N"]
    assert sorted(r["item"] for r in read_results(out).values())[0] == \
        "flat.npz;friction=0.1;tip_radius_m=1e-08;effective_modulus_Pa=1000000000.0"


def test_replay_pipeline_finds_each_sessions_scan(tmp_path, monkeypatch):
    d = tmp_path / "sessions"
    d.mkdir()
    save_scan(_scan(0), d / "scan.npz")
    monkeypatch.chdir(d)  # the sessions record the scan as the relative path "scan.npz"
    _session(d / "a.h5", "scan.npz", 6e-9)
    _session(d / "b.h5", "scan.npz", 10e-9)
    (d / "c.h5").write_bytes(b"\x89HDF\r\n\x1a\n" + b"\0" * 40)  # a damaged file
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "out"
    r = run_batch("replay", [d], out, workers=0, progress=False)
    rows = read_results(out, PIPELINES["replay"].columns)
    assert (r.ok, r.failed) == (2, 1) and rows["c.h5"]["error"].startswith("SessionError: ")
    a, b = rows["a.h5"], rows["b.h5"]
    assert a["scan"] == str(d / "scan.npz") and int(a["n_ticks"]) == 30
    assert 0 < float(a["max_depth_m"]) < float(b["max_depth_m"]) and 0 < float(a["peak_force_N"]) < float(b["peak_force_N"])
    assert (out / "a.h5" / "forces.csv").exists() and (out / "b.h5" / "replay.h5").exists()


# a worker that dies: module-level so the spawned workers import it by reference
def _die_on_three(x):
    if x == 3:
        os._exit(7)
    return x * x


def test_a_worker_that_dies_is_found_and_the_others_complete():
    results, crashes = {}, {}
    calls = [(x,) for x in range(7)]
    executors.execute_local(_die_on_three, calls, 2, results.__setitem__, crashes.__setitem__)
    assert results == {i: i * i for i in range(7) if i != 3}
    assert list(crashes) == [3] and "worker process died" in crashes[3]


def test_missing_dask_is_one_line(folder, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "distributed", None)
    with pytest.raises(MissingDependency, match=r"pip install 'arsurf\[dask\]'"):
        run_batch("process", [folder], tmp_path / "out", scheduler="tcp://127.0.0.1:8786", progress=False)
    assert not (tmp_path / "out").exists()


def test_inputs_globs_and_the_output_folder(folder, tmp_path):
    files, root, _ = collect_inputs([str(folder / "s*.*"), folder / "s0.gsf"])
    assert [f.name for f in files] == ["s0.gsf", "s1.npz", "s2.gwy"] and root == Path(os.path.abspath(folder))
    # an output folder inside the input folder: its tables and surfaces are not inputs
    out = folder / "out"
    run_batch("process", [folder], out, workers=0, progress=False)
    r = run_batch("process", [folder, str(folder / "**" / "*.npz")], out, workers=0, progress=False, resume=True)
    assert (r.total, r.skipped) == (4, 3)


def _exit_status(argv) -> int:
    try:
        return main(argv)
    except SystemExit as exc:  # argparse's own errors
        return exc.code


@pytest.mark.parametrize("argv, message", [
    (["sweep", "{f}/s0.gsf", "--workers", "2", "--scheduler", "tcp://h:1"], "not allowed with argument"),
    (["process", "{f}", "--workers", "-1"], "--workers: must be an integer >= 0"),
    (["sweep", "{f}/s0.gsf", "--friction", "0.1,x"], "--friction: must be comma-separated numbers"),
    (["sweep", "{f}/s0.gsf", "--tip-radius-nm", "10,0"], "--tip-radius-nm: every value must be finite and > 0"),
    (["sweep", "{f}/s0.gsf", "--steps", "1"], "option 'steps' must be an integer in [2, 100000]"),
    (["process", "{f}", "--export", "obj"], "--export: invalid choice"),
    (["process", "{f}/nothing*.gsf"], "no file matches the pattern"),
    (["process", "{f}/missing.gsf"], "does not exist"),
    (["process", "{f}", "--smoothing", "nan"], "--smoothing: must be a finite number >= 0"),
    (["shuffle", "{f}"], "invalid choice: 'shuffle'"),
    (["process", "{f}", "--scheduler", " "], "scheduler address is empty"),
])
def test_bad_arguments_are_one_line_and_exit_2(folder, tmp_path, capsys, argv, message):
    argv = ["batch", *(a.format(f=folder) for a in argv), "-o", str(tmp_path / "out"), "-q"]
    assert _exit_status(argv) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1, err
    assert not (tmp_path / "out" / "results.csv").exists()


def test_command_line_runs_and_resumes(folder, tmp_path, capsys):
    out = tmp_path / "out"
    args = ["batch", "process", str(folder), "-o", str(out), "--workers", "0", "--sigma-nm", "1", "-q"]
    assert main(args) == 1  # one item failed
    captured = capsys.readouterr()
    assert "4 items: 3 ok, 1 failed" in captured.out
    assert captured.err.strip().startswith("arsurf batch: failed: broken.gsf: CorruptScan: ")
    assert main(args) == 2 and "pass --resume" in capsys.readouterr().err
    (folder / "broken.gsf").unlink()
    assert main([*args, "--resume"]) == 0
    assert "3 items: 3 ok, 0 failed, 0 not run; 0 run now, 3 done before" in capsys.readouterr().out
    settings = json.loads((out / "batch.json").read_text())
    assert settings["options"]["sigma_m"] == 1e-9 and settings["version"] == 3


def test_a_batch_started_by_an_older_arsurf_resumes(folder, tmp_path):
    """batch.json version 1 named the options as the API does (``sigma``, no unit): still resumable."""
    out = tmp_path / "out"
    (folder / "broken.gsf").unlink()
    run_batch("process", [folder], out, options={"sigma": 1e-9}, workers=0, progress=False)
    settings = json.loads((out / "batch.json").read_text())
    old = {**settings, "version": 1, "options": {k.removesuffix("_m"): v for k, v in settings["options"].items()}}
    assert "sigma" in old["options"] and "dx" in old["options"]
    (out / "batch.json").write_text(json.dumps(old))
    r = run_batch("process", [folder], out, options={"sigma": 1e-9}, workers=0, progress=False, resume=True)
    assert (r.skipped, r.ran) == (3, 0)
    assert json.loads((out / "batch.json").read_text()) == settings  # rewritten in the current form
    (out / "batch.json").write_text(json.dumps(old))
    with pytest.raises(BatchError, match=r"options \['sigma'\] differ"):
        run_batch("process", [folder], out, options={"sigma": 2e-9}, workers=0, progress=False, resume=True)


def test_an_unreachable_scheduler_is_one_line_and_writes_nothing(folder, tmp_path):
    pytest.importorskip("distributed")
    with pytest.raises(BatchError, match=r"cannot reach the Dask scheduler at 'tcp://127.0.0.1:9' within 1 s"):
        run_batch("process", [folder], tmp_path / "out", scheduler="tcp://127.0.0.1:9", connect_timeout=1.0,
                  progress=False)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("old, new", [("seed000", "mwcnt-push"), ("seed001", "thesis-haptics"),
                                      ("seed002", "spline-ar"), ("seed003", "tipless-rolling")])
def test_a_sweep_accepts_a_presets_old_name_and_records_the_new_one(old, new):
    from arsurf.assembly import PRESETS
    from arsurf.batch.pipelines import _check_sweep

    checked = _check_sweep({"preset": old})
    assert checked["preset"] == new and checked["tip_radius"] == [PRESETS[new].tip_radius]


def test_a_folder_is_read_by_content_and_what_is_left_is_listed(tmp_path, capsys):
    """#30: a NanoScope file named ``.di`` (which ``arsurf info`` reads) is taken from a folder, as a
    renamed .gsf is; a file that is no scan is named in the output and the summary, not dropped silently."""
    from tests.support.real_scans import real_scan_path

    d = tmp_path / "scans"
    d.mkdir()
    (d / "tip.di").write_bytes(real_scan_path("Veeco_20160622.003").read_bytes())
    save_scan(_scan(0), d / "renamed.gsf")
    (d / "renamed.gsf").rename(d / "renamed.dat2")
    (d / "notes.md").write_text("not a scan\n")
    files, root, skipped = collect_inputs([d])
    assert [f.name for f in files] == ["renamed.dat2", "tip.di"] and [p.name for p in skipped] == ["notes.md"]
    assert load_scan(files[1]).metadata["format"] == "nanoscope"
    out = tmp_path / "out"
    assert main(["batch", "process", str(d), "-o", str(out), "--workers", "0", "-q"]) == 0
    printed = capsys.readouterr().out
    assert "2 items: 2 ok" in printed and "skipped: 1 file, not inputs: notes.md" in printed
    assert json.loads((out / "summary.json").read_text())["not_inputs"] == ["notes.md"]


def test_a_folder_without_scans_is_one_short_line(tmp_path, capsys):
    """#30: not every extension (NanoScope alone has a thousand): one line saying how to list the formats."""
    d = tmp_path / "empty"
    d.mkdir()
    (d / "notes.md").write_text("not a scan\n")
    assert _exit_status(["batch", "process", str(d), "-o", str(tmp_path / "out"), "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and len(err) < 250 and "arsurf formats" in err, err
    assert main(["formats"]) == 0
    listing = capsys.readouterr().out
    assert ".000-.999" in listing and len(listing.splitlines()) == len(load_scan.__globals__["FORMATS"])
