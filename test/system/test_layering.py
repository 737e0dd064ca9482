"""The core, the settings and the wire codecs never import rclpy, ROS messages or bag libraries.

Every module of ``diffdrive_odom.core``, ``diffdrive_odom.settings`` and
``diffdrive_odom.wire`` (walked with
pkgutil, so a new module is checked too) is imported in a fresh interpreter in which
those packages cannot be imported at all (a meta-path finder refuses them), so an
import anywhere in their import graph, even an indirect one, fails the test with the
module that pulled it in. import-linter's contracts (setup.cfg) say the same per
package, and more (the layers); they are run here too when the tool is installed.
"""

from __future__ import annotations

import json
import pkgutil
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import diffdrive_odom.core
import diffdrive_odom.settings
import diffdrive_odom.wire

from paths import ROOT

pytestmark = [pytest.mark.process]

# Also pure, as before the layers had packages: the package and each layer's
# ``__init__`` (a docstring of what the layer may import), and the demo's pure parts.
# The tools' packages import nothing in their ``__init__`` (a command's --help needs no
# rosbags), and what every command shares (cmdline) is pure.
ALSO_PURE = ("diffdrive_odom", "diffdrive_odom.ros", "diffdrive_odom.tools",
             "diffdrive_odom.tools.bags", "diffdrive_odom.tools.replaying",
             "diffdrive_odom.tools.calibrating", "diffdrive_odom.tools.cmdline",
             "diffdrive_odom.tools.cmdline.args", "diffdrive_odom.tools.cmdline.outputs",
             "diffdrive_odom.demo", "diffdrive_odom.demo.settings",
             "diffdrive_odom.demo.report", "diffdrive_odom.demo.plot")
BLOCKED = (
    "rclpy", "rosbags", "mcap", "mcap_ros2", "builtin_interfaces", "rcl_interfaces",
    "rosgraph_msgs", "std_srvs", "tf2_msgs", "launch", "launch_ros", "ament_index_python",
)

CHECK = r"""
import importlib, importlib.abc, json, sys
blocked = tuple(json.loads(sys.argv[1]))

class Refuse(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        top = name.split(".")[0]
        if top in blocked or top.endswith("_msgs") or top.endswith("_interfaces"):
            raise ImportError(f"the core must not import {name}")
        return None

sys.meta_path.insert(0, Refuse())
failures = {}
for module in json.loads(sys.argv[2]):
    try:
        importlib.import_module(module)
    except ImportError as err:
        failures[module] = str(err)
print(json.dumps(failures))
"""


def pure_modules() -> list[str]:
    """Every module of the core, settings and wire packages, and :data:`ALSO_PURE`."""
    names = []
    for package in (diffdrive_odom.core, diffdrive_odom.settings, diffdrive_odom.wire):
        names.append(package.__name__)
        names += [m.name for m in pkgutil.walk_packages(package.__path__, package.__name__ + ".")]
    return sorted(names) + list(ALSO_PURE)


def test_the_core_imports_no_ros_and_no_rosbags() -> None:
    modules = pure_modules()
    assert {"diffdrive_odom.core.geometry.integration",
            "diffdrive_odom.core.estimation.wheels.estimator", "diffdrive_odom.wire.conversions",
            "diffdrive_odom.core.estimation.pipeline", "diffdrive_odom.settings.params",
            "diffdrive_odom.settings.registry"} <= set(modules)
    assert len([m for m in modules if m.startswith("diffdrive_odom.core.")]) >= 40
    out = subprocess.run(
        [sys.executable, "-c", CHECK, json.dumps(BLOCKED), json.dumps(modules)],
        capture_output=True, text=True, timeout=120, check=True)
    failures = json.loads(out.stdout.strip().splitlines()[-1])
    assert failures == {}, failures


def test_the_check_catches_an_import() -> None:
    """The blocker really blocks: a shell module, which imports rclpy, is refused."""
    out = subprocess.run(
        [sys.executable, "-c", CHECK, json.dumps(BLOCKED),
         json.dumps(["diffdrive_odom.ros.runtime"])],
        capture_output=True, text=True, timeout=120, check=True)
    failures = json.loads(out.stdout.strip().splitlines()[-1])
    assert "diffdrive_odom.ros.runtime" in failures
    assert "must not import" in failures["diffdrive_odom.ros.runtime"]


def test_import_linter_contracts_are_kept() -> None:
    """``lint-imports`` (import-linter; ``make lint`` runs it too): the layers and the
    pure core hold, per package."""
    tool = Path(sys.executable).parent / "lint-imports"
    command = str(tool) if tool.exists() else shutil.which("lint-imports")
    if command is None:
        pytest.skip("lint-imports (import-linter) is not installed: pip install import-linter")
    out = subprocess.run([command], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "0 broken" in out.stdout, out.stdout
