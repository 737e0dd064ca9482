"""The package through the real ``ros2`` command line, as a user drives it on a robot.

Against one colcon install (the session's, shared with test_colcon and test_launch),
in a shell environment taken from its ``install/setup.sh``, with the ros2 daemon
started in this run's own ROS_DOMAIN_ID and stopped at the end (without it, each
graph query discovers from scratch and a loaded machine misses nodes that are
there; ../shared/launch/README.md). The nodes run once for the whole module, each
check polls for what it waits on:

* ``ros2 run`` of every node on the shipped config/diffdrive_odom.yaml (each starts,
  its topic appears) and ``ros2 launch`` of both launch files (in namespaces);
* ``ros2 param describe/get/set/dump/load`` (ranges shown, an integer set on a
  double stays a double, a typo names the closest parameter, a dump loads back);
* ``ros2 service call`` of the reset, ``ros2 topic echo --once`` of odom,
  ``ros2 lifecycle set/get`` of the managed node;
* Ctrl-C ends every process with exit code 0 and leaves none behind.

Skipped, saying why, where ``ros2`` or launch is missing (a user's clone has no
../shared/launch); CI has them.
"""

from __future__ import annotations

import importlib
import os
import re
import signal
import subprocess
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest
import yaml

from diffdrive_odom.settings.odometry import ODOMETRY_PARAMS

from rosutil import BIN

pytestmark = [pytest.mark.dds, pytest.mark.process, pytest.mark.launch, pytest.mark.slow,
              pytest.mark.xdist_group("colcon")]

PACKAGE = "diffdrive_odom"
ROS2 = BIN / "ros2"
MISSING = (
    "the ros2 command line and launch are not on PyPI: on a robot they come with ROS 2 "
    "Jazzy from apt; here run `bash ../shared/launch/install.sh .venv` (make venv does it "
    "where ../shared/launch exists)"
)
NODES = ("odometry_node", "odometry_lifecycle_node", "cmd_vel_node", "sim_node",
         "path_follower_node")
MANAGED = "/managed/odometry_lifecycle_node"
GRAPH_TIMEOUT_S = 60.0  # nine nodes starting at once on two shared cores
# What each start brings up: ros2 run of every node (the managed one publishes only once
# active), odometry.launch.py in /l1, base.launch.py use_sim:=true in /l2.
RUN_NODES = {"/odometry_node", MANAGED, "/cmd_vel_node", "/sim_node", "/path_follower_node"}
RUN_TOPICS = {"/odom", "/wheel_commands", "/joint_states", "/ground_truth/odom",
              "/path_follower_node/done"}
LAUNCH_NODES = {"/l1/odometry_node", "/l2/odometry_node", "/l2/cmd_vel_node", "/l2/sim_node"}
LAUNCH_TOPICS = {"/l1/odom", "/l2/odom", "/l2/joint_states", "/l2/wheel_commands"}


@dataclass
class Cli:
    """A sourced install: its environment, the processes it started, their logs."""

    env: dict[str, str]
    share: Path
    prefix: Path
    logs: Path
    procs: dict[str, subprocess.Popen[str]] = field(default_factory=dict)
    missing: str | None = "not waited for"  # what of the graph did not come up

    def ros2(self, *args: str, timeout: float = 30.0) -> subprocess.CompletedProcess[str]:
        """One ``ros2`` command, as typed in the sourced shell."""
        return subprocess.run([str(ROS2), *args], env=self.env, capture_output=True,
                              text=True, timeout=timeout)

    def start(self, name: str, *args: str) -> None:
        """``ros2 <args>`` in the background, in its own process group (as a terminal
        runs it: Ctrl-C reaches ``ros2 run``'s child too), output to ``logs/name``."""
        log = open(self.logs / f"{name}.log", "w", encoding="utf-8")  # noqa: SIM115
        self.procs[name] = subprocess.Popen(
            [str(ROS2), *args], env=self.env, stdout=log, stderr=subprocess.STDOUT,
            text=True, start_new_session=True)
        log.close()

    def log(self, name: str) -> str:
        return (self.logs / f"{name}.log").read_text(encoding="utf-8")

    def all_logs(self) -> str:
        return "\n".join(f"--- {n}\n{self.log(n)[-1500:]}" for n in self.procs)

    def stop_all(self, timeout: float) -> dict[str, int]:
        """Ctrl-C (SIGINT to each process group), wait, SIGKILL what is left; exit codes."""
        for proc in self.procs.values():
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGINT)
        deadline = time.monotonic() + timeout
        codes = {}
        for name, proc in self.procs.items():
            try:
                codes[name] = proc.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                codes[name] = proc.wait()
        return codes


def _sourced_env(ws: Path, logs: Path) -> dict[str, str]:
    """The environment of a shell that ran ``. install/setup.sh`` (and has ros2 on PATH)."""
    base = {**os.environ, "PATH": f"{BIN}:{os.environ.get('PATH', '')}",
            "ROS_LOG_DIR": str(logs / "ros"), "PYTHONUNBUFFERED": "1"}
    out = subprocess.run(["bash", "-c", ". install/setup.sh && env -0"], cwd=ws, env=base,
                         capture_output=True, text=True, timeout=60, check=True)
    return dict(item.split("=", 1) for item in out.stdout.split("\0") if "=" in item)


def _poll(check: Callable[[], str | None], timeout: float) -> str | None:
    """Call ``check`` until it returns None (done) or ``timeout`` passes; its last word."""
    deadline = time.monotonic() + timeout
    while True:
        problem = check()
        if problem is None or time.monotonic() > deadline:
            return problem
        time.sleep(0.2)  # between two ros2 commands (each takes ~1 s)


@pytest.fixture(scope="module")
def cli(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory,
        ) -> Iterator[Cli]:
    for tool in (ROS2, BIN / "colcon"):
        if not tool.exists():
            pytest.skip(f"{tool} missing: {MISSING}")
    try:
        importlib.import_module("launch_ros")
    except ImportError as err:
        pytest.skip(f"launch_ros missing ({err}): {MISSING}")
    colcon_ws: Path = request.getfixturevalue("colcon_ws")  # built once per session
    logs = tmp_path_factory.mktemp("ros2_cli")
    prefix = colcon_ws / "install" / PACKAGE
    cli = Cli(_sourced_env(colcon_ws, logs), prefix / "share" / PACKAGE, prefix, logs)
    daemon = cli.ros2("daemon", "start")
    assert daemon.returncode == 0, daemon.stdout + daemon.stderr
    config = str(cli.share / "config" / "diffdrive_odom.yaml")
    try:
        for node in NODES:
            extra = ["-r", "__ns:=/managed", "-r", "joint_states:=/joint_states"] if (
                node == "odometry_lifecycle_node") else []
            cli.start(node, "run", PACKAGE, node, "--ros-args", "--params-file", config, *extra)
        cli.start("odometry.launch.py", "launch", PACKAGE, "odometry.launch.py", "namespace:=l1")
        cli.start("base.launch.py", "launch", PACKAGE, "base.launch.py", "namespace:=l2",
                  "use_sim:=true")
        cli.missing = _poll(lambda: _graph_missing(
            cli, RUN_NODES | LAUNCH_NODES, RUN_TOPICS | LAUNCH_TOPICS), GRAPH_TIMEOUT_S)
        yield cli
    finally:
        cli.stop_all(10.0)  # a no-op when the last test stopped them (and checked)
        cli.ros2("daemon", "stop")


def _published(cli: Cli) -> set[str]:
    """Topics with a publisher, from ``ros2 topic list -v``."""
    out = cli.ros2("topic", "list", "-v").stdout
    published = out.split("Subscribed topics:")[0]
    return set(re.findall(r"^ \* (\S+) \[", published, re.MULTILINE))


def _graph_missing(cli: Cli, nodes: set[str], topics: set[str]) -> str | None:
    """What of ``nodes`` and published ``topics`` the daemon does not see yet (None: all)."""
    for name, proc in cli.procs.items():
        if proc.poll() is not None:
            return f"{name} ended with {proc.returncode}"
    missing_topics = topics - _published(cli)
    if missing_topics:
        return f"no publisher yet on {sorted(missing_topics)}"
    missing_nodes = nodes - set(cli.ros2("node", "list").stdout.split())
    return f"nodes not up: {sorted(missing_nodes)}" if missing_nodes else None


def _assert_up(cli: Cli, nodes: set[str], topics: set[str]) -> None:
    if cli.missing is not None:  # the whole graph did not come up: is this part of it?
        problem = _graph_missing(cli, nodes, topics)
        assert problem is None, f"{problem}\n{cli.all_logs()}"


def test_ros2_run_starts_every_node_on_the_shipped_config(cli: Cli) -> None:
    """Each node starts on config/diffdrive_odom.yaml as installed, and what it publishes
    appears (the managed node publishes only once active: its services are there)."""
    _assert_up(cli, RUN_NODES, RUN_TOPICS)
    services = cli.ros2("service", "list").stdout.split()
    assert f"{MANAGED}/change_state" in services and "/odometry_node/reset_odometry" in services


def test_ros2_launch_of_both_files(cli: Cli) -> None:
    """odometry.launch.py in /l1; base.launch.py use_sim:=true in /l2, whose simulated
    base drives its odometry: an odom message arrives there."""
    _assert_up(cli, LAUNCH_NODES, LAUNCH_TOPICS)
    echo = cli.ros2("topic", "echo", "--once", "/l2/odom", timeout=30.0)
    assert echo.returncode == 0 and "frame_id: l2/odom" in echo.stdout, echo.stdout + echo.stderr


def test_ros2_topic_echo_once_of_odom(cli: Cli) -> None:
    # --no-lost-messages: under load ros2cli reports a lost-message event on stdout
    # ("A message was lost!!!" and its counts), which is not the message's YAML.
    echo = cli.ros2("topic", "echo", "--once", "--no-lost-messages", "/odom", timeout=30.0)
    assert echo.returncode == 0, echo.stdout + echo.stderr
    msg = yaml.safe_load(echo.stdout.split("\n---")[0])
    assert (msg["header"]["frame_id"], msg["child_frame_id"]) == ("odom", "base_link")


def test_ros2_service_call_resets_the_odometry(cli: Cli) -> None:
    call = cli.ros2("service", "call", "/odometry_node/reset_odometry",
                    "std_srvs/srv/Trigger")
    assert call.returncode == 0 and "success=True" in call.stdout, call.stdout + call.stderr


def test_ros2_param_describe_set_get(cli: Cli) -> None:
    """describe shows the range and its rule; an integer set on a double stays a double;
    a typo is refused with the closest real name."""
    node = "/odometry_node"
    described = cli.ros2("param", "describe", node, "wheel_radius", "left_wheel_sign")
    out = described.stdout
    assert described.returncode == 0, out + described.stderr
    radius, sign = out.split("Parameter name: left_wheel_sign")
    for text in ("Type: double", "Nominal wheel radius [m]", "Min value: 0.0",
                 "Max value: inf", "Additional constraints: at least 0.001 (1 mm), finite"):
        assert text in radius, (text, out)
    for text in ("Type: integer", "Min value: -1", "Max value: 1", "Step: 2"):
        assert text in sign, (text, out)

    assert "Set parameter successful" in cli.ros2("param", "set", node, "wheel_radius",
                                                  "1").stdout
    got = cli.ros2("param", "get", node, "wheel_radius").stdout
    assert got.strip() == "Double value is: 1.0", got

    typo = cli.ros2("param", "set", node, "wheel_radious", "0.05")
    said = typo.stdout + typo.stderr
    assert "'wheel_radious' (did you mean wheel_radius?)" in said, said

    outside = cli.ros2("param", "set", node, "wheel_radius", "-0.5")
    said = outside.stdout + outside.stderr
    assert "Setting parameter failed" in said and "wheel_radius" in said, said

    # Inside ROS's range but no robot's: refused with the reason the start gives.
    tiny = cli.ros2("param", "set", node, "wheel_separation", "1e-9")
    said = tiny.stdout + tiny.stderr
    assert "Setting parameter failed" in said and "must be at least 0.001 m" in said, said
    got = cli.ros2("param", "get", node, "wheel_separation").stdout
    assert got.strip() != "Double value is: 1e-09", got


def test_ros2_param_dump_then_load(cli: Cli, tmp_path: Path) -> None:
    """The node's own dump loads back: every parameter is set but the read-only ones,
    which rclpy refuses as read-only (as for any node: ``start_type_description_service``
    is rclpy's own)."""
    node = "/odometry_node"
    dump = cli.ros2("param", "dump", node)
    assert dump.returncode == 0, dump.stderr
    path = tmp_path / "odometry_node.yaml"
    path.write_text(dump.stdout, encoding="utf-8")
    dumped = yaml.safe_load(dump.stdout)[node]["ros__parameters"]
    assert isinstance(dumped["wheel_noise_k_left"], float)

    load = cli.ros2("param", "load", node, str(path))
    assert load.returncode == 0, load.stdout + load.stderr
    ok = set(re.findall(r"^Set parameter (\S+) successful$", load.stdout, re.MULTILINE))
    failed = dict(re.findall(r"^Set parameter (\S+) failed: (.*)$", load.stderr, re.MULTILINE))
    read_only = {s.name for s in ODOMETRY_PARAMS if s.read_only}
    assert set(failed) <= read_only | {"start_type_description_service"}, failed
    assert all("read-only" in why for why in failed.values()), failed
    names = {s.name for s in ODOMETRY_PARAMS}
    assert names - read_only <= ok, sorted(names - read_only - ok)
    again = yaml.safe_load(cli.ros2("param", "dump", node).stdout)[node]["ros__parameters"]
    assert again == dumped  # the same values, still doubles where they were
    assert all(type(v) is float for v in again["twist_covariance_diagonal"])


def test_ros2_lifecycle_set_and_get(cli: Cli) -> None:
    for transition in ("configure", "activate"):
        out = cli.ros2("lifecycle", "set", MANAGED, transition)
        assert "Transitioning successful" in out.stdout, out.stdout + out.stderr
    assert cli.ros2("lifecycle", "get", MANAGED).stdout.strip() == "active [3]"
    echo = cli.ros2("topic", "echo", "--once", "/managed/odom", timeout=30.0)
    assert echo.returncode == 0 and "frame_id: managed/odom" in echo.stdout, (
        echo.stdout + echo.stderr)


def test_ctrl_c_ends_every_process_with_exit_0(cli: Cli) -> None:
    """Last: SIGINT to each ``ros2 run`` / ``ros2 launch`` (as Ctrl-C in its terminal)."""
    codes = cli.stop_all(10.0)
    assert codes == dict.fromkeys(cli.procs, 0), f"{codes}\n{cli.all_logs()}"
    left = []
    for entry in Path("/proc").iterdir():
        try:
            cmd = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode()
        except OSError:
            continue
        if str(cli.prefix) in cmd:
            left.append(cmd)
    assert not left, left
