"""The launch files: what they declare and name (always), and a real run (with launch_ros).

(a) Each file is read with ``ast`` (no ``launch`` import): it declares ``params_file``,
``namespace`` and ``use_sim_time``, and every executable, config file and included
launch file it names is in a colcon install of the package (test_colcon's build).
(b) Where ``launch_ros`` imports, each file runs for real with ``launch.LaunchService``
against that install, in a namespace and with ``use_sim_time``: a peer checks over DDS
that the nodes answer (odometry from JointStates it sends, wheel commands from a
Twist, the simulated base's clock), then ``LaunchService.shutdown()`` must stop every
process with exit code 0 and leave none behind.
"""

from __future__ import annotations

import ast
import importlib
import math
import os
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
import yaml
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Twist
from nav_msgs.msg import Odometry
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Imu, JointState
from std_msgs.msg import Float64MultiArray

from rosutil import (
    ROOT,
    STEP_NS,
    T0_NS,
    listen,
    node_parameters,
    ros_test_node,
    send_first,
    spin_until,
    stamp,
    wait_ready,
)

PACKAGE = "diffdrive_odom"
REQUIRED_ARGUMENTS = {"params_file", "namespace", "use_sim_time"}
# What each file starts itself, and which launch files it includes.
EXECUTABLES = {"odometry.launch.py": {"odometry_node"},
               "base.launch.py": {"cmd_vel_node", "sim_node", "path_follower_node"}}
INCLUDES = {"odometry.launch.py": set[str](), "base.launch.py": {"launch/odometry.launch.py"}}
# Files of the package's share each names, and what it starts of other packages.
SHARE_FILES = {"odometry.launch.py": {"config/diffdrive_odom.yaml", "rviz/diffdrive_odom.rviz"},
               "base.launch.py": {"config/diffdrive_odom.yaml"}}
FOREIGN = {"odometry.launch.py": {"rviz2/rviz2"}, "base.launch.py": set[str]()}
NAMESPACE = "robot1"
MISSING_LAUNCH_ROS = (
    "launch_ros is missing (ROS 2 launch is not on PyPI): on a robot it comes with ROS 2 "
    "Jazzy from apt; here run `bash ../shared/launch/install.sh .venv` (make venv does "
    "it where ../shared/launch exists)"
)


pytestmark = [pytest.mark.xdist_group("colcon")]


@pytest.fixture(scope="session")
def install(colcon_ws: Path) -> Path:
    """The package's colcon install prefix (built once per session, shared with test_colcon)."""
    return colcon_ws / "install" / PACKAGE


# --- (a) what the files declare and name, read without launch -----------------------------


@dataclass
class Named:
    """What a launch file declares and refers to."""

    arguments: dict[str, ast.expr | None] = field(default_factory=dict)
    executables: set[str] = field(default_factory=set)
    foreign: set[str] = field(default_factory=set)  # package/executable of other packages
    share_files: set[str] = field(default_factory=set)  # relative to share/<package>
    includes: set[str] = field(default_factory=set)


def _callee(call: ast.Call) -> str:
    f = call.func
    return f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else ""


def _text(node: ast.expr | None, constants: dict[str, str] | None = None) -> str:
    """A string literal, or a module-level string constant's value."""
    if isinstance(node, ast.Name) and constants and node.id in constants:
        return constants[node.id]
    assert isinstance(node, ast.Constant) and isinstance(node.value, str), (
        ast.dump(node) if node else "missing")
    return node.value


def _keyword(call: ast.Call, name: str) -> ast.expr | None:
    return next((k.value for k in call.keywords if k.arg == name), None)


def read_launch_file(path: Path) -> Named:
    named = Named()
    tree = ast.parse(path.read_text(), str(path))
    constants = {t.id: s.value.value for s in tree.body if isinstance(s, ast.Assign)
                 and isinstance(s.value, ast.Constant) and isinstance(s.value.value, str)
                 for t in s.targets if isinstance(t, ast.Name)}

    def text(node: ast.expr | None) -> str:
        return _text(node, constants)

    for call in (n for n in ast.walk(tree) if isinstance(n, ast.Call)):
        kind = _callee(call)
        if kind == "DeclareLaunchArgument":
            named.arguments[text(call.args[0])] = _keyword(call, "default_value")
        elif kind == "Node":
            package, exe = text(_keyword(call, "package")), text(_keyword(call, "executable"))
            if package == PACKAGE:
                named.executables.add(exe)
            else:
                named.foreign.add(f"{package}/{exe}")
        elif kind == "PathJoinSubstitution":
            parts = call.args[0]
            assert isinstance(parts, ast.List) and isinstance(parts.elts[0], ast.Call)
            root, rest = _callee(parts.elts[0]), "/".join(text(e) for e in parts.elts[1:])
            if root == "FindPackageShare":
                assert text(parts.elts[0].args[0]) == PACKAGE
                named.share_files.add(rest)
            elif root == "ThisLaunchFileDir":
                named.includes.add(f"launch/{rest}")
            else:
                raise AssertionError(f"{path.name}: path from {root} not checked")
    return named


@pytest.mark.parametrize("name", sorted(EXECUTABLES))
@pytest.mark.process
@pytest.mark.launch
def test_launch_file_declares_arguments_and_names_installed_files(
    name: str, install: Path
) -> None:
    named = read_launch_file(ROOT / "launch" / name)
    assert set(named.arguments) >= REQUIRED_ARGUMENTS, named.arguments
    # Defaults a user expects: the root namespace, wall time, the shipped config.
    assert _text(named.arguments["namespace"]) == ""
    assert _text(named.arguments["use_sim_time"]) == "false"
    assert named.share_files == SHARE_FILES[name]
    assert named.executables == EXECUTABLES[name]
    assert named.foreign == FOREIGN[name]
    assert named.includes == INCLUDES[name]

    share, lib = install / "share" / PACKAGE, install / "lib" / PACKAGE
    assert (share / "launch" / name).is_file(), f"{name} not installed where ros2 launch looks"
    for exe in named.executables:
        assert os.access(lib / exe, os.X_OK), f"{name} starts {exe}, not installed in {lib}"
    for rel in named.share_files | named.includes:
        assert (share / rel).is_file(), f"{name} names {rel}, not installed in {share}"


def test_base_declares_what_it_passes_on_and_the_docs_list_every_argument() -> None:
    """base.launch.py declares odometry.launch.py's arguments too (``--show-args`` cannot
    look into an include found at run time), and doc/robot.md's table lists each one."""
    odo = read_launch_file(ROOT / "launch" / "odometry.launch.py").arguments
    base = read_launch_file(ROOT / "launch" / "base.launch.py").arguments
    assert set(odo) <= set(base)
    for name in odo:
        assert ast.dump(odo[name] or ast.Constant(None)) == ast.dump(
            base[name] or ast.Constant(None)), f"{name}: defaults differ"
    page = (ROOT / "doc" / "robot.md").read_text(encoding="utf-8")
    section = page.split("\n## Launch\n", 1)[1].split("\n## ", 1)[0]
    rows = {line.split("|")[1].strip(" `"): line.split("|")[3].strip()
            for line in section.splitlines() if line.startswith("| `")}
    assert rows == {**dict.fromkeys(base, "base"), **dict.fromkeys(odo, "both")}
    for name, default in base.items():
        if isinstance(default, ast.Constant) and isinstance(default.value, str) and default.value:
            assert f"| `{name}` | `{default.value}` |" in section, name


# --- (b) a real run with launch.LaunchService -------------------------------------------


@dataclass
class Run:
    """What one launch did: return code, processes started and how they ended."""

    returncode: int = -1
    started: dict[int, str] = field(default_factory=dict)  # pid -> executable
    exits: dict[int, int] = field(default_factory=dict)  # pid -> exit code


def _alive_under(prefix: Path) -> list[str]:
    """Processes whose command line mentions the install prefix (ours: a fresh tmp dir)."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            cmd = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode()
        except OSError:
            continue
        if str(prefix) in cmd:
            found.append(f"{entry.name}: {cmd}")
    return found


def run_launch(install: Path, name: str, arguments: dict[str, str],
               check: Callable[[], None]) -> Run:
    """Run share/<pkg>/launch/<name> as ``ros2 launch`` does; ``check`` runs meanwhile in
    another thread (LaunchService must own the main thread), then the service is shut down."""
    # Imported by name: launch has no type information (and ./launch is the package's
    # launch files, which mypy would take for it).
    launch: Any = importlib.import_module("launch")
    actions: Any = importlib.import_module("launch.actions")
    handlers: Any = importlib.import_module("launch.event_handlers")
    sources: Any = importlib.import_module("launch.launch_description_sources")

    run = Run()

    def started(event: Any, _context: Any) -> None:
        run.started[event.pid] = Path(event.cmd[0]).name

    def exited(event: Any, _context: Any) -> None:
        run.exits[event.pid] = event.returncode

    service = launch.LaunchService()
    service.include_launch_description(launch.LaunchDescription([
        actions.RegisterEventHandler(handlers.OnProcessStart(on_start=started)),
        actions.RegisterEventHandler(handlers.OnProcessExit(on_exit=exited)),
        actions.IncludeLaunchDescription(
            sources.PythonLaunchDescriptionSource(
                str(install / "share" / PACKAGE / "launch" / name)),
            launch_arguments=list(arguments.items())),
    ]))
    errors: list[BaseException] = []
    finished = threading.Event()

    def checker() -> None:
        try:
            check()
        except BaseException as err:  # reported in the main thread
            errors.append(err)
        finally:
            while not finished.wait(0.2):  # a no-op until the service runs
                service.shutdown()

    thread = threading.Thread(target=checker, daemon=True)
    thread.start()
    try:
        run.returncode = service.run()
    finally:
        finished.set()
        thread.join(60.0)
    if errors:
        raise errors[0]
    return run


def assert_clean(run: Run, install: Path, expected: set[str]) -> None:
    assert run.returncode == 0
    assert set(run.started.values()) == expected, run.started
    assert {run.started[p]: run.exits.get(p) for p in run.started} == dict.fromkeys(expected, 0)
    assert not _alive_under(install), _alive_under(install)


@pytest.fixture
def launch_env(install: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    """Environment of a sourced install: ament index and Python path (the installed code)."""
    try:
        importlib.import_module("launch_ros")
    except ImportError as err:
        pytest.skip(f"{MISSING_LAUNCH_ROS} ({err})")
    site = next((install / "lib").glob("python3*/site-packages"))
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(install))
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(
        p for p in (str(site), os.environ.get("PYTHONPATH", "")) if p))
    monkeypatch.setenv("ROS_LOG_DIR", str(tmp_path / "log"))
    yield install


def example_robot() -> tuple[float, float]:
    """(wheel_radius, wheel_separation) of the shipped config, read as plain YAML."""
    doc = yaml.safe_load((ROOT / "config" / "diffdrive_odom.yaml").read_text())
    values: dict[str, Any] = {}
    for section in doc.values():
        values.update(section["ros__parameters"])
    return float(values["wheel_radius"]), float(values["wheel_separation"])


def get_parameters(node: Node, ex: SingleThreadedExecutor, target: str,
                   names: list[str]) -> list[Any]:
    """The values of ``names`` on ``target``, asked again until answered (rosutil)."""
    values = node_parameters(node, ex, target, names)
    return [values[n] for n in names]


def check_odometry(node: Node, ex: SingleThreadedExecutor, joint_topic: str) -> None:
    """A reference reading, then both wheels 1 rad on: odom at x = r, in the namespace's frames."""
    r, _ = example_robot()
    assert get_parameters(node, ex, f"/{NAMESPACE}/odometry_node",
                          ["use_sim_time", "wheel_radius"]) == [True, r]
    sink = listen(node, f"/{NAMESPACE}/odom")
    pub = node.create_publisher(JointState, f"/{NAMESPACE}/{joint_topic}", 10)
    wait_ready(ex, pub, sink)

    def reading(k: int, angle: float) -> JointState:
        msg = JointState(name=["left_wheel_joint", "right_wheel_joint"],
                         position=[angle, angle])
        msg.header.stamp = stamp(T0_NS + k * STEP_NS)
        return msg

    send_first(ex, pub, sink, reading(0, 0.0))
    pub.publish(reading(1, 1.0))
    last = T0_NS + STEP_NS
    assert spin_until(ex, lambda: any(
        o.header.stamp.sec * 10**9 + o.header.stamp.nanosec == last for o in sink.odom), 10.0)
    odom = sink.odom[-1]
    assert math.isclose(odom.pose.pose.position.x, r * 1.0, abs_tol=1e-12)
    assert odom.pose.pose.position.y == 0.0
    assert (odom.header.frame_id, odom.child_frame_id) == (
        f"{NAMESPACE}/odom", f"{NAMESPACE}/base_link")


def drive(node: Node, linear: float, angular: float) -> None:
    """Publish the Twist at 20 Hz (the cmd_vel watchdog wants a steady stream)."""
    pub = node.create_publisher(Twist, f"/{NAMESPACE}/cmd_vel", 10)
    cmd = Twist()
    cmd.linear.x, cmd.angular.z = linear, angular
    node.create_timer(0.05, lambda: pub.publish(cmd))


@pytest.mark.dds
@pytest.mark.process
@pytest.mark.launch
def test_odometry_launch_runs_namespaced_on_sim_time(launch_env: Path) -> None:
    def check() -> None:
        with ros_test_node("launch_peer") as (node, ex):
            check_odometry(node, ex, "encoders")

    run = run_launch(launch_env, "odometry.launch.py", {
        "namespace": NAMESPACE, "use_sim_time": "true", "joint_states_topic": "encoders"}, check)
    assert_clean(run, launch_env, {"odometry_node"})


@pytest.mark.dds
@pytest.mark.process
@pytest.mark.launch
def test_base_launch_runs_odometry_and_cmd_vel(launch_env: Path) -> None:
    r, b = example_robot()
    v, w = 0.21, 1.0
    expected = [(v - 0.5 * w * b) / r, (v + 0.5 * w * b) / r]  # rad/s, left and right

    def check() -> None:
        with ros_test_node("launch_peer") as (node, ex):
            check_odometry(node, ex, "joint_states")
            assert get_parameters(
                node, ex, f"/{NAMESPACE}/cmd_vel_node", ["use_sim_time"]) == [True]
            commands: list[Float64MultiArray] = []
            node.create_subscription(
                Float64MultiArray, f"/{NAMESPACE}/wheel_commands", commands.append, 10)
            drive(node, v, w)
            assert spin_until(ex, lambda: any(
                len(c.data) == 2 and all(math.isclose(a, e, rel_tol=1e-9)
                                         for a, e in zip(c.data, expected, strict=True))
                for c in commands), 15.0), [list(c.data) for c in commands[-3:]]

    run = run_launch(launch_env, "base.launch.py", {
        "namespace": NAMESPACE, "use_sim_time": "true"}, check)
    assert_clean(run, launch_env, {"odometry_node", "cmd_vel_node"})


@pytest.mark.parametrize("sim_time", [True, False], ids=["sim_time", "wall_time"])
@pytest.mark.dds
@pytest.mark.process
@pytest.mark.launch
def test_base_launch_with_sim_closes_the_loop(launch_env: Path, sim_time: bool) -> None:
    """use_sim: a Twist moves the simulated base and odometry follows its truth; the sim
    owns /clock with use_sim_time and publishes none without."""
    v = 0.1

    def check() -> None:
        with ros_test_node("launch_peer") as (node, ex):
            clocks: list[Clock] = []
            node.create_subscription(Clock, "/clock", clocks.append, 10)
            truth: dict[int, Odometry] = {}
            node.create_subscription(
                Odometry, f"/{NAMESPACE}/ground_truth/odom",
                lambda m: truth.__setitem__(_ns(m), m), 100)
            sink = listen(node, f"/{NAMESPACE}/odom")
            assert get_parameters(node, ex, f"/{NAMESPACE}/sim_node",
                                  ["publish_clock", "use_sim_time"]) == [sim_time, False]
            for other in ("odometry_node", "cmd_vel_node"):
                assert get_parameters(node, ex, f"/{NAMESPACE}/{other}",
                                      ["use_sim_time"]) == [sim_time]
            assert spin_until(ex, lambda: len(sink.odom) >= 5, 20.0), len(sink.odom)
            if sim_time:
                assert spin_until(ex, lambda: len(clocks) >= 5, 10.0), len(clocks)
                assert _ns(clocks[-1]) > _ns(clocks[0])
            else:
                assert node.count_publishers("/clock") == 0 and not clocks
            drive(node, v, 0.0)
            # Moving at v for a while (motor lag 50 ms): odometry's twist and pose.
            assert spin_until(ex, lambda: sink.odom[-1].pose.pose.position.x > 0.1, 20.0)
            odom = sink.odom[-1]
            assert math.isclose(odom.twist.twist.linear.x, v, rel_tol=1e-3)
            # True geometry = nominal, ideal encoders, no slip: odometry is the truth.
            assert spin_until(ex, lambda: _ns(odom) in truth, 5.0)
            same = truth[_ns(odom)]
            assert math.isclose(odom.pose.pose.position.x, same.pose.pose.position.x,
                                abs_tol=1e-9)
            assert abs(odom.pose.pose.position.y) < 1e-9
            assert odom.header.frame_id == f"{NAMESPACE}/odom"

    run = run_launch(launch_env, "base.launch.py", {
        "namespace": NAMESPACE, "use_sim_time": str(sim_time).lower(), "use_sim": "true"}, check)
    assert_clean(run, launch_env, {"odometry_node", "cmd_vel_node", "sim_node"})


@pytest.mark.dds
@pytest.mark.process
@pytest.mark.launch
def test_base_launch_with_sim_and_use_imu_gives_the_odometry_its_gyro(launch_env: Path) -> None:
    """use_sim:=true use_imu:=true: sim_node publishes its gyro (imu_rate 100 Hz: two
    samples per 50 Hz reading) and odometry_node runs gyro-aided on it, its /diagnostics
    saying so (without the gyro it said "IMU silent: wheels only")."""

    def check() -> None:
        with ros_test_node("launch_peer") as (node, ex):
            assert get_parameters(node, ex, f"/{NAMESPACE}/sim_node",
                                  ["imu_rate", "joint_state_rate"]) == [100.0, 50.0]
            assert get_parameters(node, ex, f"/{NAMESPACE}/odometry_node",
                                  ["use_imu"]) == [True]
            imu: list[Imu] = []
            joints: list[JointState] = []
            node.create_subscription(Imu, f"/{NAMESPACE}/imu", imu.append, 100)
            node.create_subscription(
                JointState, f"/{NAMESPACE}/joint_states", joints.append, 100)
            aided: list[dict[str, str]] = []

            def on_diagnostics(msg: DiagnosticArray) -> None:
                for s in msg.status:
                    values = {kv.key: kv.value for kv in s.values}
                    if "odometry" in s.name and values.get("imu") == "gyro-aided" and int(
                            values.get("imu samples", "0")) > 0:
                        aided.append(values)

            node.create_subscription(DiagnosticArray, "/diagnostics", on_diagnostics, 10)
            assert spin_until(ex, lambda: bool(aided) and len(joints) >= 100, 30.0), (
                len(joints), len(imu))
            # Two samples per reading, counted over the stretch both streams were heard.
            i_ns, j_ns = [_ns(m) for m in imu], [_ns(m) for m in joints]
            lo, hi = max(i_ns[0], j_ns[0]), min(i_ns[-1], j_ns[-1])
            both = sum(lo <= s <= hi for s in i_ns), sum(lo <= s <= hi for s in j_ns)
            assert both[1] >= 50 and abs(both[0] - 2 * both[1]) <= 2, both

    run = run_launch(launch_env, "base.launch.py", {
        "namespace": NAMESPACE, "use_sim": "true", "use_imu": "true"}, check)
    assert_clean(run, launch_env, {"odometry_node", "cmd_vel_node", "sim_node"})


def _ns(msg: Any) -> int:
    t = msg.clock if isinstance(msg, Clock) else msg.header.stamp
    return int(t.sec) * 10**9 + int(t.nanosec)


# The robot's own file: a /** value over the shipped default, and a node-named section.
ROBOT_FILE = """\
/**:
  ros__parameters:
    wheel_radius: 0.05
odometry_node:
  ros__parameters:
    enable_odom_tf: false
"""


@pytest.mark.dds
@pytest.mark.process
@pytest.mark.launch
def test_launch_arguments_switch_and_a_second_params_file_layers(
    launch_env: Path, tmp_path: Path
) -> None:
    """extra_params_file is applied after params_file (its /** and its node section win
    over the shipped defaults, for every node); a switch given beats the files, an
    empty one leaves the files' value. Root namespace: the file's
    ``odometry_node`` section is the node's own."""
    robot = tmp_path / "robot.yaml"
    robot.write_text(ROBOT_FILE, encoding="utf-8")
    r_shipped, _ = example_robot()
    assert r_shipped != 0.05  # or the layering would not show

    def check() -> None:
        with ros_test_node("launch_peer") as (node, ex):
            assert get_parameters(node, ex, "/odometry_node", [
                "wheel_radius", "use_imu", "enable_odom_tf"]) == [0.05, True, False]
            assert get_parameters(node, ex, "/cmd_vel_node", ["wheel_radius"]) == [0.05]

    run = run_launch(launch_env, "base.launch.py", {
        "extra_params_file": str(robot), "use_imu": "true"}, check)
    assert_clean(run, launch_env, {"odometry_node", "cmd_vel_node"})

    def check_switch_off() -> None:
        with ros_test_node("launch_peer") as (node, ex):
            assert get_parameters(node, ex, "/odometry_node", [
                "wheel_radius", "use_imu", "enable_odom_tf"]) == [0.05, False, True]

    # enable_odom_tf given true beats the robot file's node section.
    run = run_launch(launch_env, "odometry.launch.py", {
        "extra_params_file": str(robot), "use_imu": "false", "enable_odom_tf": "true"},
        check_switch_off)
    assert_clean(run, launch_env, {"odometry_node"})
