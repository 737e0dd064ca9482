"""What a Python file imports, read from its source; which modules are ROS packages.

For the tests that hold the declared dependencies (package.xml, setup.py's extras, the
table of settings.dependencies) to the imports: one reading of an import statement.
"""

from __future__ import annotations

import ast
import functools
import os
import sys
from pathlib import Path

OURS = "diffdrive_odom"


def imported_names(path: Path, *, for_typing: bool = False) -> tuple[set[str], set[str]]:
    """The modules the file ``path`` imports, and the names it imports from them.

    Every ``import a.b`` (``a.b``) and ``from a.b import c`` (``a.b``; ``a.b.c``, which
    may be a module, in the second set) at any depth, functions included; absolute
    only, not the standard library's nor this package's; those under ``if
    TYPE_CHECKING:`` only with ``for_typing``.
    """
    tree = ast.parse(path.read_text(encoding="utf-8"))
    skipped: set[int] = set()
    for node in ast.walk(tree):
        if (not for_typing and isinstance(node, ast.If)
                and "TYPE_CHECKING" in ast.unparse(node.test)):
            skipped.update(id(n) for stmt in node.body for n in ast.walk(stmt))
    modules: set[str] = set()
    members: set[str] = set()
    for node in ast.walk(tree):
        if id(node) in skipped:
            continue
        if isinstance(node, ast.Import):
            modules.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            modules.add(node.module)
            members.update(f"{node.module}.{a.name}" for a in node.names)

    def foreign(name: str) -> bool:
        top = name.split(".")[0]
        return top not in (OURS, "__future__") and top not in sys.stdlib_module_names

    return {m for m in modules if foreign(m)}, {m for m in members if foreign(m)}


def tops(names: set[str]) -> set[str]:
    """The top-level packages of dotted names."""
    return {n.split(".")[0] for n in names}


@functools.cache
def ament_packages() -> frozenset[str]:
    """The ROS packages this environment's ament index lists (its prefixes and the venv's).

    A Python module of that name is that package's (its rosdep key: the same name).
    """
    prefixes = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    names: set[str] = set()
    for prefix in [*prefixes, sys.prefix]:
        index = Path(prefix) / "share" / "ament_index" / "resource_index" / "packages"
        if index.is_dir():
            names.update(p.name for p in index.iterdir())
    return frozenset(names)
