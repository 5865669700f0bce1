"""The Sphinx site in docs/ builds with warnings as errors (numpydoc docstrings, the API reference, the
gallery of examples/plot_*.py run), and documents every public name of ``arsurf``."""
from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

for module in ("sphinx", "numpydoc", "sphinx_gallery"):
    pytest.importorskip(module, reason=f"the docs build needs {module}: pip install 'arsurf[docs]'")


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    out = tmp_path_factory.mktemp("docs")
    cmd = [sys.executable, "-m", "sphinx", "-W", "--keep-going", "-b", "html", "-q", "-d", str(out / "doctrees"),
           str(ROOT / "docs"), str(out / "html")]
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=900,
                          env={**os.environ, "MPLBACKEND": "Agg"})
    assert proc.returncode == 0, f"sphinx -W failed:\n{proc.stdout[-4000:]}\n{proc.stderr[-6000:]}"
    return out / "html"


@pytest.mark.slow  # builds the module fixture
def test_the_site_has_its_pages(site):
    for page in ("index.html", "pipeline.html", "equations.html", "units.html", "notebook.html", "api/index.html",
                 "auto_examples/index.html", "auto_examples/plot_contact_mechanics.html", "install.html", "cli.html",
                 "formats.html", "figures.html", "sessions.html", "devices.html", "instruments.html",
                 "bridge-protocol.html", "feel.html", "benchmarks.html", "references.html"):
        assert (site / page).is_file(), page
    equations = (site / "equations.html").read_text(encoding="utf-8")
    for source in ("Maugis 1992", "Johnson &amp; Greenwood 1997", "[MWCNT] Eq. 9", "Hannaford &amp; Ryu 2002",
                   "[Bolopion] Table II", "[Alabdulmuhsin] Eq. 31-34"):
        assert source in equations, source


def test_every_public_name_is_in_the_api_reference(site):
    import arsurf

    ids = set()
    for page in (site / "api").glob("*.html"):
        ids |= set(re.findall(r'id="(arsurf\.[A-Za-z_0-9]+)"', page.read_text(encoding="utf-8")))
    missing = sorted(f"arsurf.{n}" for n in arsurf.__all__ if n not in ("synthetic", "meshes")
                     and f"arsurf.{n}" not in ids)
    assert not missing, f"public names without an API entry (add them to docs/api/*.rst): {missing}"


def test_the_gallery_ran_its_examples(site):
    page = (site / "auto_examples" / "plot_scan_to_surface.html").read_text(encoding="utf-8")
    assert "arsurf-repr" in page and "BSplineSurface" in page  # the surface's own HTML card, captured
    assert "largest |spline - pixel| on this profile" in page
    images = sorted(p.name for p in (site / "_images").glob("sphx_glr_plot_*_001.png"))
    assert len(images) == len(list((ROOT / "examples").glob("plot_*.py"))) >= 3


def test_the_session_schema_page_lists_every_tick_field(site):
    """docs/sessions.rst's per-tick table is generated from the code at every build (docs/_ext/arsurf_schema.py):
    every dataset a session may hold is on the page, with its unit."""
    from arsurf.sessions import schema

    page = (site / "sessions.html").read_text(encoding="utf-8")
    table = page.split("Per-tick datasets", 1)[1]
    fields = (*schema.TICK_FIELDS, schema.SAFETY_FLAGS, schema.TUBE_POSES, schema.INSTRUMENT_POSITION)
    names = re.findall(r'<tr class="row-\w+"><td><p><code class="[^"]*"><span class="pre">([a-z_]+)</span>', table)
    assert names[:len(fields)] == [f.name for f in fields]
    for name in ("tip_position", "energy", "passivity_damping", "instrument_position"):  # missing from the old README
        assert name in names, name
