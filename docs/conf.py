"""Sphinx configuration of the RoadBEV-ROS documentation (``make docs``; rosdoc2 builds the same
project through ``rosdoc2.yaml``).

Pages are Markdown (MyST) except the API pages (reStructuredText, where autodoc lives). The
package is imported from this checkout (the repository root goes first on ``sys.path``), so the
API pages, the parameter tables and the command line are those of the code next to them.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
sys.path[:0] = [str(ROOT), str(DOCS / "_ext")]

_version = re.search(r"<version>([^<]+)</version>", (ROOT / "package.xml").read_text(encoding="utf-8"))

project = "RoadBEV-ROS"
author = "RoadBEV-ROS developers"
copyright = "RoadBEV-ROS developers, MIT licence"
release = _version.group(1).strip() if _version else "unknown"
version = release

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "sphinx.ext.viewcode",
    "sphinxarg.ext",
    "roadbev_docs",
]
source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build", "_ext"]
templates_path: list[str] = []

# MyST: ```{directive} fences, $-free text (σ, ×, ± are written as they are), anchors for headings
myst_enable_extensions = ["colon_fence", "deflist"]
myst_heading_anchors = 3

# autodoc + napoleon: the code's Google-style docstrings
autodoc_default_options = {"members": True, "member-order": "bysource"}
autodoc_typehints = "signature"
autodoc_class_signature = "mixed"
napoleon_google_docstring = True
napoleon_numpy_docstring = False
# "Attributes:" sections as fields of their class, not as second descriptions of the attributes
# autodoc already documents
napoleon_use_ivar = True

html_theme = "alabaster"
html_title = f"RoadBEV-ROS {release}"
html_static_path: list[str] = []
