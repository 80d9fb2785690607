"""Sphinx configuration of the grasp_fc_ros documentation site (`make docs`).

The API pages are rendered from the package's numpy-style docstrings (napoleon); the
node reference page reads the node's parameter table and the interface definitions
from the code (``_ext/grasp_fc_docs.py``), so they cannot drift from it.
"""

from __future__ import annotations

import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
sys.path.insert(0, str(DOCS / "_ext"))
sys.path.insert(0, str(DOCS.parent))

project = "grasp_fc_ros"
author = "grasp_fc_ros maintainers"
copyright = "grasp_fc_ros maintainers, Apache-2.0"

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "grasp_fc_docs",
]

source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
root_doc = "index"
# The experiment's report folder keeps its own README as its index page; the CSVs and
# PNGs next to it are linked as downloads.
exclude_patterns = ["_build", "_ext"]

# Markdown: `## Exact stage` gets the anchor `#exact-stage`, as on GitHub, so that links
# such as performance.md#worker-chunks work on both.
myst_heading_anchors = 3
myst_enable_extensions = ["dollarmath"]

# numpy-style docstrings only; their "Parameters" become field lists.
napoleon_google_docstring = False
napoleon_numpy_docstring = True
napoleon_use_rtype = False
autodoc_member_order = "bysource"
autodoc_typehints = "description"
autodoc_default_options = {"show-inheritance": True}

html_theme = "alabaster"
html_title = "grasp_fc_ros"
html_theme_options = {"description": "Exact, fast force closure for ROS 2 Jazzy",
                      "fixed_sidebar": True}
