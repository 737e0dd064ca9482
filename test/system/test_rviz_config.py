"""The RViz2 config names what the nodes publish (rviz2 is not on PyPI: its file is checked).

The nodes are built in a private Context with the shipped params file and asked for the
topics they create; the frames come from the parameter registry's defaults. The config
must show the odometry with its covariance, the TF tree and the follower's path, on
those names and with QoS the publishers can serve; odometry.launch.py must start
RViz2 with it and with a fixed frame the node uses.
"""

from __future__ import annotations

import ast
from typing import Any

import pytest
import yaml
from rclpy.qos import ReliabilityPolicy

from diffdrive_odom.ros.odometry_node import OdometryNode
from diffdrive_odom.ros.path_follower_node import PathFollowerNode
from diffdrive_odom.settings.odometry import ODOMETRY_PARAMS

from rosutil import ROOT, built

CONFIG = ROOT / "rviz" / "diffdrive_odom.rviz"
PARAMS = ROOT / "config" / "diffdrive_odom.yaml"
# RViz display class -> the message type it subscribes to.
DISPLAY_TYPES = {"rviz_default_plugins/Odometry": "nav_msgs/msg/Odometry",
                 "rviz_default_plugins/Path": "nav_msgs/msg/Path"}


def displays() -> dict[str, dict[str, Any]]:
    doc = yaml.safe_load(CONFIG.read_text(encoding="utf-8"))
    return {d["Class"]: d for d in doc["Visualization Manager"]["Displays"]}


def fixed_frame() -> str:
    doc = yaml.safe_load(CONFIG.read_text(encoding="utf-8"))
    return str(doc["Visualization Manager"]["Global Options"]["Fixed Frame"])


def _type(cls: Any) -> str:
    return f"{cls.__module__.split('.')[0]}/msg/{cls.__name__}"


@pytest.mark.dds
def test_rviz_shows_what_the_nodes_publish_on_their_names() -> None:
    shown = displays()
    assert {"rviz_default_plugins/TF", "rviz_default_plugins/Odometry",
            "rviz_default_plugins/Path"} <= set(shown)
    with built(OdometryNode, "--params-file", str(PARAMS)) as odom:
        published = {p.topic_name: p for p in odom.publishers}
    with built(PathFollowerNode, "--params-file", str(PARAMS)) as follower:
        followed = {s.topic_name: s for s in follower.subscriptions}

    odometry = shown["rviz_default_plugins/Odometry"]
    pub = published[odometry["Topic"]["Value"]]
    assert _type(pub.msg_type) == DISPLAY_TYPES["rviz_default_plugins/Odometry"]
    # A reliable subscriber matches only a reliable publisher.
    if odometry["Topic"]["Reliability Policy"] == "Reliable":
        assert pub.qos_profile.reliability == ReliabilityPolicy.RELIABLE
    cov = odometry["Covariance"]
    assert cov["Value"] and cov["Position"]["Value"] and cov["Orientation"]["Value"]
    assert "/tf" in published  # the TF display's odom -> base_link

    path = shown["rviz_default_plugins/Path"]
    sub = followed[path["Topic"]["Value"]]  # the path the follower is given
    assert _type(sub.msg_type) == DISPLAY_TYPES["rviz_default_plugins/Path"]
    assert path["Topic"]["Reliability Policy"] == (
        "Reliable" if sub.qos_profile.reliability == ReliabilityPolicy.RELIABLE
        else "Best Effort")  # the same publishers serve both


def test_fixed_frame_is_the_odometry_frame_and_the_launch_file_starts_rviz_with_it() -> None:
    default = next(s.default for s in ODOMETRY_PARAMS if s.name == "odom_frame_id")
    assert fixed_frame() == default
    tree = ast.parse((ROOT / "launch" / "odometry.launch.py").read_text(encoding="utf-8"))
    rviz = [c for c in ast.walk(tree) if isinstance(c, ast.Call)
            and any(k.arg == "package" and isinstance(k.value, ast.Constant)
                    and k.value.value == "rviz2" for k in c.keywords)]
    assert len(rviz) == 1
    source = ast.unparse(rviz[0])
    assert "IfCondition(LaunchConfiguration('rviz'))" in source
    assert "'rviz', 'diffdrive_odom.rviz'" in source
    # -f: the frame prefix the node takes from its namespace, then the same frame.
    assert f"f'{{namespace}}/{default}' if namespace else '{default}'" in source
    # The config's root-namespace topics are remapped into the namespace.
    for display in ("rviz_default_plugins/Odometry", "rviz_default_plugins/Path"):
        assert f"('{displays()[display]['Topic']['Value']}'," in source
