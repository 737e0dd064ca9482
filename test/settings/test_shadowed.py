"""A ``-p`` that a params file overrides is named in one line, by the node and by the tools.

rclpy is the oracle: the real ``odometry_node`` runs with the command line, its values
are read back over ``get_parameters``, and each ``-p`` whose value it does not hold is
one the node's warning and replay's must name (and no other). The demo's own params
file is the case a user met: its ``odometry_node: {use_imu: false}`` section beats
``-p use_imu:=true``.
"""

from __future__ import annotations

import contextlib
import itertools
import subprocess
from pathlib import Path

import pytest

from diffdrive_odom.settings.params import EXAMPLE_PARAMS_FILE
from diffdrive_odom.settings.rcl import parse_override
from diffdrive_odom.tools import replay
from diffdrive_odom.tools.cmdline.args import load_settings

from rosutil import node_parameters, node_process, ros_test_node

LATER = """\
/**:
  ros__parameters:
    wheel_separation: 0.31
"""

CASES = {
    # use_imu: the node section wins; publish_rate: nobody else sets it (reaches the node).
    "demo file, node section": [
        "--params-file", str(EXAMPLE_PARAMS_FILE), "-p", "use_imu:=true",
        "-p", "publish_rate:=7.5"],
    # wheel_separation: a file after the -p sets /** again; odom_frame_id: node section.
    "later file and node section": [
        "--params-file", str(EXAMPLE_PARAMS_FILE), "-p", "wheel_separation:=0.4",
        "-p", "odom_frame_id:=odo_p", "-p", "wheel_radius:=0.06", "--params-file", "LATER"],
    # Nothing shadowed: no line.
    "nothing lost": [
        "--params-file", str(EXAMPLE_PARAMS_FILE), "-p", "wheel_radius:=0.06"],
}


def given(ros_args: list[str]) -> dict[str, str]:
    """name -> the -p text, for each -p of the command line."""
    return {parse_override(v)[0]: v for f, v in itertools.pairwise(ros_args) if f == "-p"}


@pytest.mark.parametrize("case", list(CASES), ids=list(CASES))
@pytest.mark.dds
@pytest.mark.process
def test_a_lost_p_is_named_by_the_node_and_by_replay(
    case: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    later = tmp_path / "later.yaml"
    later.write_text(LATER, encoding="utf-8")
    ros_args = [str(later) if a == "LATER" else a for a in CASES[case]]
    ps = given(ros_args)
    with node_process("odometry_node", ["--ros-args", *ros_args]) as proc:
        with ros_test_node() as (node, ex):
            got = node_parameters(node, ex, "/odometry_node", list(ps))
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.wait(timeout=1.0)
    out = proc.stdout.read() if proc.stdout else ""
    # The oracle: which -p values rclpy did not give the node.
    lost = {n for n, text in ps.items() if got[n] != parse_override(text)[1]}
    assert (case == "nothing lost") == (not lost), (case, got)

    node_lines = [ln for ln in out.splitlines() if "does not get" in ln]
    args = replay._parser().parse_args(["bag", *ros_args])
    settings = load_settings(args.ros_params, args.node_name, args.namespace)
    tool_lines = [ln for ln in capsys.readouterr().err.splitlines() if "does not get" in ln]
    if not lost:
        assert not node_lines and not tool_lines, (out, tool_lines)
        return
    for lines in (node_lines, tool_lines):
        assert len(lines) == 1, lines
        named = {n for n, text in ps.items() if f"-p {text} " in lines[0]}
        assert named == lost, lines[0]
    assert "WARN" in node_lines[0]
    # The tool's settings hold the node's values, not the lost -p.
    if "use_imu" in got:
        assert (settings.gyro is not None) == got["use_imu"]
    if "odom_frame_id" in got:
        assert settings.odom_frame_id == got["odom_frame_id"]
