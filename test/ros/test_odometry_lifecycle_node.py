"""``odometry_lifecycle_node`` over real DDS, driven through lifecycle_msgs as a manager does.

The node runs as its own process; a private-Context peer asks ChangeState and GetState
and drives the wheels straight, so every pose published has the closed form
x = r * wheel angle (y = 0, yaw = 0).
"""

from __future__ import annotations

import math
import signal
import time
from typing import Any

import pytest
from diagnostic_msgs.msg import DiagnosticArray
from lifecycle_msgs.msg import Transition
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters
from rclpy.node import Node
from sensor_msgs.msg import JointState

from rosutil import (
    EXIT_WITHIN_S,
    STEP_NS,
    T0_NS,
    LifecycleManager,
    Sink,
    burst,
    call_service,
    drive_straight,
    joint_state,
    listen,
    node_process,
    ns_of,
    ros_test_node,
    spin_for,
    spin_until,
    wait_ready,
)

pytestmark = [pytest.mark.dds, pytest.mark.process]

NAME = "/odometry_lifecycle_node"
R, B = 0.1, 0.4
PER_STEP = 0.5  # rad of both wheels per reading: 5 cm straight ahead
GEOMETRY = ["-p", f"wheel_radius:={R}", "-p", f"wheel_separation:={B}"]


def step(o: Any) -> int:
    k, rest = divmod(ns_of(o.header.stamp) - T0_NS, STEP_NS)
    assert rest == 0
    return k


def wait_for_step(ex: Any, sink: Sink, k: int) -> None:
    assert spin_until(ex, lambda: any(step(o) == k for o in sink.odom), 10.0), \
        f"no odom for reading {k} ({len(sink.odom)} received)"


def assert_closed_form(sink: Sink, origin_k: int = 0) -> None:
    """Every pose and /tf at x = r * (angle since the reading ``origin_k``): no jump."""
    assert sink.odom
    for o in sink.odom:
        x = R * (step(o) - origin_k) * PER_STEP
        p = o.pose.pose
        assert math.isclose(p.position.x, x, abs_tol=1e-9), (step(o), p.position.x, x)
        assert p.position.y == 0.0 and p.orientation.z == 0.0
    tfs = [t for m in sink.tf for t in m.transforms if t.child_frame_id == "base_link"]
    assert tfs
    for t in tfs:
        k = (ns_of(t.header.stamp) - T0_NS) // STEP_NS
        assert math.isclose(t.transform.translation.x, R * (k - origin_k) * PER_STEP,
                            abs_tol=1e-9)


def ours(diagnostics: list[DiagnosticArray]) -> list[DiagnosticArray]:
    name = "odometry_lifecycle_node: odometry"
    return [d for d in diagnostics if any(s.name == name for s in d.status)]


def test_publishes_only_while_active_and_the_pose_never_jumps() -> None:
    """unconfigured -> inactive -> active -> inactive -> active -> cleanup -> again -> shutdown.

    Readings sent while inactive are integrated: the first pose after each activation
    is already r * (total angle), as REP 105 asks of odom.
    """
    with node_process("odometry_lifecycle_node", ["--ros-args", *GEOMETRY]) as proc, \
            ros_test_node() as (node, ex):
        sink = listen(node, "/odom")
        diagnostics: list[DiagnosticArray] = []
        node.create_subscription(DiagnosticArray, "/diagnostics", diagnostics.append, 10)
        pub = node.create_publisher(JointState, "/joint_states", 10)
        manager = LifecycleManager(node, ex, NAME)

        # unconfigured: no subscription, no publisher (the node's services are up).
        assert manager.state() == "unconfigured"
        spin_for(ex, 1.0)
        assert pub.get_subscription_count() == 0
        assert sink.odom_sub.get_publisher_count() == 0

        assert manager.change(Transition.TRANSITION_CONFIGURE)
        assert manager.state() == "inactive"
        wait_ready(ex, pub, sink, proc)

        # inactive: readings 0..20 integrated (1 m), nothing published.
        drive_straight(pub, ex, sink, 0, 20, PER_STEP, prime=False)
        spin_for(ex, 1.5)  # more than a diagnostics period
        assert not sink.odom and not sink.tf and not ours(diagnostics)

        assert manager.change(Transition.TRANSITION_ACTIVATE)
        assert manager.state() == "active"
        drive_straight(pub, ex, sink, 21, 19, PER_STEP, prime=True)
        wait_for_step(ex, sink, 40)
        assert min(step(o) for o in sink.odom) == 21  # the first after activation...
        assert_closed_form(sink)  # ...already at r * 21 * PER_STEP: continuous
        assert spin_until(ex, lambda: ours(diagnostics), 5.0), "no /diagnostics while active"

        assert manager.change(Transition.TRANSITION_DEACTIVATE)
        assert manager.state() == "inactive"
        spin_for(ex, 0.3)  # what was in flight before the deactivation
        sink.odom.clear()
        sink.tf.clear()
        diagnostics.clear()
        drive_straight(pub, ex, sink, 41, 19, PER_STEP, prime=False)
        spin_for(ex, 1.5)
        assert not sink.odom and not sink.tf and not ours(diagnostics)

        assert manager.change(Transition.TRANSITION_ACTIVATE)
        drive_straight(pub, ex, sink, 61, 19, PER_STEP, prime=True)
        wait_for_step(ex, sink, 80)
        assert min(step(o) for o in sink.odom) == 61
        assert_closed_form(sink)

        # cleanup: endpoints gone, pose forgotten; configured again, it starts at 0.
        assert manager.change(Transition.TRANSITION_DEACTIVATE)
        assert manager.change(Transition.TRANSITION_CLEANUP)
        assert manager.state() == "unconfigured"
        assert spin_until(ex, lambda: pub.get_subscription_count() == 0
                          and sink.odom_sub.get_publisher_count() == 0, 10.0)
        assert manager.change(Transition.TRANSITION_CONFIGURE)
        assert manager.change(Transition.TRANSITION_ACTIVATE)
        wait_ready(ex, pub, sink, proc)
        sink.odom.clear()
        sink.tf.clear()
        drive_straight(pub, ex, sink, 100, 10, PER_STEP, prime=True)
        wait_for_step(ex, sink, 110)
        assert_closed_form(sink, origin_k=100)

        assert manager.change(Transition.TRANSITION_ACTIVE_SHUTDOWN)
        assert manager.state() == "finalized"
        assert spin_until(ex, lambda: sink.odom_sub.get_publisher_count() == 0, 10.0)
        assert proc.poll() is None


def _set_radius(node: Node, ex: Any, value: float) -> Any:
    request = SetParameters.Request(parameters=[ParameterMsg(
        name="wheel_radius",
        value=ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=value))])
    return call_service(node, ex, SetParameters, f"{NAME}/set_parameters",
                        request).results[0]


def test_bad_parameter_fails_configure_and_can_be_fixed() -> None:
    """A bad value: configure FAILS with one line naming it; set_parameters; configure again."""
    args = ["--ros-args", "-p", "wheel_radius:=-0.1", "-p", f"wheel_separation:={B}"]
    with node_process("odometry_lifecycle_node", args) as proc, ros_test_node() as (node, ex):
        manager = LifecycleManager(node, ex, NAME)
        assert not manager.change(Transition.TRANSITION_CONFIGURE)
        assert manager.state() == "unconfigured"
        assert proc.poll() is None
        assert not manager.change(Transition.TRANSITION_ACTIVATE)  # not from unconfigured
        assert _set_radius(node, ex, R).successful  # unconfigured: taken, checked at configure
        assert manager.change(Transition.TRANSITION_CONFIGURE)
        assert manager.state() == "inactive"
        # Configured: the runtime check of odometry_node applies.
        refused = _set_radius(node, ex, -1.0)
        assert not refused.successful and "wheel_radius" in refused.reason
        assert proc.poll() is None
    out = proc.stdout.read() if proc.stdout else ""
    failed = [ln for ln in out.splitlines() if "configure failed" in ln]
    assert len(failed) == 1 and "'wheel_radius'" in failed[0], out
    assert "Traceback" not in out


@pytest.mark.serial
def test_sigterm_in_the_active_state_exits_0_within_a_second() -> None:
    """While a burst of readings is integrated and published."""
    topic = "/lifecycle_signal/joint_states"
    args = ["--ros-args", *GEOMETRY, "-r", f"joint_states:={topic}",
            "-r", "odom:=/lifecycle_signal/odom"]
    with burst(JointState, [topic], joint_state) as source, \
            node_process("odometry_lifecycle_node", args) as proc, \
            ros_test_node() as (node, ex):
        manager = LifecycleManager(node, ex, NAME)
        assert manager.change(Transition.TRANSITION_CONFIGURE)
        assert manager.change(Transition.TRANSITION_ACTIVATE)
        odom: list[Odometry] = []
        node.create_subscription(Odometry, "/lifecycle_signal/odom", odom.append, 10)
        assert spin_until(ex, lambda: len(odom) > 10, 20.0), "not publishing"
        sent = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        try:
            code = proc.wait(timeout=3 * EXIT_WITHIN_S)
        finally:
            took = time.monotonic() - sent
        assert source.sent > 0
    out = proc.stdout.read() if proc.stdout else ""
    assert code == 0 and took < EXIT_WITHIN_S, (code, took, out[-2000:])
    assert "Traceback" not in out
