"""The pure core never imports rclpy, ROS messages or rosbags: enforced, not hoped for.

Each core module is imported in a fresh interpreter in which those packages cannot be
imported at all (a meta-path finder refuses them), so an import anywhere in the core's
import graph, even an indirect one, fails the test with the module that pulled it in.
"""

from __future__ import annotations

import json
import pkgutil
import subprocess
import sys

import pytest

import diffdrive_odom

pytestmark = [pytest.mark.process]

# The rclpy shells and the bag tools: the only modules allowed to import ROS or rosbags.
SHELL = {
    "ros_common", "bagio", "replay", "evaluate", "play", "demo", "cli", "calibrate",
}
# The demo is a package: its rclpy parts (loop, cli) are shell, these are pure.
PURE_DEMO = ("diffdrive_odom.demo", "diffdrive_odom.demo.settings",
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


def core_modules() -> list[str]:
    """Every module of the package that is not a node, the rclpy layer or a bag tool."""
    names = [m.name for m in pkgutil.iter_modules(diffdrive_odom.__path__)]
    return sorted([f"diffdrive_odom.{n}" for n in names
                   if n not in SHELL and not n.endswith("_node")] + list(PURE_DEMO))


def test_the_core_imports_no_ros_and_no_rosbags() -> None:
    modules = core_modules()
    assert {"diffdrive_odom.core.integration", "diffdrive_odom.core.estimator",
            "diffdrive_odom.core.conversions",
            "diffdrive_odom.core.pipeline", "diffdrive_odom.settings.params"} <= set(modules)
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
