# Two commands do everything on a fresh machine (README):
#   make demo   -> set up, then run the full demo headless on a bundled scan
#   make test   -> set up, then run the test suite (what .ci/run calls)
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.arsurf-installed
OUT    ?= out/demo

.PHONY: demo demo-material test setup system bench scans docs clean
# the PeakForce QNM file of the material demo (third-party test data, ../shared: never copied here)
QNM ?= ../shared/scans-real/sample_0.spm

setup: system $(STAMP)
	@$(PY) tools/editable_root.py  # this checkout on the path: a folder named arsurf beside a script cannot shadow it

# Debian packages for offscreen rendering (Mesa/OSMesa); only installs what is missing.
system:
	@sh tools/install-system-deps.sh

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q --no-compile -e ".[all,test,docs]"  # no .pyc for the ~11000 installed modules: each compiles at first import (docs/testing.rst)
	$(PY) -m arsurf.warmup --quiet  # numba's cache, built once here: the first demo does not wait on the compiler
	touch $(STAMP)

demo: setup
	$(VENV)/bin/arsurf demo --out $(OUT)

# feel a QNM file's soft, stiff and sticky regions. sample_0.spm leaves its DMTModulus (Arb) and
# Adhesion (V of deflection) uncalibrated: the conversions below are stated assumptions
# (docs/materials.rst), not the file's: 1.7e10 Pa per Arb (median E* ~1 GPa), 50 nm/V, 40 N/m;
# R 5 nm is the file's own Tip Radius
demo-material: setup
	$(VENV)/bin/arsurf demo --material $(QNM) --out out/demo-material --tip-radius-nm 5 \
		--modulus-scale 1.7e10 --deflection-sensitivity-nm-per-v 50 --spring-constant 40

# the suite on every core (pytest-xdist: one worker per CPU, whole files, the slow ones first:
# docs/testing.rst); PYTEST_WORKERS=0 runs it in this one process, PYTEST_ARGS adds pytest's own
PYTEST_WORKERS ?= logical
test: setup
	$(PY) -m pytest -q -p no:cacheprovider -n $(PYTEST_WORKERS) $(PYTEST_ARGS)

bench: setup
	@for b in bench/*.py; do echo "== $$b"; $(PY) $$b || exit 1; done

# the Sphinx site (API reference, pipeline, equations, gallery) into docs/_build/html; warnings are errors
docs: setup
	$(PY) -m sphinx -W --keep-going -b html docs docs/_build/html
	@echo "open docs/_build/html/index.html"

# the demo scans; the demo's own (nanotubes) is package data, so that a wheel carries it
scans: setup
	$(VENV)/bin/arsurf synth --out scans
	mv scans/nanotubes.npz arsurf/data/nanotubes.npz

clean:
	rm -rf $(VENV) out .pytest_cache docs/_build docs/auto_examples
