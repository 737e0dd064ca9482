"""Replay resolves params files and ``-p`` exactly as rclpy does for the same node.

Each case starts the real ``odometry_node`` with a command line, reads every declared
parameter back over its ``get_parameters`` service, and compares with what
``diffdrive-odom replay`` makes of the equivalent flags (its own argument parser,
then ``rcl.resolve_parameters``). Also: unknown names are reported once.
"""

from __future__ import annotations

import math
import threading
import time
from pathlib import Path
from typing import Any

import pytest

from diffdrive_odom.settings.odometry import ODOMETRY_PARAMS
from diffdrive_odom.settings.rcl import resolve_parameters
from diffdrive_odom.tools import replay
from diffdrive_odom.tools.cmdline.args import load_settings

from rosutil import ROOT, node_parameters, node_process, ros_test_node

CONFIG = str(ROOT / "config" / "diffdrive_odom.yaml")
SPECS = ODOMETRY_PARAMS

# Old style: geometry under /**, then the node's own section.
FILE_A = """\
/**:
  ros__parameters:
    wheel_radius: 0.05
    wheel_separation: 0.3
    publish_rate: 1.0
odometry_node:
  ros__parameters:
    publish_rate: 2.0
    odom_frame_id: odo_a
"""
# Namespaced and wildcard sections.
FILE_B = """\
/odometry_node:
  ros__parameters:
    publish_rate: 3.0
/**/odometry_node:
  ros__parameters:
    time_jump_threshold: 4.0
/robot1/*:
  ros__parameters:
    max_wheel_speed: 50.0
robot1:
  odometry_node:
    ros__parameters:
      base_frame_id: base_b
/**:
  ros__parameters:
    enable_odom_tf: false
"""
# A wildcard section after the node's own one.
FILE_C = """\
odometry_node:
  ros__parameters:
    velocity_rolling_window_size: 3
/**:
  ros__parameters:
    wheel_radius: 0.06
    wheel_separation: 0.25
    velocity_rolling_window_size: 5
"""

CASES: dict[str, list[str]] = {
    "node section beats /**": ["--params-file", "A"],
    "namespaced: node section no longer applies": ["--params-file", "A", "-r", "__ns:=/robot1"],
    "-p after the file loses to the node section": [
        "--params-file", "A", "-p", "publish_rate:=9.0", "-p", "wheel_radius:=0.07"],
    "-p before the file loses to both": [
        "-p", "wheel_radius:=0.08", "-p", "odom_frame_id:=odo_p", "--params-file", "A"],
    "two files, namespace, wildcards": [
        "--params-file", "A", "--params-file", "B", "-r", "__ns:=/robot1",
        "-p", "enable_odom_tf:=true"],
    "two files, no namespace": ["--params-file", "A", "--params-file", "B"],
    "/** after the node section wins; renamed node": [
        "--params-file", "C", "-r", "__node:=other_name"],
    "/** after the node section wins": ["--params-file", "C"],
    "shipped config, -p after it wins": [
        "--params-file", "CONFIG", "-p", "enable_odom_tf:=false", "-p", "publish_rate:=7.5"],
    "shipped config, namespace and renamed node": [
        "--params-file", "CONFIG", "-r", "__ns:=/robot1", "-r", "__node:=odom2",
        "-p", "wheel_radius:=0.033"],
}


def replay_flags(ros_args: list[str]) -> list[str]:
    """The replay command line equivalent to the node's --ros-args."""
    out: list[str] = []
    it = iter(ros_args)
    for arg in it:
        if arg == "-r":
            rule = next(it)
            key, _, value = rule.partition(":=")
            out += {"__ns": ["--namespace", value], "__node": ["--node-name", value]}[key]
        else:
            out.append(arg)
    return out


def fqn_of(ros_args: list[str]) -> str:
    flags = replay_flags(ros_args)
    name = flags[flags.index("--node-name") + 1] if "--node-name" in flags else "odometry_node"
    ns = flags[flags.index("--namespace") + 1].strip("/") if "--namespace" in flags else ""
    return f"/{ns}/{name}" if ns else f"/{name}"


def same(a: Any, b: Any) -> bool:
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return bool(a == b)


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    d = tmp_path_factory.mktemp("params")
    out = {"CONFIG": CONFIG}
    for key, text in (("A", FILE_A), ("B", FILE_B), ("C", FILE_C)):
        (d / f"{key}.yaml").write_text(text, encoding="utf-8")
        out[key] = str(d / f"{key}.yaml")
    return out


@pytest.mark.parametrize("case", list(CASES), ids=list(CASES))
@pytest.mark.dds
@pytest.mark.process
def test_replay_resolves_as_the_node_does(case: str, files: dict[str, str]) -> None:
    ros_args = [files.get(a, a) if prev == "--params-file" else a
                for prev, a in zip(["", *CASES[case][:-1]], CASES[case], strict=True)]
    flags = replay_flags(ros_args)
    args = replay._parser().parse_args(["bag", *flags])
    resolved = resolve_parameters(args.ros_params, args.node_name, args.namespace)
    expected = {s.name: resolved.get(s.name, s.default) for s in SPECS}
    names = [s.name for s in SPECS]
    with node_process("odometry_node", ["--ros-args", *ros_args]) as proc, \
            ros_test_node() as (node, ex):
        got = node_parameters(node, ex, fqn_of(ros_args), names)
        assert proc.poll() is None
    differ = {n: (got[n], expected[n]) for n in names if not same(got[n], expected[n])}
    assert not differ, f"{case}: node vs replay {differ}"
    # And replay builds the very settings (frames with the namespace prefix too).
    settings = load_settings(args.ros_params, args.node_name, args.namespace)
    assert settings.publish_rate == got["publish_rate"]
    assert settings.geometry.wheel_radius == got["wheel_radius"]


@pytest.mark.dds
@pytest.mark.process
def test_known_figures_of_the_old_problems(files: dict[str, str]) -> None:
    """The values themselves, from rcl's rules (not from the code under test)."""
    def resolve(*argv: str) -> dict[str, Any]:
        args = replay._parser().parse_args(["bag", *argv])
        return resolve_parameters(args.ros_params, args.node_name, args.namespace)

    a = files["A"]
    assert resolve("--params-file", a)["publish_rate"] == 2.0
    assert resolve("--params-file", a, "--namespace", "/robot1")["publish_rate"] == 1.0
    assert resolve("--params-file", a, "-p", "publish_rate:=9.0")["publish_rate"] == 2.0
    assert resolve("-p", "wheel_radius:=0.08", "--params-file", a)["wheel_radius"] == 0.05
    shipped = resolve("--params-file", CONFIG, "-p", "enable_odom_tf:=false")
    assert shipped["enable_odom_tf"] is False
    c = files["C"]
    assert resolve("--params-file", c)["velocity_rolling_window_size"] == 5


# The nodes' start-up lines: the parameters are declared (and warned about) before them.
STARTED = ("wheel odometry: ", "-> wheel_commands")


def run_to_start(executable: str, args: list[str], seconds: float = 30.0) -> str:
    """Output of a node run until its start-up line (at most ``seconds``), then SIGINT.

    Held until the line is seen: after a fixed 4 s the line had not come yet beside a
    loaded machine (the "and it started" check failed in two runs, passing when run
    again).
    """
    lines: list[str] = []
    with node_process(executable, args) as proc:
        reader = threading.Thread(target=lambda: lines.extend(proc.stdout or ()), daemon=True)
        reader.start()
        deadline = time.monotonic() + seconds
        while (time.monotonic() < deadline and proc.poll() is None
               and not any(s in ln for ln in list(lines) for s in STARTED)):
            time.sleep(0.05)
    reader.join(10.0)
    return "".join(lines)


@pytest.mark.parametrize("executable", ["odometry_node", "cmd_vel_node"])
@pytest.mark.dds
@pytest.mark.process
def test_a_typo_gets_one_warning_with_the_real_name(executable: str, tmp_path: Path) -> None:
    typo = tmp_path / "typo.yaml"
    typo.write_text("/**:\n  ros__parameters:\n    wheel_seperation_multiplier: 1.01\n",
                    encoding="utf-8")
    out = run_to_start(executable, [
        "--ros-args", "--params-file", CONFIG, "--params-file", str(typo),
        "-p", "wheel_radious:=0.05"])
    warned = [ln for ln in out.splitlines() if "unknown parameters" in ln]
    assert len(warned) == 1, out
    line = warned[0]
    assert "WARN" in line
    assert "wheel_seperation_multiplier (did you mean wheel_separation_multiplier?)" in line
    assert "wheel_radious (did you mean wheel_radius?)" in line
    # Names another node of the package knows are not suspicious (one shared file).
    for other in ("publish_rate", "wheel_command_rate", "enable_odom_tf", "linear.x"):
        assert other not in line, line
    assert any(s in out for s in STARTED)  # and it started


def test_replay_warns_the_same_way(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    typo = tmp_path / "typo.yaml"
    typo.write_text("/**:\n  ros__parameters:\n    wheel_seperation_multiplier: 1.01\n",
                    encoding="utf-8")
    args = replay._parser().parse_args(
        ["bag", "--params-file", CONFIG, "--params-file", str(typo),
         "-p", "wheel_radious:=0.05"])
    load_settings(args.ros_params, args.node_name, args.namespace)
    err = capsys.readouterr().err.splitlines()
    warned = [ln for ln in err if "unknown parameters" in ln]
    assert len(warned) == 1, err
    assert "wheel_seperation_multiplier (did you mean wheel_separation_multiplier?)" in warned[0]
    assert "wheel_radious (did you mean wheel_radius?)" in warned[0]
