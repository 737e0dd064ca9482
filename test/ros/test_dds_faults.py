"""Driver faults against the real odometry_node process over DDS: restarts, bursts,
stalls, a fleet and garbage, each checked against the closed form of the motion.

The node runs as its own process (test_faults' helpers); expected poses come from
the motion sent: straight drives and arcs of constant curvature, whose pose is the
single-arc closed form however the readings are grouped (Furlan et al.).
"""

from __future__ import annotations

import math
import random
import time
from contextlib import ExitStack
from typing import Any

import pytest
from nav_msgs.msg import Odometry
from sensor_msgs.msg import JointState

import oracle
from diagutil import diagnosed
from rosutil import (
    STEP_NS,
    T0_NS,
    B,
    OdomRigs,
    R,
    Sink,
    listen,
    ns_of,
    odometry_node,
    reading,
    ros_test_node,
    send_first,
    spin_for,
    spin_until,
    wait_matched,
    wait_ready,
    yaw,
)

pytestmark = [pytest.mark.dds, pytest.mark.process]

OK, WARN, ERROR = 0, 1, 2


def drive(ex: Any, pub: Any, t0_ns: int, start: tuple[float, float],
          rate: tuple[float, float], steps: int, step_ns: int = STEP_NS) -> int:
    """Readings k = 1..steps after ``t0_ns``: positions start + rate x k; returns the
    last stamp."""
    for k in range(1, steps + 1):
        pub.publish(reading(t0_ns + k * step_ns,
                            [start[0] + rate[0] * k, start[1] + rate[1] * k]))
        spin_for(ex, 0.004)
    return t0_ns + steps * step_ns


def pose_at(ex: Any, sink: Sink, t_ns: int, timeout: float = 10.0) -> Odometry:
    """The odometry the node published for the reading stamped ``t_ns``."""
    assert spin_until(ex, lambda: any(ns_of(o.header.stamp) == t_ns for o in sink.odom),
                      timeout), f"no odometry for stamp {t_ns}"
    return [o for o in sink.odom if ns_of(o.header.stamp) == t_ns][-1]


def assert_pose(o: Odometry, x: float, y: float, theta: float, tol: float = 1e-9) -> None:
    p = o.pose.pose
    got = (p.position.x, p.position.y, yaw(p.orientation))
    assert math.isclose(got[0], x, abs_tol=tol), (got, (x, y, theta))
    assert math.isclose(got[1], y, abs_tol=tol), (got, (x, y, theta))
    assert math.isclose(math.remainder(got[2] - theta, math.tau), 0.0, abs_tol=tol), \
        (got, (x, y, theta))


def then(pose: tuple[float, float, float], s_left: float, s_right: float
         ) -> tuple[float, float, float]:
    """``pose`` followed by one constant-curvature arc of wheel arcs s_left, s_right."""
    return oracle.wheel_arc(s_left, s_right, B, pose)


def restart_run(odom_rig: OdomRigs, max_reading_gap: float, pause_s: float
                ) -> tuple[Odometry, Odometry]:
    """An arc, the driver away for ``pause_s`` while the wheels turn on, the counters
    carrying on; returns the odometry before the pause and at the end."""
    rate = (0.2, 0.3)  # rad per 20 ms reading: 10 and 15 rad/s
    proc, _, _, ex, pub, sink = odom_rig("-p", f"max_reading_gap:={max_reading_gap}")
    send_first(ex, pub, sink, reading(T0_NS, [0.0, 0.0]))
    before_ns = drive(ex, pub, T0_NS, (0.0, 0.0), rate, 50)
    before = pose_at(ex, sink, before_ns)
    spin_for(ex, pause_s)  # the driver is down; the encoders keep counting
    pause_steps = round(pause_s * 1e9 / STEP_NS)
    back_ns = before_ns + pause_steps * STEP_NS
    at_back = (rate[0] * (50 + pause_steps), rate[1] * (50 + pause_steps))
    pub.publish(reading(back_ns, list(at_back)))
    last_ns = drive(ex, pub, back_ns, at_back, rate, 25)
    final = pose_at(ex, sink, last_ns)
    assert proc.poll() is None
    return before, final


def test_driver_restart_within_max_reading_gap_integrates_the_motion_meanwhile(
        odom_rig: OdomRigs) -> None:
    """Counters carry on after 2 s of silence, max_reading_gap 3 s: the step over the
    silence is a real, known motion and is integrated: one arc of 50 + 100 + 25 readings."""
    before, final = restart_run(odom_rig, 3.0, 2.0)
    assert_pose(before, *oracle.wheel_arc(R * 0.2 * 50, R * 0.3 * 50, B))
    assert_pose(final, *oracle.wheel_arc(R * 0.2 * 175, R * 0.3 * 175, B))


def test_driver_restart_after_max_reading_gap_integrates_counts_that_went_on(
        odom_rig: OdomRigs) -> None:
    """The same, max_reading_gap 1 s: the counts went on over the 2 s at the speeds the
    wheels showed before and after (issue 37), so the silence's motion is integrated as
    one arc and named: the same arc of 175 readings as within max_reading_gap."""
    before, final = restart_run(odom_rig, 1.0, 2.0)
    assert_pose(before, *oracle.wheel_arc(R * 0.2 * 50, R * 0.3 * 50, B))
    assert_pose(final, *oracle.wheel_arc(R * 0.2 * 175, R * 0.3 * 175, B))


def test_counter_reset_after_a_short_pause_is_skipped_by_max_wheel_speed(
        odom_rig: OdomRigs) -> None:
    """Counters 0 -> 20 rad in 1 s, 0.5 s pause (within max_reading_gap), then counting
    from 0 again. Only max_wheel_speed can tell that reset from motion: at the wheels'
    real top speed (25 rad/s here; they drive at 20), -20 rad in 0.5 s (40 rad/s) is
    implausible, so the step is skipped and the pose carries on. (With a loose
    max_wheel_speed, 200 rad/s by default, the same reset would be integrated as 20 rad
    backwards: set it to what the wheels can really do.)
    """
    proc, out, _, ex, pub, sink = odom_rig("-p", "max_wheel_speed:=25.0")
    send_first(ex, pub, sink, reading(T0_NS, [0.0, 0.0]))
    before_ns = drive(ex, pub, T0_NS, (0.0, 0.0), (0.4, 0.4), 50)
    before = pose_at(ex, sink, before_ns)
    spin_for(ex, 0.5)
    restart_ns = before_ns + 25 * STEP_NS
    pub.publish(reading(restart_ns, [0.0, 0.0]))
    last_ns = drive(ex, pub, restart_ns, (0.0, 0.0), (0.2, 0.2), 25)
    final = pose_at(ex, sink, last_ns)
    skipped = out.wait_for("over max_wheel_speed")
    assert proc.poll() is None
    assert_pose(before, R * 20.0, 0.0, 0.0)
    assert_pose(final, R * 25.0, 0.0, 0.0)  # 20 rad before, 5 rad after, none backwards
    assert skipped, out.text()


def test_burst_of_5000_readings_ends_on_the_exact_pose(odom_rig: OdomRigs) -> None:
    """5,000 readings as fast as the publisher goes: the node's keep-last 100 queue may
    drop some, but increments are differences of absolute positions, so the pose at
    the last reading is still the arc's closed form. Stamps 1 ms apart (a 1 kHz
    driver) and a max_reading_gap of 60 s: this is about queue drops, not gaps."""
    n, rate = 5000, (0.004, 0.006)  # rad per reading: 4 and 6 rad/s
    proc, _, _, ex, pub, sink = odom_rig("-p", "max_reading_gap:=60.0",
                                         "-p", "enable_odom_tf:=false", qos=100)
    send_first(ex, pub, sink, reading(T0_NS, [0.0, 0.0]))
    step = 1_000_000
    for k in range(1, n + 1):
        pub.publish(reading(T0_NS + k * step, [rate[0] * k, rate[1] * k]))
    last = reading(T0_NS + n * step, [rate[0] * n, rate[1] * n])
    last_ns = T0_NS + n * step
    # Best effort may lose the last one too: repeat it (repeats are dropped as such).
    for _ in range(50):
        if spin_until(ex, lambda: any(ns_of(o.header.stamp) == last_ns for o in sink.odom),
                      0.5):
            break
        pub.publish(last)
    final = pose_at(ex, sink, last_ns)
    assert proc.poll() is None
    assert_pose(final, *oracle.wheel_arc(R * rate[0] * n, R * rate[1] * n, B))


def test_stall_of_5_s_warns_and_recovers_without_a_jump() -> None:
    """5 s without input, robot standing: /diagnostics goes stale (WARN, then ERROR) and
    back to OK once readings flow; the pose continues from where it was."""
    geometry = ["-p", f"wheel_radius:={R}", "-p", f"wheel_separation:={B}"]
    with diagnosed("odometry_node", geometry) as peer:
        ex = peer.executor
        sink = listen(peer.node, "/odom")
        pub = peer.node.create_publisher(JointState, "/joint_states", 10)
        wait_ready(ex, pub, sink)
        send_first(ex, pub, sink, reading(T0_NS, [0.0, 0.0]))
        before_ns = drive(ex, pub, T0_NS, (0.0, 0.0), (0.2, 0.3), 50)
        before = pose_at(ex, sink, before_ns)
        peer.cursor = len(peer.statuses)
        stale = peer.wait_for(lambda s: s.level != OK, 10.0)
        error = peer.wait_for(lambda s: s.level == ERROR, 10.0)  # 5 s without a reading
        at = (0.2 * 50, 0.3 * 50)  # it stood still: the same positions
        resume_ns = before_ns + 300 * STEP_NS
        pub.publish(reading(resume_ns, list(at)))
        peer.cursor = len(peer.statuses)
        done, ok = 0, None
        deadline = time.monotonic() + 8.0
        while ok is None and time.monotonic() < deadline:
            drive(ex, pub, resume_ns + done * STEP_NS,
                  (at[0] + 0.2 * done, at[1] + 0.3 * done), (0.2, 0.3), 10)
            done += 10
            ok = next((s for s in peer.statuses[peer.cursor:] if s.level == OK), None)
        final = pose_at(ex, sink, resume_ns + done * STEP_NS)
    assert stale.level == WARN and stale.message.startswith("stale"), stale.message
    assert error.message.startswith("no reading for"), error.message
    assert ok is not None, [s.message for s in peer.statuses]
    start = oracle.wheel_arc(R * 0.2 * 50, R * 0.3 * 50, B)
    assert_pose(before, *start)
    assert_pose(final, *then(start, R * 0.2 * done, R * 0.3 * done))


def test_ten_namespaced_robots_at_once_have_no_crosstalk() -> None:
    """Ten nodes (``-r __ns:=/robotN``), each fed its own straight drive: each odom is its
    own closed form, in its own frames."""
    n = 10
    with ExitStack() as stack:
        procs = [stack.enter_context(odometry_node("-r", f"__ns:=/robot{i}"))[0]
                 for i in range(n)]
        node, ex = stack.enter_context(ros_test_node())
        sinks = [listen(node, f"/robot{i}/odom") for i in range(n)]
        pubs = [node.create_publisher(JointState, f"/robot{i}/joint_states", 10)
                for i in range(n)]
        for i in range(n):  # both ways (rosutil.handshake): a robot whose odom publisher
            # did not see us yet would lose its first pose, and the repeats are dropped
            assert wait_matched(node, ex, pubs[i], sinks[i].odom_sub, 90.0), f"robot{i}"
        for i in range(n):
            send_first(ex, pubs[i], sinks[i], reading(T0_NS, [0.0, 0.0]))
        steps = 30
        for k in range(1, steps + 1):
            for i in range(n):  # robot i: 0.01 (i + 1) rad per reading on both wheels
                phi = 0.01 * (i + 1) * k
                pubs[i].publish(reading(T0_NS + k * STEP_NS, [phi, phi]))
            spin_for(ex, 0.01)
        last_ns = T0_NS + steps * STEP_NS
        finals = [pose_at(ex, sinks[i], last_ns, 20.0) for i in range(n)]
        assert all(p.poll() is None for p in procs)
    for i, o in enumerate(finals):
        assert o.header.frame_id == f"robot{i}/odom" and o.child_frame_id == f"robot{i}/base_link"
        assert_pose(o, R * 0.01 * (i + 1) * steps, 0.0, 0.0)
        assert all(m.header.frame_id == f"robot{i}/odom" for m in sinks[i].odom)
    transforms = [t for m in sinks[0].tf for t in m.transforms]  # /tf: every robot's
    assert {(t.header.frame_id, t.child_frame_id) for t in transforms} == \
        {(f"robot{i}/odom", f"robot{i}/base_link") for i in range(n)}


def bad_reading(rng: random.Random, k: int) -> JointState:
    """One seeded bad JointState: non-finite or huge values, short or empty arrays,
    wrong names, zero or old stamps."""
    t_ns = T0_NS + k * STEP_NS
    kind = rng.randrange(8)
    good = [0.01 * k, 0.01 * k]
    if kind == 0:
        return reading(t_ns, [rng.choice([math.nan, math.inf, -math.inf]), 0.01 * k])
    if kind == 1:
        return reading(t_ns, [rng.choice([1e308, -1e308, 1e20, -3e15]), 0.01 * k])
    if kind == 2:
        return reading(t_ns, good[:rng.randrange(2)])
    if kind == 3:
        return reading(t_ns, good, names=rng.choice([["a", "b"], ["left_wheel_joint"], []]))
    if kind == 4:
        msg = reading(t_ns, good)
        msg.header.stamp.sec, msg.header.stamp.nanosec = 0, 0
        return msg
    if kind == 5:
        return reading(t_ns - rng.randrange(1, 100) * STEP_NS, good)
    if kind == 6:
        return reading(t_ns, [math.nan, math.nan],
                       velocity=[rng.choice([math.nan, math.inf, 1e300]), 1.0])
    return reading(t_ns, good, velocity=[1.0])  # velocity shorter than the names


def finite(o: Odometry) -> bool:
    p, t = o.pose.pose, o.twist.twist
    values = [p.position.x, p.position.y, p.position.z, p.orientation.x, p.orientation.y,
              p.orientation.z, p.orientation.w, t.linear.x, t.linear.y, t.angular.z,
              *o.pose.covariance, *o.twist.covariance]
    return all(math.isfinite(v) for v in values)


def test_dds_fuzz_never_kills_or_poisons_the_node(odom_rig: OdomRigs) -> None:
    """A few hundred seeded bad readings: the node lives, publishes nothing non-finite,
    and a clean straight drive afterwards (after a gap, so it starts a new reference)
    moves the pose on from where the bad input left it by exactly its closed form."""
    rng = random.Random(9)
    proc, out, _, ex, pub, sink = odom_rig(qos=50)
    send_first(ex, pub, sink, reading(T0_NS, [0.0, 0.0]))
    n = 300
    for k in range(1, n + 1):
        pub.publish(bad_reading(rng, k) if rng.random() < 0.8
                    else reading(T0_NS + k * STEP_NS, [0.01 * k, 0.01 * k]))
        spin_for(ex, 0.002)
    assert proc.poll() is None, out.text()
    # 4 s later, past max_reading_gap, a driver restart (counters back at zero): the
    # first clean reading is held, the next one continues from it, so it becomes the new
    # reference and the pose carries on.
    clean_ns = T0_NS + (n + 200) * STEP_NS
    pub.publish(reading(clean_ns, [0.0, 0.0]))
    spin_for(ex, 0.2)
    last_ns = drive(ex, pub, clean_ns, (0.0, 0.0), (0.1, 0.1), 40)
    final = pose_at(ex, sink, last_ns)
    assert proc.poll() is None
    assert out.wait_for("dropped"), out.text()  # the garbage did reach the node
    # Where the bad input left the pose: the last odometry stamped before the clean
    # readings (every bad stamp is), odom being reliable and in order. Not the last
    # one seen at some moment: a node running behind publishes more of the fuzz later.
    # The clean odometry after it, 40 at most, cannot push it out of the sink's 50.
    start = [o for o in sink.odom if ns_of(o.header.stamp) < clean_ns][-1]
    assert all(finite(o) for o in sink.odom)
    assert all(math.isfinite(v) for m in sink.tf for t in m.transforms
               for v in (t.transform.translation.x, t.transform.translation.y,
                         t.transform.rotation.z, t.transform.rotation.w))
    p = start.pose.pose
    th = yaw(p.orientation)
    d = R * 0.1 * 40
    assert_pose(final, p.position.x + d * math.cos(th), p.position.y + d * math.sin(th), th)
