"""odometry_node with ``open_loop: true`` over real DDS: fed velocity commands, odometry checked.

The node runs as its own process; a peer publishes Twist on ``cmd_vel`` and listens to
``odom``, ``/tf`` and ``/diagnostics``. A constant command (v, w) is a circle of radius
v / w through the origin: every published pose must lie on it whatever the arrival times
(closed form, independent of the transport's jitter); how far along it the robot got
depends on when the commands arrived and stopped (the node's clock). The poses' stamps
are that clock: a command that changes the twist arrived after the last pose without it
and by the first with it, so the closed form is checked on the node's own times, whatever
delays the transport or a loaded CI adds (one test still bounds by the sender's clock).
"""

from __future__ import annotations

import itertools
import math
import time
from pathlib import Path

import pytest
from geometry_msgs.msg import Twist, TwistStamped
from lifecycle_msgs.msg import Transition
from nav_msgs.msg import Odometry
from sensor_msgs.msg import JointState
from tf2_msgs.msg import TFMessage

import oracle
from diagutil import Peer, diagnosed
from rosutil import (
    DATA,
    LifecycleManager,
    call_service,
    handshake,
    node_parameters,
    node_process,
    ns_of,
    ros_test_node,
    spin_for,
    spin_until,
    yaw,
)

pytestmark = [pytest.mark.dds, pytest.mark.process]

GEOMETRY = ["-p", "wheel_radius:=0.05", "-p", "wheel_separation:=0.3"]
OPEN_LOOP = [*GEOMETRY, "-p", "open_loop:=true", "-p", "publish_rate:=40.0"]
V, W = 0.2, 0.5  # m/s, rad/s: a circle of radius 0.4 m
OK = 0
DELAY = 0.05  # s: the transport's delay on a loaded two-core machine, with margin
# [s] cmd_vel_timeout where a test follows the node's hold law on its stamps: longer than
# a stall of the node on a loaded CI (up to 0.5 s), during which a command held since
# before the stall would expire, rightly, on the node's clock.
HOLD = 1.0


def twist(v: float, w: float) -> Twist:
    msg = Twist()
    msg.linear.x, msg.angular.z = v, w
    return msg


def drive(peer: Peer, pub: object, seconds: float, rate: float = 20.0) -> None:
    """Publish (V, W) at ``rate`` for ``seconds``."""
    msg = twist(V, W)
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        pub.publish(msg)  # type: ignore[attr-defined]
        spin_for(peer.executor, 1.0 / rate)


def on_circle(o: Odometry, radius: float) -> float:
    """Distance of a pose from the circle through the origin, centre (0, radius)."""
    p = o.pose.pose.position
    return abs(math.hypot(p.x, p.y - radius) - radius)


def test_commands_are_integrated_on_the_commanded_circle_and_stop_at_the_timeout() -> None:
    odom: list[Odometry] = []
    tf: list[TFMessage] = []
    with diagnosed("odometry_node", [*OPEN_LOOP, "-p", f"cmd_vel_timeout:={HOLD}"]) as peer:
        node = peer.node
        node.create_subscription(Odometry, "odom", odom.append, 100)
        node.create_subscription(TFMessage, "/tf", tf.append, 100)
        pub = node.create_publisher(Twist, "cmd_vel", 10)
        assert spin_until(peer.executor, lambda: pub.get_subscription_count() > 0
                          and len(odom) > 3, 20.0)
        handshake(node, peer.executor, "/odometry_node")  # it hears us: no command lost
        assert node.count_subscribers("/joint_states") == 0  # a fixed switch, no fallback
        at_rest = peer.wait_for(lambda s: s.values.get("commands") == "0", 10.0)
        sent_ns = time.time_ns()
        drive(peer, pub, 2.0)
        # The last command: twice as fast on the same circle, so the pose that first
        # follows it shows when it arrived, on the node's clock.
        last_sent_ns = time.time_ns()
        pub.publish(twist(2 * V, 2 * W))

        def poses_at_rest() -> int:
            moved = [i for i, o in enumerate(odom) if o.twist.twist.linear.x != 0.0]
            return len(odom) - 1 - moved[-1] if moved else 0

        # Past the timeout: at rest, the pose still published (TF stays fresh).
        assert spin_until(peer.executor, lambda: poses_at_rest() > 20, 10.0)
        after = peer.wait_for(lambda s: s.values.get("commanding") == "false"
                              and s.values.get("commands") != "0", 10.0)
    assert at_rest.level == OK and at_rest.message.startswith("open loop")
    assert "waiting for the first command" in at_rest.message
    assert after.level == OK and after.message.startswith("open loop"), after.message
    assert "no command for cmd_vel_timeout" in after.message
    assert after.values["mode"] == "open loop"
    radius = V / W
    assert max(on_circle(o, radius) for o in odom) < 1e-9
    # The commands in force, in order: none, (V, W), (2V, 2W), none after the timeout.
    twists = [(o.twist.twist.linear.x, o.twist.twist.angular.z) for o in odom]
    first = twists.index((V, W))
    second = twists.index((2 * V, 2 * W))
    stop = twists.index((0.0, 0.0), second)
    assert set(twists[:first]) == {(0.0, 0.0)} and set(twists[first:second]) == {(V, W)}
    assert set(twists[second:stop]) == {(2 * V, 2 * W)} and set(twists[stop:]) == {(0.0, 0.0)}
    # Times [s] on the node's clock (its stamps), from the first pose; our sends on the
    # same (system) clock. The pose is the closed-form arc of each command held from its
    # arrival: the first arrived after the pose before ``first`` and by ``first``, where
    # the heading, growing at W from it, puts it; the last likewise at ``second``.
    ref = ns_of(odom[0].header.stamp)
    t = [(ns_of(o.header.stamp) - ref) * 1e-9 for o in odom]
    a1 = t[first] - yaw(odom[first].pose.pose.orientation) / W
    a2 = 2 * t[second] - a1 - yaw(odom[second].pose.pose.orientation) / W
    assert t[first - 1] <= a1 <= t[first] + 1e-9 and a1 >= (sent_ns - ref) * 1e-9
    assert t[second - 1] <= a2 <= t[second] + 1e-9 and a2 >= (last_sent_ns - ref) * 1e-9
    end_at = a2 + HOLD  # the last command is followed for cmd_vel_timeout, then zero
    print(f"open loop: commands arrived {(a1 - (sent_ns - ref) * 1e-9) * 1e3:.1f} ms and "
          f"{(a2 - (last_sent_ns - ref) * 1e-9) * 1e3:.1f} ms after they were sent; at rest "
          f"from the pose {(t[stop] - end_at) * 1e3:.1f} ms past the timeout")
    assert t[stop - 1] <= end_at + 1e-9 < t[stop]
    middle = oracle.arc(V * (a2 - a1), W * (a2 - a1))
    for o, ti in zip(odom, t, strict=True):
        if ti <= a1:
            want = oracle.ORIGIN
        elif ti <= a2:
            want = oracle.arc(V * (ti - a1), W * (ti - a1))
        else:
            held = min(ti, end_at) - a2
            want = oracle.arc(2 * V * held, 2 * W * held, middle)
        p = o.pose.pose
        assert math.hypot(p.position.x - want[0], p.position.y - want[1]) < 1e-9, (ti, p)
        assert abs(math.remainder(yaw(p.orientation) - want[2], math.tau)) < 1e-9, (ti, p)
    end = odom[-1]
    # At rest after the timeout: zero twist, the pose still published (TF stays fresh).
    assert end.twist.twist.linear.x == 0.0 and end.twist.twist.angular.z == 0.0
    # A command is not a measurement: the heading's variance grows fast with the turn.
    assert end.pose.covariance[35] > 0.01
    assert odom[stop - 1].twist.covariance[0] > 0.0
    assert (end.header.frame_id, end.child_frame_id) == ("odom", "base_link")
    assert tf and tf[-1].transforms[0].child_frame_id == "base_link"


def test_the_shipped_ddc_yaml_with_open_loop_true(tmp_path: Path) -> None:
    """diff_drive_controller's file with ``open_loop: true``: no longer ignored, and its
    ``cmd_vel_timeout`` (0.8 s) is the one the odometry holds a command for."""
    text = (DATA / "diffbot_controllers.yaml").read_text(encoding="utf-8")
    assert "open_loop: false" in text
    path = tmp_path / "diffbot_open_loop.yaml"
    path.write_text(text.replace("open_loop: false", "open_loop: true"), encoding="utf-8")
    # covariance_model static: the file's diagonals, as diff_drive_controller publishes them.
    args = ["--params-file", str(path), "-r", "__node:=diffbot_base_controller",
            "-p", "covariance_model:=static"]
    odom: list[Odometry] = []
    with diagnosed("odometry_node", args) as peer:
        node = peer.node
        got = node_parameters(node, peer.executor, "/diffbot_base_controller",
                              ["open_loop", "cmd_vel_timeout", "publish_rate"])
        assert got == {"open_loop": True, "cmd_vel_timeout": 0.8, "publish_rate": 25.0}
        node.create_subscription(Odometry, "/odom", odom.append, 100)
        pub = node.create_publisher(Twist, "/cmd_vel", 10)
        js = node.create_publisher(JointState, "/joint_states", 10)
        assert spin_until(peer.executor, lambda: pub.get_subscription_count() > 0
                          and bool(odom), 20.0)
        # It hears us: else its reader may match our writer after the one command went
        # (a loaded run: no "commands 1" within 10 s).
        handshake(node, peer.executor, "/diffbot_base_controller")
        msg = twist(0.3, 0.0)
        start = time.monotonic()
        pub.publish(msg)  # one command, then silence: 0.8 s of 0.3 m/s
        while time.monotonic() - start < 2.0:
            js.publish(JointState(name=["wheel_l_joint", "wheel_r_joint"],
                                  position=[5.0, 9.0]))  # ignored: open loop
            spin_for(peer.executor, 0.05)
        status = peer.wait_for(lambda s: s.values.get("commands") == "1", 10.0)
    end = odom[-1]
    assert status.message.startswith("open loop")
    assert (end.header.frame_id, end.child_frame_id) == ("odom", "base_footprint")
    assert end.pose.pose.position.x == pytest.approx(0.3 * 0.8, abs=0.3 * DELAY)
    assert abs(end.pose.pose.position.y) < 1e-12
    assert list(end.pose.covariance[::7]) == [0.002] * 5 + [0.02]
    assert list(end.twist.covariance[::7]) == [0.003] * 5 + [0.03]


def test_from_the_cmd_vel_nodes_limited_output() -> None:
    """``open_loop_source: cmd_vel_out``: what cmd_vel_node really asked the wheels for
    (ramped at linear.x.max_acceleration), not the raw command.

    The odometry holds each cmd_vel_out until the next (cmd_vel_timeout 0: never
    expires), as the distance's bound below counts it. With a hold of 1 s it failed
    beside loaded runs (2 of 55 here, x 0.20-0.21 m under the bound): both nodes stood
    still for 1.5 s at 0.4 m/s (no cmd_vel_out stamped for 1.50 s from 4.79 s into the
    run, and cmd_vel_node's ramp down resumed one step below 0.4, so it had not ticked;
    no pose heard for 1.61 s), so the odometry's held command expired after 1 s, as its
    hold law says (the first test here judges that law), while the bound held it until
    the next change."""
    limits = [*GEOMETRY, "-p", "publish_limited_velocity:=true",
              "-p", "linear.x.max_acceleration:=0.5", "-p", f"cmd_vel_timeout:={HOLD}"]
    odom: list[Odometry] = []
    limited: list[tuple[int, float]] = []  # (stamp [ns], linear.x) of each cmd_vel_out
    args = [*OPEN_LOOP, "-p", "open_loop_source:=cmd_vel_out", "-p", "cmd_vel_timeout:=0.0"]
    with node_process("cmd_vel_node", ["--ros-args", *limits]) as base, \
            diagnosed("odometry_node", args) as peer:
        node = peer.node
        node.create_subscription(Odometry, "odom", odom.append, 100)
        node.create_subscription(
            TwistStamped, "cmd_vel_out",
            lambda m: limited.append((ns_of(m.header.stamp), m.twist.linear.x)), 100)
        pub = node.create_publisher(Twist, "cmd_vel", 10)
        assert spin_until(peer.executor, lambda: pub.get_subscription_count() > 0
                          and bool(odom) and bool(limited), 20.0)
        status = peer.wait_for(lambda s: "/cmd_vel_out" in s.message, 10.0)
        msg = twist(0.4, 0.0)

        def at_full_speed() -> bool:
            pub.publish(msg)
            spin_for(peer.executor, 0.05)
            return any(o.twist.twist.linear.x == 0.4 for o in odom)

        # Commanded (at 10-20 Hz) until the odometry follows the ramp's top, then not.
        assert spin_until(peer.executor, at_full_speed, 10.0)
        # Until cmd_vel_node's timeout and ramp down have reached the odometry and us.
        assert spin_until(peer.executor, lambda: odom[-1].twist.twist.linear.x == 0.0
                          and any(o.twist.twist.linear.x > 0.0 for o in odom)
                          and limited[-1][1] == 0.0, 10.0)
        assert base.poll() is None
    assert status.message.startswith("open loop")
    speeds = [o.twist.twist.linear.x for o in odom]
    assert max(speeds) == pytest.approx(0.4, abs=1e-12)
    ramp = [v for v in speeds if 0.0 < v < 0.4]
    assert len(ramp) > 10  # 0.8 s of acceleration at 40 Hz: the limited twist, not 0.4 at once
    # The distance is the integral of the limited twist, each held from its arrival at the
    # odometry to the next's: sum of v_j (a_(j+1) - a_j) = -sum of a_j (v_j - v_(j-1)) from
    # rest to rest, so only the arrivals of the changes count. Each lies after its stamp
    # and after the last pose that did not show it, and by the first pose that did (or a
    # later change: a change lost on the way counts as arriving with the next one).
    assert limited[0][1] == 0.0 and limited[-1][1] == 0.0
    changes = [(0, 0.0)] + [(ts, v) for (_, u), (ts, v) in itertools.pairwise(limited)
                            if v != u]
    ref = ns_of(odom[0].header.stamp)
    shown = []  # the latest change each pose shows, in order
    j = 0
    for k, o in enumerate(odom):
        while changes[j][1] != o.twist.twist.linear.x:
            j += 1
            assert j < len(changes), (
                f"pose {k} shows {o.twist.twist.linear.x} m/s: no later cmd_vel_out says so")
        shown.append(j)
    low = high = 0.0
    for j in range(1, len(changes)):
        after = [ns_of(o.header.stamp) for o, c in zip(odom, shown, strict=True) if c < j]
        by = [ns_of(o.header.stamp) for o, c in zip(odom, shown, strict=True) if c >= j]
        window = ((max([changes[j][0], *after[-1:]]) - ref) * 1e-9, (by[0] - ref) * 1e-9)
        dv = changes[j][1] - changes[j - 1][1]
        low += min(-dv * a for a in window)
        high += max(-dv * a for a in window)
    x = odom[-1].pose.pose.position.x
    print(f"open loop from cmd_vel_out: {x:.4f} m, arrivals bound it to "
          f"[{low:.4f}, {high:.4f}] m over {len(changes) - 1} changes")
    # The evidence, should it fail: the longest silences of each stream as heard here.
    gaps = {name: max((b - a) * 1e-9 for a, b in itertools.pairwise(stamps)) for name, stamps
            in (("odom", [ns_of(o.header.stamp) for o in odom]),
                ("cmd_vel_out", [ts for ts, _ in limited]))}
    assert low - 1e-9 <= x <= high + 1e-9, gaps
    assert odom[-1].twist.twist.linear.x == 0.0


def test_the_managed_node_runs_open_loop_while_active() -> None:
    """odometry_lifecycle_node takes open_loop too: nothing before activate, then the
    commanded straight line (commands while inactive are integrated, as readings are)."""

    odom: list[Odometry] = []
    args = ["--ros-args", *OPEN_LOOP, "-p", "cmd_vel_timeout:=0.0"]
    with node_process("odometry_lifecycle_node", args) as proc, \
            ros_test_node() as (node, ex):
        node.create_subscription(Odometry, "/odom", odom.append, 100)
        pub = node.create_publisher(Twist, "/cmd_vel", 10)
        manager = LifecycleManager(node, ex, "/odometry_lifecycle_node")
        assert manager.change(Transition.TRANSITION_CONFIGURE)
        assert spin_until(ex, lambda: pub.get_subscription_count() > 0, 20.0)
        handshake(node, ex, "/odometry_lifecycle_node")  # it hears us: the command arrives
        msg = twist(0.2, 0.0)
        sent_ns = time.time_ns()
        pub.publish(msg)  # inactive: integrated, not published (held: no timeout)
        spin_for(ex, 1.0)
        assert not odom
        activate_ns = time.time_ns()
        assert manager.change(Transition.TRANSITION_ACTIVATE)
        assert spin_until(ex, lambda: len(odom) > 10, 20.0)
        assert proc.poll() is None
    assert all(o.pose.pose.position.y == 0.0 for o in odom)
    assert all(o.twist.twist.linear.x == 0.2 for o in odom)
    # Each pose is 0.2 m/s held since one arrival (on the node's clock, its stamps) ...
    t = [(ns_of(o.header.stamp) - sent_ns) * 1e-9 for o in odom]
    arrival = t[0] - odom[0].pose.pose.position.x / 0.2
    for o, ti in zip(odom, t, strict=True):
        assert o.pose.pose.position.x == pytest.approx(0.2 * (ti - arrival), abs=1e-9)
    # ... after we sent it, and before we asked to activate: the command sent while
    # inactive moved it already.
    print(f"managed open loop: the command arrived {arrival * 1e3:.1f} ms after it was "
          f"sent, {(activate_ns - sent_ns) * 1e-6 - arrival * 1e3:.0f} ms before activate")
    assert 0.0 <= arrival < (activate_ns - sent_ns) * 1e-9


def test_commands_of_the_other_type_are_named() -> None:
    """A TwistStamped sender while the node takes Twist: nothing can arrive, and it says so."""
    with node_process("odometry_node", ["--ros-args", *OPEN_LOOP]) as proc, \
            ros_test_node() as (node, ex):
        pub = node.create_publisher(TwistStamped, "/cmd_vel", 10)
        odom: list[Odometry] = []
        node.create_subscription(Odometry, "/odom", odom.append, 10)
        assert spin_until(ex, lambda: bool(odom), 20.0)
        for _ in range(40):
            pub.publish(TwistStamped())
            spin_for(ex, 0.1)
        assert proc.poll() is None
    out = proc.stdout.read() if proc.stdout else ""
    assert ("/cmd_vel has a publisher of type geometry_msgs/msg/TwistStamped but this node "
            "expects geometry_msgs/msg/Twist: set enable_stamped_cmd_vel to true") in out, out
    assert "open loop: odometry from the commanded velocity on /cmd_vel (Twist)" in out


def test_on_simulated_time_the_pose_is_the_closed_form() -> None:
    """use_sim_time: the test owns /clock, so each command's arrival time is known exactly
    and the published poses are the commanded arcs to rounding, over DDS."""
    from rosgraph_msgs.msg import Clock

    from rosutil import stamp

    odom: list[Odometry] = []
    args = [*OPEN_LOOP, "-p", "use_sim_time:=true", "-p", "cmd_vel_timeout:=0.5"]
    with diagnosed("odometry_node", args) as peer:
        node, ex = peer.node, peer.executor
        clock = node.create_publisher(Clock, "/clock", 10)
        node.create_subscription(Odometry, "/odom", odom.append, 100)
        pub = node.create_publisher(Twist, "/cmd_vel", 10)
        t0 = 100 * 10**9

        def tick(t_ns: int) -> None:
            """The clock at ``t_ns`` until the node has published a pose stamped so: it
            has the time and its timer ran at it, before anything else is sent."""
            for _ in range(100):
                clock.publish(Clock(clock=stamp(t_ns)))
                if spin_until(ex, lambda: any(ns_of(o.header.stamp) == t_ns for o in odom),
                              0.3):
                    return
            raise AssertionError(f"no pose stamped {t_ns} ns on simulated time")

        assert spin_until(ex, lambda: clock.get_subscription_count() > 0
                          and pub.get_subscription_count() > 0, 20.0)
        handshake(node, ex, "/odometry_node")  # it hears us: the command arrives
        tick(t0)
        msg = twist(V, W)
        pub.publish(msg)  # arrives at t0 on the node's clock (paused there)
        # Held until the node reports it taken (wall-clock diagnostics), then time goes on.
        peer.wait_for(lambda s: s.values.get("commands") == "1", 10.0)
        tick(t0 + 300_000_000)  # the command is followed ...
        tick(t0 + 2 * 10**9)  # ... until its timeout at t0 + 0.5 s, then at rest
        tick(t0 + 2 * 10**9 + 100_000_000)
    stamps = {o.header.stamp.sec * 10**9 + o.header.stamp.nanosec: o for o in odom}
    for t_ns, held in ((t0 + 300_000_000, 0.3), (t0 + 2 * 10**9, 0.5)):
        o = stamps[t_ns]
        x, y, th = oracle.arc(V * held, W * held)
        p = o.pose.pose
        assert abs(p.position.x - x) < 1e-12 and abs(p.position.y - y) < 1e-12, (t_ns, p)
        assert abs(math.remainder(yaw(p.orientation) - th, math.tau)) < 1e-12
    assert stamps[t0 + 300_000_000].twist.twist.linear.x == V
    assert stamps[t0 + 2 * 10**9].twist.twist.linear.x == 0.0


def test_set_pose_and_reset_in_open_loop() -> None:
    """~/set_pose works in open loop as with encoders: stamped zero, the pose now; then
    ~/reset_odometry puts it back at the origin."""
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from std_srvs.srv import Trigger

    odom: list[Odometry] = []
    with node_process("odometry_node", ["--ros-args", *OPEN_LOOP]) as proc, \
            ros_test_node() as (node, ex):
        node.create_subscription(Odometry, "/odom", odom.append, 100)
        pub = node.create_publisher(PoseWithCovarianceStamped, "/odometry_node/set_pose", 10)
        assert spin_until(ex, lambda: pub.get_subscription_count() > 0 and bool(odom), 20.0)
        handshake(node, ex, "/odometry_node")  # it hears us: the one set_pose arrives
        msg = PoseWithCovarianceStamped()
        msg.header.frame_id = "odom"
        msg.pose.pose.position.x, msg.pose.pose.position.y = 1.5, -2.0
        msg.pose.pose.orientation.w = 1.0
        msg.pose.covariance[0] = msg.pose.covariance[7] = msg.pose.covariance[35] = 0.04
        pub.publish(msg)
        assert spin_until(ex, lambda: odom[-1].pose.pose.position.x == 1.5, 10.0)
        last = odom[-1]
        answer = call_service(node, ex, Trigger, "/odometry_node/reset_odometry",
                              Trigger.Request())
        assert answer.success and answer.message == "odometry reset to the origin"
        assert spin_until(ex, lambda: odom[-1].pose.pose.position.x == 0.0, 10.0)
        assert proc.poll() is None
    assert (last.pose.pose.position.x, last.pose.pose.position.y) == (1.5, -2.0)
    assert last.pose.covariance[0] == pytest.approx(0.04, rel=1e-6)
    reset = odom[-1].pose.pose
    assert (reset.position.x, reset.position.y, yaw(reset.orientation)) == (0.0, 0.0, 0.0)
