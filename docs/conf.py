"""Sphinx configuration of omnican's documentation (``python -m sphinx -W -b html docs OUT``).

Builds offline: no intersphinx, no remote images. The configuration reference is made
from the schema, the CLI reference from the argument parsers, and the pictures by
``tools/gen_docs_pictures.py`` from the code, at every build (docs/_ext/omnican_docs.py).
"""

from __future__ import annotations

import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "_ext"))
sys.path.insert(0, str(HERE.parent))

import omnican  # noqa: E402

project = "omnican"
author = "the omnican developers"
copyright = "2026, the omnican developers"
release = version = omnican.__version__

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "sphinxarg.ext",
    "omnican_docs",
]
source_suffix = {".md": "markdown"}
# No typographic dashes and quotes: the pages are full of options and values to type
# (--sim, 'vector'), and an en-dash or a curly quote cannot be pasted into a terminal.
smartquotes = False
myst_enable_extensions = ["colon_fence", "deflist"]
myst_heading_anchors = 3
exclude_patterns = ["_build", "_generated/**"]
root_doc = "index"

autodoc_typehints = "description"
autodoc_member_order = "bysource"
autodoc_default_options = {"members": True, "show-inheritance": True}
autodoc_mock_imports: list[str] = []

html_theme = "furo"
html_title = f"omnican {release}"
html_static_path: list[str] = []
