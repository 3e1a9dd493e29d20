"""Sphinx configuration of the selfcal manual.

Build (from the repository root; no network needed)::

    python3 -m sphinx -W --keep-going -b html docs docs/_build/html
"""

from __future__ import annotations

import os
import re
import shutil
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
# The repository's own selfcal first, whatever copy is installed (editable elsewhere).
sys.path.insert(0, str(ROOT))
os.environ.setdefault("MPLBACKEND", "Agg")

import selfcal  # noqa: E402

# autosummary's stubs are made anew by every build: a stub left by a name since removed
# would be a page outside every toctree (a warning, an error under -W).
shutil.rmtree(DOCS / "api" / "generated", ignore_errors=True)

if Path(selfcal.__file__).resolve().parent != ROOT / "selfcal":   # pragma: no cover
    raise RuntimeError(f"the docs would document {selfcal.__file__}, not {ROOT / 'selfcal'}")

project = "selfcal"
author = "the selfcal authors"
copyright = "the selfcal authors"
release = selfcal.__version__
version = ".".join(release.split(".")[:2])

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "numpydoc",
    "myst_parser",
    "sphinx_gallery.gen_gallery",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build", "README.md", "examples", "auto_examples/*.ipynb",
                    "auto_examples/*.py", "auto_examples/*.zip", "auto_examples/*.md5",
                    "auto_examples/*.codeobj.json"]
templates_path = ["_templates"]

# -- autodoc / autosummary / numpydoc ------------------------------------------------------
autosummary_generate = True
autosummary_imported_members = True
autodoc_typehints = "none"          # the numpydoc sections say the types
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_validation_checks: set = set()
numpydoc_xref_param_type = False

# -- MyST ----------------------------------------------------------------------------------
myst_heading_anchors = 3

# -- the gallery -----------------------------------------------------------------------------
sphinx_gallery_conf = {
    "examples_dirs": "examples",
    "gallery_dirs": "auto_examples",
    "filename_pattern": r"/plot_",
    "download_all_examples": False,
    # no execution-times pages: they load DataTables and jQuery from CDNs when viewed
    "write_computation_times": False,
    "remove_config_comments": True,
    "within_subsection_order": "FileNameSortKey",     # plot_1_..., plot_2_...
    "abort_on_example_error": True,
    "plot_gallery": "True",
    "image_scrapers": ("matplotlib",),
    "reference_url": {},
}

# -- HTML ------------------------------------------------------------------------------------
html_theme = "pydata_sphinx_theme"
html_title = f"selfcal {release}"
html_theme_options = {
    "navigation_with_keys": False,
    "show_prev_next": True,
    "github_url": None,
    "icon_links": [],
}
html_static_path: list = []


# -- the API pages list every public name ---------------------------------------------------
#: Public names not given an autosummary entry, and why (said on the page instead).
API_UNLISTED = {"selfcal": {"__version__"}}   # a string; docs/api/selfcal.rst names it


def _autosummary_names(rst: Path) -> tuple[str, set]:
    """The ``currentmodule`` of an API page and the names its autosummary tables list."""
    module, names, inside = "", set(), False
    for line in rst.read_text(encoding="utf-8").splitlines():
        if line.startswith(".. currentmodule::"):
            module = line.split("::", 1)[1].strip()
        if line.startswith(".. autosummary::"):
            inside = True
            continue
        if inside:
            item = line.strip()
            if line and not line.startswith("   "):
                inside = False
            elif item and not item.startswith(":"):
                names.add(item)
                continue
        # "* ``selfcal.hdr.merge_hdr``: :func:`selfcal.merge_hdr`" (documented elsewhere)
        found = re.match(r"\* ``([\w.]+)\.(\w+)``: :\w+:`[\w.]+`$", line)
        if found and found.group(1) == module:
            names.add(found.group(2))
    return module, names


def check_api_pages(app) -> None:
    """Warn (an error under ``-W``) when an API page and its module's ``__all__`` differ."""
    import importlib

    from sphinx.util import logging

    log = logging.getLogger("selfcal.docs")
    for rst in sorted((DOCS / "api").glob("*.rst")):
        module, listed = _autosummary_names(rst)
        if not module:
            continue
        public = set(getattr(importlib.import_module(module), "__all__", ()))
        public -= API_UNLISTED.get(module, set())
        for name in sorted(public - listed):
            log.warning(f"{rst.relative_to(ROOT)}: {module}.{name} is public (__all__) "
                        "but not listed")
        for name in sorted(listed - public):
            log.warning(f"{rst.relative_to(ROOT)}: {module}.{name} is listed but not in "
                        f"{module}.__all__")


def setup(app):
    app.connect("builder-inited", check_api_pages)
