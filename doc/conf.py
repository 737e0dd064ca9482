"""Sphinx configuration: `make docs` (sphinx-build -W) and rosdoc2 (docs.ros.org) read it.

rosdoc2 copies this folder into a build directory of its own and runs this file there
(its wrapping conf.py adds autodoc, intersphinx, myst_parser and its theme), so paths are
taken from where the package is installed or from this checkout, whichever imports.
"""

import re
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent if "__file__" in globals() else Path.cwd()


def _package_root() -> Path:
    """The checkout's root: beside this file, or, under rosdoc2, where it copied doc/ from.

    rosdoc2 runs a conf.py of its own in a build folder that exec's this file by its
    original path (``exec(open("<package>/doc/conf.py").read())``): that path names the
    package, whose sources autodoc and the directive import (the buildfarm installs the
    package's dependencies, not the package).
    """
    if (HERE.parent / "package.xml").is_file():
        return HERE.parent
    wrapper = HERE / "conf.py"
    text = wrapper.read_text(encoding="utf-8") if wrapper.is_file() else ""
    found = re.search(r'exec\(open\("([^"]+)"\)', text)
    return Path(found.group(1)).resolve().parent.parent if found else HERE.parent


ROOT = _package_root()
# The directive extension beside this file (rosdoc2's copy has it too), and the package.
sys.path.insert(0, str(HERE / "_ext"))
sys.path.insert(0, str(ROOT))

project = "diffdrive_odom"
author = "diffdrive_odom maintainers"
copyright = "diffdrive_odom maintainers, Apache-2.0"
try:
    from xml.etree import ElementTree

    release = (ElementTree.parse(ROOT / "package.xml").findtext("version") or "").strip()
except (OSError, ElementTree.ParseError):
    release = ""
version = ".".join(release.split(".")[:2])

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "param_tables",
]
source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = master_doc = "index"
# doc/incoming: other branches' drafts, folded into the pages at merge (never built).
# The rest are what rosdoc2 generates beside a copy of this tree (its own index of the
# same pages, a second copy of them under user_docs/, sphinx-apidoc's module pages that
# the API pages here already cover, the README as a "standard document").
exclude_patterns = [
    "_build", "incoming", "incoming/**", "Thumbs.db", ".DS_Store",
    "user_docs", "user_docs/**", "user_docs*.rst", "modules.rst", "diffdrive_odom.*rst",
    "standard_docs", "standard_docs/**", "standards.rst", "__readme_include.rst",
    "sphinx_output", "sphinx_output/**",
]

# MyST: `[text](page.md#a-heading)` anchors for headings down to ####, so a broken
# internal link is a warning (an error under -W).
myst_heading_anchors = 4
myst_enable_extensions = ["colon_fence", "dollarmath"]
# -n checks every page link, heading anchor, :doc: and toctree entry. The core's
# docstrings name Python objects the way the code reads (``kinematics.body_increment``
# from a sibling package, module constants autodoc does not list): those references are
# rendered, not resolved.
nitpick_ignore_regex = [(r"py:.*", r".*")]

# autodoc: the core's API from its docstrings (the core imports no ROS: nothing to mock).
autodoc_default_options = {"members": True, "show-inheritance": True}
autodoc_member_order = "bysource"
autodoc_typehints = "none"

try:
    import sphinx_rtd_theme  # noqa: F401  (rosdoc2's theme, as docs.ros.org shows it)

    html_theme = "sphinx_rtd_theme"
except ImportError:
    html_theme = "alabaster"
html_title = f"diffdrive_odom {release}"
# The theme keeps table cells on one line in an 800 px column (wide tables scrolled
# sideways, their key column off-screen): _static/tables.css wraps them.
html_static_path = ["_static"]
html_css_files = ["tables.css"]
# A code block without a language is program output, not Python (Sphinx's default
# would colour it as Python).
highlight_language = "text"

rosdoc2_settings = {
    # The API pages here document the core with autodoc already.
    "enable_autodoc": True,
    "support_markdown": True,
}
