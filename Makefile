# Two commands do everything on a fresh machine (README):
#   make demo   -> set up, then run the full demo headless on a bundled scan
#   make test   -> set up, then run the test suite (what .ci/run calls)
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.arsurf-installed
OUT    ?= out/demo

.PHONY: demo test setup system bench scans docs clean

setup: system $(STAMP)

# Debian packages for offscreen rendering (Mesa/OSMesa); only installs what is missing.
system:
	@sh tools/install-system-deps.sh

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e ".[all,test,docs]"
	touch $(STAMP)

demo: setup
	$(VENV)/bin/arsurf demo --out $(OUT)

test: setup
	$(PY) -m pytest -q -p no:cacheprovider $(PYTEST_ARGS)

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
