"""Sphinx configuration of the arsurf documentation (``make docs``; tests/project/test_docs.py builds it with -W)."""
from __future__ import annotations

import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # this tree's arsurf, whatever is installed
sys.path.insert(0, str(ROOT / "docs" / "_ext"))  # arsurf_schema: the session schema table, from the code
os.environ.setdefault("MPLBACKEND", "Agg")  # the gallery draws without a display

import arsurf  # noqa: E402

project = "arsurf"
author = "the arsurf developers"
copyright = "arsurf developers, MIT licence"  # noqa: A001
version = release = arsurf.__version__

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
    "numpydoc",
    "sphinx_gallery.gen_gallery",
    "arsurf_schema",
]
exclude_patterns = ["_build", "_ext", "**.md", "auto_examples/*.ipynb", "auto_examples/*.py", "auto_examples/*.zip",
                    "auto_examples/*.md5", "auto_examples/*.json"]
templates_path: list[str] = []
html_theme = "alabaster"
html_static_path: list[str] = []
html_theme_options = {"description": "AR surface model for AFM nanomanipulation", "fixed_sidebar": True}
default_role = "obj"
nitpicky = False
suppress_warnings = ["config.cache"]  # sphinx_gallery_conf holds a function: the environment is rebuilt

# autodoc / numpydoc
autodoc_member_order = "bysource"
autodoc_typehints = "none"  # the numpydoc Parameters sections give the types, with units
autodoc_mock_imports: list[str] = []
numpydoc_show_class_members = False  # members are listed explicitly where they are documented
numpydoc_class_members_toctree = False
numpydoc_xref_param_type = False
numpydoc_attributes_as_param_list = True

# the gallery: examples/plot_*.py, run at every build (each a few seconds)
sphinx_gallery_conf = {
    "examples_dirs": str(ROOT / "examples"),
    "gallery_dirs": "auto_examples",
    "filename_pattern": r"/plot_",
    "ignore_pattern": r"__init__\.py",
    "capture_repr": ("_repr_html_", "__repr__"),
    "download_all_examples": False,
    "remove_config_comments": True,
    "within_subsection_order": "FileNameSortKey",
    "show_memory": False,
    "backreferences_dir": None,
    "write_computation_times": False,
    "matplotlib_animations": False,
    "default_thumb_file": None,
}
