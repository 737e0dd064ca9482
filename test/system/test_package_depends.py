"""package.xml's run dependencies are what the nodes and the launch files import: all, no more.

Why: rosdep installs on every robot what package.xml declares. It declared
python3-matplotlib and python3-scipy, which no node imports (only the offline tools,
whose libraries are setup.py's ``tools`` extra), and lacked python3-yaml, which the
settings import (issue 39).

How: a fresh interpreter imports every node's module (the installed distribution's
console scripts under ``diffdrive_odom.ros``); every module of this package it then holds
(``sys.modules``) is read for the modules it imports by name (every import statement,
those inside functions too: a node may reach them after its start; not those for the
type checker only), and so are the launch files. Each such module maps to its rosdep
key: a ROS package (in this environment's ament index) to its own name, a Python
library by :data:`KEYS`. Then: every key is declared, every declared key is imported,
and the nodes load nothing beyond what those imports bring (a second interpreter
imports the same modules without this package's code).
"""

from __future__ import annotations

import functools
import json
import subprocess
import sys
from dataclasses import dataclass
from importlib.metadata import entry_points
from pathlib import Path
from xml.etree import ElementTree

import pytest

from importscan import OURS, ament_packages, imported_names, tops
from paths import ROOT

pytestmark = [pytest.mark.process]

# Python libraries the package imports -> their rosdep keys (rosdistro's python.yaml).
KEYS = {"numpy": "python3-numpy", "yaml": "python3-yaml"}

# Imports the named modules (argv[1], JSON) in order, and those of argv[2] that are
# modules (``from a import b``: b may be one); prints what the interpreter then holds,
# what it held at its start (site, .pth hooks), and where our modules are.
LOAD = r"""
import importlib, json, sys
startup = sorted(sys.modules)
for name in json.loads(sys.argv[1]):
    importlib.import_module(name)
for name in json.loads(sys.argv[2]):
    try:
        importlib.import_module(name)
    except ImportError:
        pass
print(json.dumps({"startup": startup, "loaded": sorted(sys.modules), "files": sorted(
    m.__file__ for n, m in list(sys.modules.items())
    if n.split(".")[0] == "diffdrive_odom" and getattr(m, "__file__", None))}))
"""


@dataclass(frozen=True)
class Loaded:
    """What a fresh interpreter held at its start and after the imports; our modules' files."""

    startup: set[str]
    loaded: set[str]
    files: list[Path]


def load(modules: list[str], maybe: list[str] | tuple[()] = ()) -> Loaded:
    done = subprocess.run([sys.executable, "-c", LOAD, json.dumps(modules), json.dumps(maybe)],
                          capture_output=True, text=True, timeout=120, check=False)
    assert done.returncode == 0, done.stderr
    result = json.loads(done.stdout.splitlines()[-1])
    return Loaded(set(result["startup"]), set(result["loaded"]),
                  [Path(p) for p in result["files"]])


def declared() -> set[str]:
    """package.xml's run dependencies (``exec_depend``, and ``depend``, which implies it)."""
    root = ElementTree.parse(ROOT / "package.xml").getroot()
    return {e.text.strip() for tag in ("exec_depend", "depend") for e in root.iter(tag)
            if e.text}


def node_modules() -> list[str]:
    scripts = [e for e in entry_points(group="console_scripts")
               if e.value.startswith(f"{OURS}.ros.")]
    assert {e.name for e in scripts} >= {"odometry_node", "cmd_vel_node", "sim_node"}
    return sorted({e.value.split(":")[0] for e in scripts})


def key_of(module: str) -> str | None:
    if module in KEYS:
        return KEYS[module]
    return module if module in ament_packages() else None


@functools.cache
def nodes() -> tuple[Loaded, set[str], set[str]]:
    """What importing the nodes loads, and the modules (and names) their code imports."""
    loaded = load(node_modules())
    modules: set[str] = set()
    members: set[str] = set()
    for path in loaded.files:
        found, named = imported_names(path)
        modules |= found
        members |= named
    return loaded, modules, members


def launch_imports() -> set[str]:
    files = sorted((ROOT / "launch").glob("*.launch.py"))
    assert files, ROOT / "launch"
    return set().union(*(imported_names(path)[0] for path in files))


def test_what_the_nodes_import_is_declared_in_package_xml() -> None:
    _, modules, _ = nodes()
    names = tops(modules)
    assert {"rclpy", "numpy", "yaml", "nav_msgs", "tf2_msgs"} <= names, names
    unmapped = sorted(m for m in names if key_of(m) is None)
    assert not unmapped, f"no rosdep key known for {unmapped}: add it to KEYS"
    missing = sorted({key_of(m) or m for m in names} - declared())
    assert not missing, f"the nodes import these, package.xml lacks them: {missing}"


def test_every_run_dependency_is_imported_by_a_node_or_a_launch_file() -> None:
    _, modules, _ = nodes()
    launched = tops(launch_imports())
    unmapped = sorted(m for m in launched if key_of(m) is None)
    if unmapped:
        pytest.skip(f"{unmapped}: not installed here (launch and launch_ros come from "
                    "../shared/launch), so the launch files' keys cannot be told")
    used = {key_of(m) for m in tops(modules) | launched}
    assert not declared() - used, (
        f"package.xml declares what no node or launch file imports: {sorted(declared() - used)}")
    for library in ("python3-matplotlib", "python3-scipy"):  # the tools' (issue 39)
        assert library not in declared()


def test_the_nodes_load_nothing_beyond_what_their_imports_bring() -> None:
    """The modules the nodes' code imports, imported without it, load the same set."""
    loaded, modules, members = nodes()
    alone = load(sorted(modules), sorted(members))
    extra = sorted(t for t in tops(loaded.loaded) - tops(alone.loaded) - tops(loaded.startup)
                   if t != OURS and t not in sys.stdlib_module_names)
    assert not extra, f"the nodes load {extra}, which no import of theirs names"
