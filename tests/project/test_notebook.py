"""examples/quickstart.ipynb runs top to bottom in a fresh Jupyter kernel (nbclient); any cell error
fails the test. Its rich outputs are the objects' own displays (HTML cards, thumbnails, the 3D view)."""
from __future__ import annotations

import base64
import io
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
NOTEBOOK = ROOT / "examples" / "quickstart.ipynb"

nbformat = pytest.importorskip("nbformat", reason="the notebook test needs nbformat (pip install 'arsurf[test]')")
nbclient = pytest.importorskip("nbclient", reason="the notebook test needs nbclient (pip install 'arsurf[test]')")
pytest.importorskip("ipykernel", reason="the notebook test needs a Python kernel: pip install 'arsurf[test]'")


def test_the_committed_notebook_has_no_outputs():
    """Outputs are made by running it (here, in CI), not stored: the diff of a change stays readable."""
    nb = nbformat.read(NOTEBOOK, as_version=4)
    nbformat.validate(nb)
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert len(code) >= 8
    assert all(not c.outputs and c.execution_count is None for c in code)


@pytest.fixture(scope="module")
def executed(tmp_path_factory):
    from arsurf_viewer.backend import probe

    result = probe()
    if not result.ok:  # the notebook draws the 3D view; CI has an OpenGL context
        pytest.skip(f"no OpenGL context can be made here, the notebook's 3D view cannot render: {result.detail}")
    nb = nbformat.read(NOTEBOOK, as_version=4)
    cwd = tmp_path_factory.mktemp("notebook")
    nbclient.NotebookClient(nb, timeout=600, kernel_name="python3",
                            resources={"metadata": {"path": str(cwd)}}).execute()  # CellExecutionError on any error
    return nb


def _outputs(nb):
    return [[o for o in c.outputs] for c in nb.cells if c.cell_type == "code"]


def _data(cell_outputs, mime):
    return [o["data"][mime] for o in cell_outputs if o.get("output_type") == "execute_result" and mime in o["data"]]


@pytest.mark.slow  # builds the module fixture
def test_every_cell_runs_and_no_cell_writes_an_error(executed):
    for outs in _outputs(executed):
        assert not [o for o in outs if o.get("output_type") == "error"]
        assert not [o for o in outs if o.get("name") == "stderr" and "Traceback" in o.get("text", "")]


def test_the_objects_show_themselves_with_units(executed):
    outs = _outputs(executed)
    html = [h for cell in outs for h in _data(cell, "text/html")]
    scan, surface, dented, session, replay = html
    assert "Scan" in scan and "256 x 256 px" in scan and "4 nm x 4 nm" in scan and "z range" in scan
    assert "BSplineSurface" in surface and "258 x 258" in surface and ">no<" in surface
    assert "control points moved" in dented
    assert "Session" in session and "400 over 399 ms at 1 kHz" in session and "checksums verified" in session
    assert "Replay" in replay and "contact-state mismatches" in replay
    text = "".join(o.get("text", "") for cell in outs for o in cell if o.get("output_type") == "stream")
    assert "t_s,F_recorded_x_N," in text and "decoupled" in text


def test_the_3d_view_is_a_picture_in_the_notebook(executed):
    from PIL import Image

    pictures = [p for cell in _outputs(executed) for p in _data(cell, "image/png") if not _data(cell, "text/html")]
    assert len(pictures) == 1
    image = Image.open(io.BytesIO(base64.b64decode(pictures[0])))
    assert image.size == (720, 480)
