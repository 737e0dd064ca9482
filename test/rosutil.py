"""Helpers for tests that talk to the nodes over real DDS (no mocks).

A test owns a private rclpy Context and an executor; the node under test runs as a
separate process started from the venv's console script, exactly as a user runs it.
What several test files share lives here (no test module imports another): the peer
side of an odometry node, its process with live output, a burst source.
"""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import pytest
import rclpy
from builtin_interfaces.msg import Time
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState, GetState
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterValue
from rcl_interfaces.srv import GetParameters, ListParameters, SetParameters
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter, parameter_value_to_python
from sensor_msgs.msg import JointState
from tf2_msgs.msg import TFMessage

from diffdrive_odom.ros import lockstep
from diffdrive_odom.ros.qos import qos
from diffdrive_odom.ros.runtime import make_executor
from diffdrive_odom.settings.errors import ParameterError
from diffdrive_odom.tools.cmdline import process
from diffdrive_odom.wire.conversions import ns_to_stamp

from paths import DATA as DATA  # re-exported: the DDS tests take both from here
from paths import ROOT as ROOT

BIN = Path(sys.executable).parent


def executable(name: str) -> str:
    """Path of a console script installed in this venv."""
    path = BIN / name
    if not path.exists():
        raise FileNotFoundError(f"{path} missing: run `make venv` (pip install -e .)")
    return str(path)


def running(pid: int) -> bool:
    """Whether process ``pid`` runs (a zombie, ended and waiting for its reaper, does not)."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            return f.read().rsplit(b")", 1)[1].split()[0] != b"Z"
    except FileNotFoundError:
        return False


def still_running(pids: Sequence[int], seconds: float) -> list[int]:
    """Of ``pids``, those still running after up to ``seconds`` (held until all ended)."""
    deadline = time.monotonic() + seconds
    while any(running(p) for p in pids) and time.monotonic() < deadline:
        time.sleep(0.02)
    return [p for p in pids if running(p)]


def kill_left(proc: subprocess.Popen[Any], pids: Sequence[int] = ()) -> None:
    """A test's cleanup: kill ``proc`` and whichever of ``pids`` still run."""
    if proc.poll() is None:
        proc.kill()
    proc.wait()
    for pid in pids:
        if running(pid):
            with suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)


@contextmanager
def node_process(
    name: str, args: Sequence[str] = (), env: dict[str, str] | None = None
) -> Iterator[subprocess.Popen[str]]:
    """Run a console script as its own process; stop it with SIGINT at the end."""
    proc = subprocess.Popen(
        [executable(name), *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env={**os.environ, **(env or {})},
    )
    try:
        yield proc
    finally:
        process.stop(proc, timeout=10)


@contextmanager
def built(node_class: type[Node], *args: str) -> Iterator[Any]:
    """The node class built in a private Context from ``--ros-args`` ``args``."""
    context = Context()
    rclpy.init(context=context, args=["test", "--ros-args", *args])
    try:
        node = node_class(context=context)
        try:
            yield node
        finally:
            node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)


@contextmanager
def ros_test_node(name: str = "test_peer") -> Iterator[tuple[Node, SingleThreadedExecutor]]:
    """A node in a private Context, with its executor; both torn down afterwards."""
    context = Context()
    rclpy.init(context=context)
    node = Node(name, context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    try:
        yield node, executor
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)


@contextmanager
def loop_peer(name: str) -> Iterator[tuple[Node, Any, lockstep.Participant]]:
    """The test's node in a lockstep loop (named in the sim's ``lockstep_nodes``): on the
    sim's /clock, its loop's topics counted, each step answered through :func:`spin_until`.

    On the EventsExecutor, as the nodes run: it answers every step, so the loop waits for
    it as for them.
    """
    context = Context()
    rclpy.init(context=context)
    node = Node(name, context=context, parameter_overrides=[
        Parameter("use_sim_time", value=True)])
    executor, _ = make_executor(context=context)
    executor.add_node(node)
    try:
        yield node, executor, lockstep.Participant(node)
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)


def spin_until(
    executor: SingleThreadedExecutor, condition: Callable[[], Any], timeout: float = 10.0
) -> bool:
    """Spin until ``condition()`` is truthy or ``timeout`` seconds pass."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        executor.spin_once(timeout_sec=0.05)
        lockstep.settle(executor)  # a peer in a lockstep loop answers what it took
    return bool(condition())


def spin_for(executor: SingleThreadedExecutor, seconds: float) -> None:
    """Spin for a fixed time."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.02)
        lockstep.settle(executor)


def call_service(node: Node, executor: SingleThreadedExecutor, srv_type: Any, name: str,
                 request: Any, timeout: float = 20.0) -> Any:
    """The answer to ``request`` on service ``name``, asked again until one comes.

    DDS can report a service before its reply path is matched, and a request sent
    then is never answered; so only for calls without side effects.
    """
    client = node.create_client(srv_type, name)
    try:
        assert spin_until(executor, client.service_is_ready, timeout), f"{name} never came up"
        deadline = time.monotonic() + timeout
        while True:
            future = client.call_async(request)
            if spin_until(executor, future.done, 2.0) or time.monotonic() > deadline:
                break
        assert future.done(), f"{name} never answered"
        return future.result()
    finally:
        node.destroy_client(client)


def handshake(node: Node, executor: SingleThreadedExecutor, target: str,
              timeout: float = 20.0) -> None:
    """Return once the node ``target`` has matched every endpoint ``node`` made so far.

    Discovery is asymmetric: our subscription can see a publisher of ``target`` while
    that publisher does not yet see us, and what it sends meanwhile is lost to us (a
    first odom lost so, its reading's repeats are dropped as repeats: the test
    waits forever). ``target`` answering a service client made after our other
    endpoints proves it has matched them too: each side announces its readers, and
    its writers, in order on one reliable discovery stream, and the client's reply
    reader and request writer come last on theirs.
    """
    call_service(node, executor, ListParameters, f"{target}/list_parameters",
                 ListParameters.Request(depth=1), timeout)


def publisher_node(node: Node, executor: SingleThreadedExecutor, topic: str,
                   timeout: float = 20.0) -> str:
    """The fully qualified name of the (first) node publishing ``topic``.

    The graph can list an endpoint before the name of its node has arrived (rmw
    sends names on their own topic): wait for the name.
    """
    names: list[str] = []

    def known() -> bool:
        names[:] = [f"{i.node_namespace.rstrip('/')}/{i.node_name}"
                    for i in node.get_publishers_info_by_topic(topic)
                    if "_UNKNOWN_" not in i.node_name + i.node_namespace]
        return bool(names)

    assert spin_until(executor, known, timeout), f"no named publisher of {topic}"
    return names[0]


def wait_matched(node: Node, executor: SingleThreadedExecutor, pub: Any, sub: Any,
                 timeout: float = 20.0) -> bool:
    """Wait until a node matches ``pub`` and publishes ``sub``'s topic, both ways.

    Both our views first (cheap), then :func:`handshake` with that node for its own.
    """
    if not (spin_until(executor, lambda: pub.get_subscription_count() > 0, timeout)
            and spin_until(executor, lambda: sub.get_publisher_count() > 0, timeout)):
        return False
    handshake(node, executor, publisher_node(node, executor, sub.topic_name, timeout),
              timeout)
    return True


def wait_for_subscriber(
    executor: SingleThreadedExecutor, publisher: Any, timeout: float = 15.0
) -> bool:
    """Wait until DDS discovery has matched ``publisher`` with a subscriber."""
    return spin_until(executor, lambda: publisher.get_subscription_count() > 0, timeout)


def assert_refuses_to_start(executable_name: str, name: str, params: list[str]) -> str:
    """The node, started with ``params`` (``-p`` arguments), stops at once with exit code 2
    and exactly one output line naming the parameter ``name``: what a user sees (returned)."""
    with node_process(executable_name, ["--ros-args", *params]) as proc:
        code = proc.wait(timeout=20)
        out = proc.stdout.read() if proc.stdout else ""
    assert code == 2, f"{name}: exit {code}, not 2 (a bad value)\n{out}"
    lines = [ln for ln in out.splitlines() if ln.strip()]
    assert len(lines) == 1 and f"'{name}'" in lines[0], out
    return lines[0]


def assert_refused_in_process(node_class: Callable[..., Node], name: str,
                              params: list[str]) -> None:
    """Building ``node_class`` with ``params`` (``-p`` arguments, parsed by rcl as on the
    command line) in a private Context raises the ParameterError naming ``name``, in one
    line: the error a node's process prints as its one line before it exits 2
    (``ros.runtime.run``), without the cost of starting a process per case."""
    context = Context()
    rclpy.init(context=context, args=["test", "--ros-args", *params])
    try:
        with pytest.raises(ParameterError) as err:
            node_class(context=context)
    finally:
        rclpy.try_shutdown(context=context)
    assert err.value.name == name, f"expected {name!r}, got {err.value.name!r}: {err.value}"
    message = str(err.value)
    assert f"'{name}'" in message and "\n" not in message.strip(), message


def node_parameters(node: Node, ex: Any, fqn: str, names: list[str],
                    timeout: float = 20.0) -> dict[str, Any]:
    """Values of ``names`` read from the running node ``fqn`` over GetParameters."""
    result = call_service(node, ex, GetParameters, f"{fqn}/get_parameters",
                          GetParameters.Request(names=names), timeout)
    assert result is not None
    return {n: parameter_value_to_python(v) for n, v in zip(names, result.values, strict=True)}


def set_parameter(node: Node, ex: Any, fqn: str, name: str, value: ParameterValue) -> Any:
    """The SetParametersResult of one parameter set on the running node ``fqn``.

    Asked again until answered (CI once lost a first request: DDS reported the
    service before its reply path matched); setting a value twice is setting it once.
    """
    request = SetParameters.Request(parameters=[ParameterMsg(name=name, value=value)])
    return call_service(node, ex, SetParameters, f"{fqn}/set_parameters", request).results[0]


class LifecycleManager:
    """What nav2_lifecycle_manager does to a node: ChangeState by id, GetState.

    A ChangeState is not idempotent, so it is sent once, on a client already proven
    answered by a request that changes nothing (an unknown transition label).
    """

    def __init__(self, node: Node, ex: Any, name: str) -> None:
        self._node, self._ex, self._name = node, ex, name
        self._client = node.create_client(ChangeState, f"{name}/change_state")
        assert spin_until(ex, self._client.service_is_ready, 20.0), "no change_state service"
        probe = ChangeState.Request(transition=Transition(label="no_such_transition"))
        deadline = time.monotonic() + 20.0
        while time.monotonic() < deadline:
            future = self._client.call_async(probe)
            if spin_until(ex, future.done, 2.0):
                assert not future.result().success
                return
        raise AssertionError("change_state never answered")

    def change(self, transition_id: int) -> bool:
        future = self._client.call_async(
            ChangeState.Request(transition=Transition(id=transition_id)))
        assert spin_until(self._ex, future.done, 20.0), f"transition {transition_id}: no answer"
        return bool(future.result().success)

    def state(self) -> str:
        return str(call_service(self._node, self._ex, GetState, f"{self._name}/get_state",
                                GetState.Request()).current_state.label)


# --- the peer side of an odometry node ------------------------------------------------

T0_NS = 1_700_000_000 * 10**9  # an arbitrary, realistic epoch for stamps
STEP_NS = 20_000_000  # 50 Hz


def stamp(ns: int) -> Time:
    return Time(sec=ns // 10**9, nanosec=ns % 10**9)


def ns_of(t: Time) -> int:
    return int(t.sec) * 10**9 + int(t.nanosec)


def yaw(q: Any) -> float:
    return 2.0 * math.atan2(q.z, q.w)


@dataclass
class Sink:
    """Collects what the node publishes."""

    odom: list[Odometry] = field(default_factory=list)
    tf: list[TFMessage] = field(default_factory=list)
    odom_sub: Any = None
    node: Any = None


def listen(node: Node, odom_topic: str) -> Sink:
    sink = Sink(node=node)
    sink.odom_sub = node.create_subscription(Odometry, odom_topic, sink.odom.append, 50)
    node.create_subscription(TFMessage, "/tf", sink.tf.append, 50)
    return sink


def output_if_ended(proc: Any) -> str:
    """A child's output once it has ended (what it said when it died)."""
    if proc is None or proc.poll() is None:
        return "(still running)"
    return proc.stdout.read() if proc.stdout else ""


def wait_ready(executor: Any, pub: Any, sink: Sink, proc: Any = None) -> None:
    """Wait for discovery both ways between us (``pub``, ``sink``) and the node.

    A first pose published before the node's odom publisher sees us is lost, and the
    repeats of its reading are dropped as repeats, so none would follow: our side's
    matches are not enough (see :func:`handshake`).
    """
    assert wait_matched(sink.node, executor, pub, sink.odom_sub), (
        "odometry_node and this test never matched: " + output_if_ended(proc))


def gyro_rig(node: Node, executor: Any) -> tuple[Any, Any, Sink]:
    """JointState and Imu publishers and an odom sink, matched with a use_imu node."""
    from sensor_msgs.msg import Imu

    joints = node.create_publisher(JointState, "joint_states", 50)
    imu = node.create_publisher(Imu, "imu", 50)
    sink = listen(node, "odom")
    wait_ready(executor, joints, sink)
    assert spin_until(executor, lambda: imu.get_subscription_count() > 0, 15.0)
    return joints, imu, sink


def send_first(executor: Any, pub: Any, sink: Sink, msg: JointState) -> None:
    """Send the reference reading until the node answers it.

    Discovery can report a match a moment before the first sample is deliverable;
    repeating the same stamp is harmless (the node drops repeats).
    """
    want = ns_of(msg.header.stamp)
    for _ in range(100):
        pub.publish(msg)
        if spin_until(executor,
                      lambda: any(ns_of(o.header.stamp) == want for o in sink.odom), 0.2):
            return
    raise AssertionError("the node never answered the first reading")


def drive_straight(pub: Any, ex: Any, sink: Sink, start_k: int, steps: int,
                   rad_per_step: float, prime: bool = True) -> int:
    """Readings ``start_k..start_k + steps``: both wheels at ``k * rad_per_step`` rad,
    stamped on k; the first sent until answered when ``prime``. Returns the last k."""
    for k in range(start_k, start_k + steps + 1):
        msg = JointState()
        msg.header.stamp = stamp(T0_NS + k * STEP_NS)
        msg.name = ["left_wheel_joint", "right_wheel_joint"]
        msg.position = [k * rad_per_step, k * rad_per_step]
        if k == start_k and prime:
            send_first(ex, pub, sink, msg)
        else:
            pub.publish(msg)
            spin_for(ex, 0.005)
    return start_k + steps


# --- an odometry node whose output is read as it comes (the fault tests) ----------------

NAMES = ["left_wheel_joint", "right_wheel_joint"]
R, B = 0.1, 0.4  # the geometry odometry_node() starts the node with
GEOMETRY = ["-p", f"wheel_radius:={R}", "-p", f"wheel_separation:={B}"]


class Output:
    """Lines of a child process's output, collected by a thread as they arrive."""

    def __init__(self, proc: Any) -> None:
        self.lines: list[str] = []
        self._thread = threading.Thread(target=self._read, args=(proc,), daemon=True)
        self._thread.start()

    def _read(self, proc: Any) -> None:
        for line in proc.stdout:
            self.lines.append(line.rstrip("\n"))

    def matching(self, *words: str) -> list[str]:
        return [ln for ln in self.lines if all(w in ln for w in words)]

    def wait_for(self, *words: str, timeout: float = 15.0) -> list[str]:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and not self.matching(*words):
            time.sleep(0.05)
        return self.matching(*words)

    def text(self) -> str:
        return "\n".join(self.lines)


@contextmanager
def odometry_node(*extra: str) -> Iterator[tuple[Any, Output]]:
    with node_process("odometry_node", ["--ros-args", *GEOMETRY, *extra]) as proc:
        yield proc, Output(proc)


class OdomRig(NamedTuple):
    """An odometry_node process and a peer in a private Context, matched both ways."""

    proc: subprocess.Popen[str]
    out: Output
    node: Node
    ex: SingleThreadedExecutor
    pub: Any  # JointState to the node
    sink: Sink  # what it publishes


OdomRigs = Callable[..., OdomRig]  # the odom_rig fixture (conftest.py)


@contextmanager
def odom_rig(*params: str, geometry: Sequence[str] = GEOMETRY, ns: str = "",
             joints: str = "joint_states", qos: Any = 10) -> Iterator[OdomRig]:
    """The rig of an odometry_node test (the ``odom_rig`` fixture's): the node started with
    ``geometry`` and ``params`` (``--ros-args`` arguments), a peer publishing JointState on
    ``{ns}/{joints}`` (``qos``: a depth or a profile) and listening to ``{ns}/odom`` and
    /tf, both sides matched (:func:`wait_ready`). Torn down peer first, then the node."""
    with node_process("odometry_node", ["--ros-args", *geometry, *params]) as proc, \
            ros_test_node() as (node, ex):
        out = Output(proc)
        sink = listen(node, f"{ns}/odom")
        pub = node.create_publisher(JointState, f"{ns}/{joints}", qos)
        assert wait_matched(node, ex, pub, sink.odom_sub), (
            "odometry_node and this test never matched:\n" + out.text())
        yield OdomRig(proc, out, node, ex, pub, sink)


def reading(t_ns: int, position: list[float], velocity: list[float] | None = None,
            names: list[str] | None = None) -> JointState:
    msg = JointState()
    msg.header.stamp = stamp(t_ns)
    msg.name = list(names if names is not None else NAMES)
    msg.position = position
    msg.velocity = velocity or []
    return msg


# --- a burst source and the stop deadline (the signal tests) ---------------------------

EXIT_WITHIN_S = 1.0  # a node ends this soon after SIGTERM or SIGINT
PULSE = 200  # messages back to back
QUIET_S = 0.15  # then nothing for this long


class Burst:
    """Publishes ``make(k)`` in pulses on one topic of ``topics`` at a time (``aim``),
    from a thread of its own, in a private Context.

    Only the process about to be signalled is fed: the others of its batch stay idle,
    so the exit time measured is the node's, not that of two cores shared with nine
    busy neighbours.
    """

    def __init__(self, msg_type: Any, topics: list[str], make: Callable[[int], Any]) -> None:
        self._context = Context()
        rclpy.init(context=self._context)
        self._node = Node("signal_burst", context=self._context)
        self.pubs = [self._node.create_publisher(msg_type, t, qos(100, True))
                     for t in topics]
        self._make = make
        self._target = 0
        self._stop = threading.Event()
        self.sent = 0
        self.cycle_s = QUIET_S  # how long one pulse and its quiet spell last, measured
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def aim(self, k: int) -> None:
        self._target = k

    def _run(self) -> None:
        while not self._stop.is_set():
            start = time.monotonic()
            pub = self.pubs[self._target]
            for _ in range(PULSE):
                pub.publish(self._make(self.sent))
                self.sent += 1
            self._stop.wait(QUIET_S)
            self.cycle_s = time.monotonic() - start

    def close(self) -> None:
        self._stop.set()
        self._thread.join()
        self._node.destroy_node()
        rclpy.try_shutdown(context=self._context)


@contextmanager
def burst(msg_type: Any, topics: list[str], make: Callable[[int], Any]) -> Iterator[Burst]:
    b = Burst(msg_type, topics, make)
    try:
        yield b
    finally:
        b.close()


def joint_state(k: int) -> JointState:
    """A reading stamped now, of a steady motion well under max_wheel_speed."""
    msg = JointState()
    ns = time.time_ns()
    msg.header.stamp = ns_to_stamp(ns, msg.header.stamp)
    msg.name = ["left_wheel_joint", "right_wheel_joint"]
    t = ns * 1e-9 % 1000.0
    msg.position = [2.0 * t, 3.0 * t]
    return msg
