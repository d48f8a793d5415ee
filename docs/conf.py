"""Sphinx configuration: the docs/ Markdown pages (MyST), the CLI reference generated from the
argparse parser, and the API reference generated from the public API's docstrings. Build with
``python tools/build_docs.py`` (warnings are errors)."""
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))          # this checkout's package, before any installed one
sys.path.insert(0, str(ROOT / "docs"))  # this file as module ``conf`` (the CLI reference)

from bdipole_cl.version import __version__  # noqa: E402


def cli_parser_without_epilogs():
    """``bdipole-cl``'s parser as the command builds it, its epilogs (lists of examples, shown
    on the command-line page) left out: sphinx-argparse reads them as reStructuredText, where
    a glob's ``*`` opens an emphasis."""
    import argparse
    from bdipole_cl.apps.cli import build_parser
    parser = build_parser()
    todo = [parser]
    while todo:
        p = todo.pop()
        p.epilog = None
        todo += [sub for a in p._actions if isinstance(a, argparse._SubParsersAction)
                 for sub in dict.fromkeys(a.choices.values())]
    return parser

project = "bdipole_cl"
author = "bdipole_cl authors"
release = version = __version__

extensions = [
    "myst_parser",
    "numpydoc",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinxarg.ext",
]
source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
root_doc = "index"
exclude_patterns = ["_build", "report.md"]    # report.md: included in performance.md
myst_heading_anchors = 3               # links to a page's sections: page.md#section-name
autosummary_generate = True
autodoc_typehints = "none"             # the docstrings say the types, with their units
numpydoc_show_class_members = False    # classes list no member stubs autosummary did not make
numpydoc_validation_checks = set()
html_theme = "alabaster"
html_static_path = []
