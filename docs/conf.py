"""Sphinx configuration: furo theme, MyST pages, executed MyST notebooks, numpydoc API."""

from __future__ import annotations

import importlib.metadata

project = "rotmod"
author = "the rotmod developers"
copyright = "2026, the rotmod developers"
release = importlib.metadata.version("rotmod")
version = release

extensions = [
    "myst_nb",
    "numpydoc",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
]

# .rst first: autosummary writes its generated pages with the first suffix.
source_suffix = {".rst": "restructuredtext", ".md": "myst-nb"}
exclude_patterns = ["_build", "figures/*.md", "**.ipynb_checkpoints"]
html_theme = "furo"
html_title = f"rotmod {release}"

myst_enable_extensions = ["dollarmath", "amsmath", "colon_fence"]
myst_heading_anchors = 3
# Tutorials run at every build (small sizes: a few seconds each); a failing cell fails the build.
nb_execution_mode = "force"
nb_execution_timeout = 300
nb_execution_raise_on_error = True
nb_execution_show_tb = True

autosummary_generate = True
autosummary_imported_members = False
autodoc_typehints = "none"  # numpydoc renders the documented types
numpydoc_show_class_members = False
numpydoc_validation_checks: set[str] = set()
numpydoc_xref_param_type = False

# No intersphinx: the docs build offline (CI reaches package registries only).
suppress_warnings = ["myst.header", "config.cache"]
