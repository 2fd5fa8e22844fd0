"""Sphinx configuration of the pirl_sim documentation.

Build: ``python3 -m sphinx -W --keep-going -b html docs /tmp/docs_html`` (needs the package installed, e.g.
``pip install -e .``, and the docs packages: sphinx, numpydoc, myst-parser, furo). Optional extras that a
documented module imports at module level (highway-env, gymnasium, numba, SUMO's Python packages, lanelet2)
are mocked when they are not installed, so the reference builds from the base install too.
"""

from __future__ import annotations

import importlib.util
import re

project = "pirl_sim"
author = "pirl_sim developers"
copyright = "pirl_sim developers"  # noqa: A001 (Sphinx's name)

try:
    from importlib.metadata import version as _version

    release = _version("pirl_sim")
except Exception:  # not installed: autodoc would fail anyway, but let conf.py load
    release = "unknown"
version = release

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
    "numpydoc",
    "myst_parser",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build"]
templates_path: list[str] = []

# single backticks in docstrings (`FeatureSet.derivatives`) are cross-references where Sphinx can resolve them
default_role = "py:obj"

# -- autodoc ---------------------------------------------------------------------------------------------
autodoc_default_options = {
    "members": True,
    "member-order": "bysource",
    "show-inheritance": True,
}
autodoc_typehints = "none"  # the numpydoc sections carry types, shapes and units
autodoc_preserve_defaults = True  # show `DEFAULT_BOUNDS`, not a dataclass repr
autodoc_inherit_docstrings = False  # pirl_sim's own docs only (not gymnasium's or scikit-learn's)

_OPTIONAL = ["highway_env", "gymnasium", "numba", "libsumo", "traci", "sumolib", "lanelet2", "pygame"]
autodoc_mock_imports = [m for m in _OPTIONAL if importlib.util.find_spec(m) is None]

# -- numpydoc ----------------------------------------------------------------------------------------------
numpydoc_show_class_members = False  # autodoc lists the members; no autosummary tables
numpydoc_class_members_toctree = False
numpydoc_validation_checks: set[str] = set()

# -- MyST ----------------------------------------------------------------------------------------------------
myst_enable_extensions = ["dollarmath", "colon_fence"]
myst_heading_anchors = 3

# -- HTML --------------------------------------------------------------------------------------------------
html_theme = "furo"
html_title = f"pirl_sim {release}"
html_static_path: list[str] = []


# -- |x| in docstrings ---------------------------------------------------------------------------------------
# Docstrings write absolute values and norms as |x| (``|log(theta_hat / theta)|``), which reStructuredText reads
# as a substitution reference. Before docutils resolves substitutions, every reference to an undefined one on an
# API page (text from docstrings) goes back to its literal text.
from docutils import nodes  # noqa: E402
from sphinx.transforms import SphinxTransform  # noqa: E402


class LiteralBars(SphinxTransform):
    """Undefined ``|text|`` substitution references on API pages become the text ``|text|``."""

    default_priority = 210  # before docutils' Substitutions transform (220)

    def apply(self, **kwargs) -> None:
        if not self.env.docname.startswith("api/"):
            return
        defined = set(self.document.substitution_defs) | set(self.document.substitution_names)
        for ref in list(self.document.findall(nodes.substitution_reference)):
            if ref["refname"] not in defined:
                ref.replace_self(nodes.Text(f"|{ref.astext()}|"))


class LiteralTrailingUnderscores(SphinxTransform):
    """Docstrings name fitted attributes the scikit-learn way (``theta_``, ``n_styles_``), which reStructuredText
    reads as a reference to a target ``theta``. On API pages, such a reference that no target resolves goes back
    to the text ``theta_``."""

    default_priority = 845  # after docutils resolves targets, before it reports dangling references (850)

    def apply(self, **kwargs) -> None:
        if not self.env.docname.startswith("api/"):
            return
        for ref in list(self.document.findall(nodes.reference)):
            if "refname" in ref and not ref.get("refuri") and not ref.get("refid"):
                if ref["refname"] not in self.document.nameids:
                    ref.replace_self(nodes.Text(f"{ref.astext()}_"))


# -- compact numpydoc entries ----------------------------------------------------------------------------------
# Many docstrings write a parameter on one line, ``name : type   description`` (three or more spaces before the
# description). numpydoc would read all of it as the type; this puts the description on its own indented line
# (continuation lines with it) before numpydoc parses the docstring.
_ENTRY_SECTIONS = {"Parameters", "Other Parameters", "Attributes", "Returns", "Yields", "Receives"}
_COMPACT = re.compile(r"^(?P<head>[*\w][\w, *]*\s:\s\S.*?\S)\s{3,}(?P<desc>\S.*)$")


def _split_compact_entries(app, what, name, obj, options, lines):
    out: list[str] = []
    in_section = compact = False
    i = 0
    while i < len(lines):
        line = lines[i]
        if i + 1 < len(lines) and re.fullmatch(r"\s*-{3,}\s*", lines[i + 1]) and line.strip():
            in_section, compact = line.strip() in _ENTRY_SECTIONS and not line[:1].isspace(), False
            out += [line, lines[i + 1]]
            i += 2
            continue
        if in_section and line and not line[0].isspace():
            m = _COMPACT.match(line)
            compact = m is not None
            out += [m["head"], "    " + m["desc"]] if m else [line]
        elif in_section and compact and line.strip():
            out.append("    " + line.strip())  # a continuation of a compact entry's description
        else:
            out.append(line)
        i += 1
    lines[:] = out


def _skip_member(app, what, name, obj, skip, options):
    """scikit-learn's generated metadata-routing methods (``set_fit_request``, ...) are not pirl_sim's API."""
    if re.fullmatch(r"set_\w+_request", name):
        return True
    return None


def setup(app):
    app.add_transform(LiteralBars)
    app.add_transform(LiteralTrailingUnderscores)
    app.connect("autodoc-skip-member", _skip_member)
    app.connect("autodoc-process-docstring", _split_compact_entries, priority=400)  # before numpydoc (500)
    return {"parallel_read_safe": True}
