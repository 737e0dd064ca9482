"""The cmd_vel node over real DDS on loopback, plus its parameter validation.

Each DDS test starts ``cmd_vel_node`` as its own process (the console script a user
runs) and talks to it from a private-Context peer node. Expected wheel speeds are the
closed-form inverse kinematics left = (v - w b/2) / r, right = (v + w b/2) / r.
"""

from __future__ import annotations

import itertools
import math
import random
import statistics
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Twist, TwistStamped
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from diffdrive_odom.ros.cmd_vel_node import CmdVelNode
from diffdrive_odom.settings.cmd_vel import CMD_VEL_PARAMS, cmd_vel_settings
from diffdrive_odom.settings.errors import ParameterError
from diffdrive_odom.settings.rcl import load_params_file

from rosutil import (
    assert_refused_in_process,
    assert_refuses_to_start,
    node_process,
    ns_of,
    ros_test_node,
    spin_for,
    spin_until,
)

# --- parameters (pure) ---------------------------------------------------------------

GOOD = {"wheel_radius": 0.1, "wheel_separation": 0.4}


def test_parameter_names_are_unique_and_geometry_is_shared() -> None:
    names = [s.name for s in CMD_VEL_PARAMS]
    assert len(names) == len(set(names))
    for name in ("wheel_radius", "wheel_separation", "left_wheel_sign", "ticks_per_revolution",
                 "linear.x.max_deceleration_reverse", "angular.z.min_jerk"):
        assert name in names


def test_defaults_refuse_to_guess_the_geometry() -> None:
    with pytest.raises(ParameterError) as err:
        cmd_vel_settings({})
    assert err.value.name == "wheel_radius"


@pytest.mark.parametrize(
    ("name", "value"),
    [
        ("linear.x.max_deceleration", 2.0),
        ("angular.z.max_acceleration_reverse", 1.0),
        ("linear.x.min_velocity", 0.2),
        ("angular.z.max_jerk", -1.0),
        ("max_wheel_velocity", -3.0),
        ("max_wheel_velocity", 2e4),  # beyond max_plausible_wheel_velocity: never reached
        ("max_plausible_wheel_velocity", 0.0),
        ("max_plausible_wheel_velocity", math.inf),
        ("max_plausible_wheel_velocity", math.nan),
        ("wheel_command_rate", 0.0),
        ("cmd_vel_timeout", -0.1),
        ("control_point_offset", math.inf),
        ("wheel_command_format", "rpm"),
        ("enable_stamped_cmd_vel", 1),
    ],
)
def test_bad_values_are_refused_by_name(name: str, value: Any) -> None:
    with pytest.raises(ParameterError) as err:
        cmd_vel_settings({**GOOD, name: value})
    assert err.value.name == name


def test_ddc_deprecated_switches_are_read_with_their_axis() -> None:
    s = cmd_vel_settings({**GOOD, "linear.x.has_jerk_limits": False, "linear.x.max_jerk": 0.0,
                          "angular.z.has_acceleration_limits": False,
                          "angular.z.max_acceleration": 0.3,
                          "angular.z.min_acceleration": -0.3})
    assert math.isnan(s.limits.linear.max_jerk)
    assert math.isnan(s.limits.angular.max_acceleration)
    assert math.isnan(s.limits.angular.max_acceleration_reverse)
    with pytest.raises(ParameterError) as err:  # jerk limits on: 0 forbids any change
        cmd_vel_settings({**GOOD, "linear.x.max_jerk": 0.0})
    assert err.value.name == "linear.x.max_jerk"


def test_ticks_format_needs_ticks_per_revolution() -> None:
    with pytest.raises(ParameterError) as err:
        cmd_vel_settings({**GOOD, "wheel_command_format": "ticks_per_second"})
    assert err.value.name == "ticks_per_revolution"


def test_nested_yaml_limits_read_like_the_node_reads_them(tmp_path: Path) -> None:
    path = tmp_path / "p.yaml"
    path.write_text(PARAMS_YAML)
    s = cmd_vel_settings(load_params_file(path, "cmd_vel_node"))
    assert s.limits.linear.max_acceleration == 2.0
    assert math.isnan(s.limits.linear.max_velocity)
    assert s.limits.angular.max_velocity == 3.0
    assert s.geometry.left_wheel_sign == -1
    assert s.wheel_command_format == "ticks_per_second"


# --- DDS helpers -----------------------------------------------------------------------

R, B = 0.1, 0.4
TIMEOUT, RATE = 0.5, 50.0
PERIOD = 1.0 / RATE
# A tick reads the steady clock, then stamps its messages from the node's clock a few
# lines later: on stamps, a tick's instant is known to within this (measured: 0.18 ms
# on a quiet machine, 2.6 ms once under CI load; half a tick period here).
STAMP_SLACK_NS = 10_000_000


@dataclass
class Sink:
    """What the node publishes, with the (monotonic) time each message arrived."""

    msgs: list[tuple[float, Any]] = field(default_factory=list)

    def add(self, msg: Any) -> None:
        self.msgs.append((time.monotonic(), msg))

    def since(self, t: float) -> list[tuple[float, Any]]:
        return [(ts, m) for ts, m in self.msgs if ts >= t]


def output(proc: Any) -> str:
    """The node's output once it has ended."""
    if proc.poll() is None:
        return "(still running)"
    return str(proc.stdout.read()) if proc.stdout else ""


@contextmanager
def cmd_vel_node(args: list[str]) -> Iterator[tuple[Any, Node, Any]]:
    with node_process("cmd_vel_node", ["--ros-args", *args]) as proc, \
            ros_test_node() as (node, ex):
        yield proc, node, ex


def wait_connected(ex: Any, pub: Any, sink: Sink, proc: Any) -> None:
    """The node heard (subscription matched) and speaks (heartbeat arrives)."""
    assert spin_until(ex, lambda: pub.get_subscription_count() > 0 and sink.msgs, 20.0), (
        "cmd_vel_node never connected: " + output(proc)
    )


def drive(ex: Any, pub: Any, make: Callable[[], Any], seconds: float, hz: float = 20.0) -> None:
    """Publish ``make()`` at ``hz`` for ``seconds``."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        pub.publish(make())
        spin_for(ex, 1.0 / hz)


def twist(v: float, w: float, vy: float = 0.0) -> Twist:
    msg = Twist()
    msg.linear.x, msg.linear.y, msg.angular.z = v, vy, w
    return msg


def stamped(v: float, w: float, stamp_ns: int) -> TwistStamped:
    msg = TwistStamped()
    msg.header.stamp = Time(sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9)
    msg.twist = twist(v, w)
    return msg


def wall_ns() -> int:
    return time.time_ns()


def is_zero(values: Any) -> bool:
    return all(x == 0.0 for x in values)


def timeline(msgs: list[tuple[float, Any]]) -> list[tuple[int, float, float]]:
    """(stamp [ns], linear.x, angular.z) of received TwistStamped: the node's ticks."""
    return [(ns_of(m.header.stamp), m.twist.linear.x, m.twist.angular.z) for _, m in msgs]


def tick_gaps(msgs: list[tuple[float, Any]]) -> list[float]:
    """Seconds between the stamps of consecutive received TwistStamped (the node's ticks)."""
    stamps = [ns_of(m.header.stamp) for _, m in msgs]
    return [(b - a) * 1e-9 for a, b in itertools.pairwise(stamps)]


def wheels(v: float, w: float) -> list[float]:
    """The closed form for (v, w): fl, rl, fr, rr with the right joints flipped."""
    left, right = (v - w * B / 2) / R, -(v + w * B / 2) / R
    return [left, left, right, right]


# --- DDS tests ---------------------------------------------------------------------------


@pytest.mark.dds
@pytest.mark.process
def test_twist_to_float64_array_watchdog_rate_nan_and_runtime_parameters() -> None:
    args = ["-p", f"wheel_radius:={R}", "-p", f"wheel_separation:={B}",
            "-p", "left_wheel_names:=['fl','rl']", "-p", "right_wheel_names:=['fr','rr']",
            "-p", "right_wheel_sign:=-1", "-p", "publish_limited_velocity:=true",
            "-p", f"cmd_vel_timeout:={TIMEOUT}", "-p", f"wheel_command_rate:={RATE}"]
    with cmd_vel_node(args) as (proc, node, ex):
        sink, ticks = Sink(), Sink()
        node.create_subscription(Float64MultiArray, "/wheel_commands", sink.add, 100)
        # A Float64MultiArray has no stamp; cmd_vel_out goes out in the same tick, stamped
        # with the node's clock then: the node's own timeline of its heartbeat and its
        # watchdog, whatever delays the delivery to this test (CI load).
        node.create_subscription(TwistStamped, "/cmd_vel_out", ticks.add, 100)
        pub = node.create_publisher(Twist, "/cmd_vel", 10)
        wait_connected(ex, pub, sink, proc)

        # Heartbeat before any command: zeros at wheel_command_rate (the median period of
        # the node's stamps: a stall of the node skips ticks, it does not move this).
        n0, k0 = len(sink.msgs), len(ticks.msgs)
        assert spin_until(ex, lambda: len(sink.msgs) - n0 > RATE
                          and len(ticks.msgs) - k0 > RATE, 10.0), output(proc)
        assert all(is_zero(m.data) for _, m in sink.msgs[n0:])
        period = statistics.median(tick_gaps(ticks.msgs[k0:]))
        print(f"heartbeat: median period {period * 1e3:.1f} ms on the node's stamps "
              f"at wheel_command_rate {RATE:g} Hz")
        assert period == pytest.approx(PERIOD, rel=0.15)

        v, w = 0.5, 1.0
        expected = wheels(v, w)
        assert spin_until(ex, lambda: (pub.publish(twist(v, w)), sink.msgs[-1][1].data)[1]
                          .tolist() == pytest.approx(expected), 10.0)
        drive(ex, pub, lambda: twist(v, w), 1.0)
        # The last command differs from those before it (half of it), so the first tick
        # that follows it is seen: its arrival lies between that tick and the one before.
        v2, w2 = v / 2, w / 2
        n1 = len(sink.msgs)
        sent_ns = wall_ns()
        pub.publish(twist(v2, w2))

        def after_stop() -> list[tuple[int, float, float]]:
            ticked = timeline(ticks.msgs)
            last = max((i for i, (_, x, z) in enumerate(ticked) if (x, z) == (v2, w2)),
                       default=None)
            return [] if last is None else ticked[last + 1:]

        # Held until the zeros are seen, and a heartbeat of them after (RATE / 2 ticks).
        assert spin_until(ex, lambda: len(after_stop()) > RATE / 2, 10.0), (
            "the node never stopped after the last command: " + output(proc))
        ticked = timeline(ticks.msgs)
        first = next(i for i, (_, x, z) in enumerate(ticked) if (x, z) == (v2, w2))
        zero = next(i for i in range(first, len(ticked)) if ticked[i][1:] == (0.0, 0.0))
        before, held = ticked[first - 1], ticked[zero - 1]
        assert all(t[1:] == (v2, w2) for t in ticked[first:zero]), ticked[first:zero]
        assert all(t[1:] == (0.0, 0.0) for t in ticked[zero:])
        timeout_ns, slack_ns = round(TIMEOUT * 1e9), STAMP_SLACK_NS
        print(f"watchdog: the last command followed from its first tick for "
              f"{(held[0] - ticked[first][0]) * 1e-6:.0f} ms, zeros "
              f"{(ticked[zero][0] - ticked[first][0]) * 1e-6:.0f} ms after it "
              f"(timeout {TIMEOUT * 1e3:.0f} ms, period {PERIOD * 1e3:.0f} ms)")
        # Zeros on the first tick past the timeout from the arrival (after ``before``,
        # after our send; at or before ``first``): held up to it, not one tick more.
        assert ticked[zero][0] - before[0] > timeout_ns - slack_ns
        assert ticked[zero][0] - sent_ns > timeout_ns - slack_ns
        assert held[0] - ticked[first][0] <= timeout_ns + slack_ns
        # The wheels got the same, tick for tick: the new command as often, then zeros.
        wheel = [list(m.data) for _, m in sink.msgs[n1:]]
        new = [i for i, d in enumerate(wheel) if d == pytest.approx(wheels(v2, w2))]
        assert new == list(range(new[0], new[0] + zero - first)), wheel
        assert all(d == pytest.approx(expected) or is_zero(d) for d in wheel[:new[0]])
        assert wheel[new[-1] + 1:] and all(is_zero(d) for d in wheel[new[-1] + 1:])
        # and the heartbeat goes on at its rate with zeros.
        assert statistics.median(tick_gaps(ticks.msgs[zero:])) == pytest.approx(
            PERIOD, rel=0.15)

        # NaN / inf commands count as no command: the robot stays stopped.
        t_nan = time.monotonic()
        drive(ex, pub, lambda: twist(math.nan, 1.0), 0.4)
        drive(ex, pub, lambda: twist(0.3, math.inf), 0.4)
        refused = sink.since(t_nan)
        assert refused, "no heartbeat while NaN / inf commands came in"
        assert all(is_zero(m.data) for _, m in refused)

        # Runtime parameters: refused with a reason naming them; a good one takes effect.
        client = AsyncParameterClient(node, "cmd_vel_node")
        assert client.wait_for_services(timeout_sec=10.0)

        def set_param(name: str, value: Any) -> Any:
            future = client.set_parameters([Parameter(name, value=value)])
            assert spin_until(ex, future.done, 10.0)
            return future.result().results[0]

        bad = set_param("linear.x.max_acceleration", -1.0)
        assert not bad.successful and "linear.x.max_acceleration" in bad.reason
        assert not set_param("wheel_command_format", "joint_state").successful  # read-only
        assert set_param("max_wheel_velocity", 3.5).successful
        # |right| = 7 > 3.5: both wheels halved, curvature kept.
        scaled = [x / 2 for x in expected]
        assert spin_until(ex, lambda: (pub.publish(twist(v, w)), sink.msgs[-1][1].data)[1]
                          .tolist() == pytest.approx(scaled), 10.0)
        assert proc.poll() is None, "node died: " + output(proc)
    for _, m in sink.msgs:
        assert all(math.isfinite(x) for x in m.data)


@pytest.mark.dds
@pytest.mark.process
def test_twist_stamped_to_joint_state_stale_and_zero_stamps() -> None:
    r, b = 0.05, 0.3
    args = ["-p", f"wheel_radius:={r}", "-p", f"wheel_separation:={b}",
            "-p", "enable_stamped_cmd_vel:=true", "-p", "wheel_command_format:=joint_state",
            "-p", f"cmd_vel_timeout:={TIMEOUT}"]
    with cmd_vel_node(args) as (proc, node, ex):
        sink = Sink()
        node.create_subscription(JointState, "/wheel_commands", sink.add, 100)
        pub = node.create_publisher(TwistStamped, "/cmd_vel", 10)
        wait_connected(ex, pub, sink, proc)

        t0 = time.monotonic()
        drive(ex, pub, lambda: stamped(0.3, 0.0, wall_ns() - 2 * 10**9), 0.8)  # 2 s old
        stale = sink.since(t0)
        assert stale, "no heartbeat while stale commands came in"
        assert all(is_zero(m.velocity) for _, m in stale)

        def latest() -> list[float]:
            return list(sink.msgs[-1][1].velocity)

        assert spin_until(ex, lambda: (pub.publish(stamped(0.3, 0.0, wall_ns())),
                                       latest())[1] == pytest.approx([6.0, 6.0]), 10.0)
        msg = sink.msgs[-1][1]
        assert list(msg.name) == ["left_wheel_joint", "right_wheel_joint"]
        assert msg.header.stamp.sec > 0

        # Zero stamp = now: accepted (turn on the spot: w b/2 / r = +-3 rad/s).
        assert spin_until(ex, lambda: (pub.publish(stamped(0.0, 1.0, 0)),
                                       latest())[1] == pytest.approx([-3.0, 3.0]), 10.0)
        drive(ex, pub, lambda: stamped(0.0, 1.0, 0), 0.3)
        # Slightly old but within the timeout: still accepted.
        assert spin_until(ex, lambda: (pub.publish(stamped(-0.1, 0.0, wall_ns() - 2 * 10**8)),
                                       latest())[1] == pytest.approx([-2.0, -2.0]), 10.0)
    out = output(proc)
    assert out.count("stamp is zero") == 1, out
    assert "stale cmd_vel ignored" in out


PARAMS_YAML = """\
/**:
  ros__parameters:
    wheel_radius: 0.1
    wheel_separation: 0.5
    left_wheel_sign: -1
    ticks_per_revolution: 4096.0
cmd_vel_node:
  ros__parameters:
    wheel_command_format: ticks_per_second
    publish_limited_velocity: true
    linear:
      x:
        max_velocity: .nan
        max_acceleration: 2.0
    angular:
      z:
        max_velocity: 3.0
"""


@pytest.mark.dds
@pytest.mark.process
def test_ticks_params_file_acceleration_limit_and_cmd_vel_out(tmp_path: Path) -> None:
    path = tmp_path / "params.yaml"
    path.write_text(PARAMS_YAML)
    # cmd_vel_timeout past a stall of the node on a loaded CI (up to 0.5 s): the command
    # must not expire mid-ramp (that would rightly ramp down, and start again).
    with cmd_vel_node(["--params-file", str(path), "-p", "cmd_vel_timeout:=1.0"]) as (
            proc, node, ex):
        sink, limited = Sink(), Sink()
        node.create_subscription(Float64MultiArray, "/wheel_commands", sink.add, 100)
        node.create_subscription(TwistStamped, "/cmd_vel_out", limited.add, 100)
        pub = node.create_publisher(Twist, "/cmd_vel", 10)
        wait_connected(ex, pub, sink, proc)
        assert spin_until(ex, lambda: limited.msgs, 10.0)

        k = 4096.0 / (2 * math.pi)
        v, w = 1.0, 3.0  # angular is capped at 3 rad/s
        left = -(v - w * 0.5 / 2) / 0.1 * k  # left joint is flipped
        right = (v + w * 0.5 / 2) / 0.1 * k

        def at_full_speed() -> bool:
            return (any(m.twist.linear.x >= v - 1e-12 for _, m in limited.msgs)
                    and any(list(m.data) == pytest.approx([left, right]) for _, m in sink.msgs))

        # Commanded until the limited output reached the target (and the wheels had it).
        assert spin_until(ex, lambda: (pub.publish(twist(1.0, 5.0)), at_full_speed())[1],
                          10.0), output(proc)
        # The node's tick clock: cmd_vel_out's stamps. Its limiter measures each step on
        # the steady clock and stamps a few lines later, so one stamp can be off by the
        # stall in between (2.6 ms seen under CI load): it lengthens one step and shortens
        # the next by as much, so the law is checked where that cancels. Short of the
        # target, steps not at the two-period cap add max_acceleration times their time
        # (on average within 5 %), never a step more than the cap allows (a stall must not
        # allow a leap), never a step back.
        ramped = timeline(limited.msgs)
        start = next(i for i, (_, x, _) in enumerate(ramped) if x > 0.0) - 1
        full = next(i for i, (_, x, _) in enumerate(ramped) if x >= v - 1e-12)
        assert start >= 0 and ramped[start][1] == 0.0
        accel, cap, slack = 2.0, 2 * 0.02, STAMP_SLACK_NS * 1e-9
        steps = [(b[1] - a[1], (b[0] - a[0]) * 1e-9)
                 for a, b in itertools.pairwise(ramped[start:full + 1])]
        assert all(dv >= 0.0 for dv, _ in steps), steps
        free = [(dv, dt) for dv, dt in steps[:-1] if dt < cap - slack]  # the last: partial
        assert len(free) > 10, steps
        rate = sum(dv for dv, _ in free) / sum(dt for _, dt in free)
        assert rate == pytest.approx(accel, rel=0.05), (rate, steps)
        assert max(dv for dv, _ in steps) <= accel * cap + 1e-9
        ramp = (ramped[full][0] - ramped[start][0]) * 1e-9
        print(f"limiter: 0 -> 1 m/s in {ramp * 1e3:.0f} ms of the node's ticks at 2 m/s^2 "
              f"(at least 500 ms; {full - start} ticks)")
        assert ramp >= v / accel - slack  # 0 -> 1 m/s at 2 m/s^2: 0.5 s at the least
        # angular.z has no acceleration limit: at its 3 rad/s cap from the first tick on.
        assert all(z == pytest.approx(3.0) for _, _, z in ramped[start + 1:full + 1])


@pytest.mark.dds
@pytest.mark.process
def test_sim_time_stale_stamps_ignored_and_fresh_ones_followed() -> None:
    args = ["-p", f"wheel_radius:={R}", "-p", f"wheel_separation:={B}",
            "-p", "enable_stamped_cmd_vel:=true", "-p", "use_sim_time:=true"]
    sim0 = 1000 * 10**9
    with cmd_vel_node(args) as (proc, node, ex):
        sink = Sink()
        node.create_subscription(Float64MultiArray, "/wheel_commands", sink.add, 100)
        pub = node.create_publisher(TwistStamped, "/cmd_vel", 10)
        clock_pub = node.create_publisher(Clock, "/clock", 10)
        wait_connected(ex, pub, sink, proc)
        assert spin_until(ex, lambda: clock_pub.get_subscription_count() > 0, 10.0)
        w0 = time.monotonic_ns()

        def sim_now() -> int:
            return sim0 + (time.monotonic_ns() - w0)

        def tick(make: Callable[[], TwistStamped]) -> TwistStamped:
            clock_pub.publish(Clock(clock=Time(sec=sim_now() // 10**9,
                                               nanosec=sim_now() % 10**9)))
            return make()

        drive(ex, pub, lambda: tick(lambda: twist_stamped_none()), 0.5)  # clock only
        t0 = time.monotonic()
        drive(ex, pub, lambda: tick(lambda: stamped(0.4, 0.0, sim_now() - 2 * 10**9)), 0.8)
        stale = sink.since(t0)
        assert stale, "no heartbeat while commands stale by the simulated clock came in"
        assert all(is_zero(m.data) for _, m in stale)
        # Fresh by the simulated clock (but ~1.7e9 s old by the wall clock): followed.
        assert spin_until(ex, lambda: (pub.publish(tick(lambda: stamped(0.4, 0.0, sim_now()))),
                                       list(sink.msgs[-1][1].data))[1]
                          == pytest.approx([4.0, 4.0]), 10.0)
    assert "stale cmd_vel ignored" in output(proc)


def twist_stamped_none() -> TwistStamped:
    """A message that the node must ignore: NaN (used to keep the clock ticking)."""
    return stamped(math.nan, 0.0, 1)


_GEOMETRY = ["-p", f"wheel_radius:={R}", "-p", f"wheel_separation:={B}"]
BAD_PARAMETERS = {
    "linear.x.max_deceleration": [*_GEOMETRY, "-p", "linear.x.max_deceleration:=2.0"],
    "ticks_per_revolution": [*_GEOMETRY, "-p", "wheel_command_format:=ticks_per_second"],
    "wheel_command_rate": [*_GEOMETRY, "-p", "wheel_command_rate:=0.0"],
    "wheel_radius": ["-p", f"wheel_separation:={B}"],
}


@pytest.mark.dds
@pytest.mark.parametrize("name", BAD_PARAMETERS)
def test_bad_parameters_stop_the_node_with_their_name(name: str) -> None:
    """Each case in this process (the node's own construction, rcl parsing the -p)."""
    assert_refused_in_process(CmdVelNode, name, BAD_PARAMETERS[name])


@pytest.mark.dds
@pytest.mark.process
def test_a_bad_parameter_stops_the_process_with_exit_2_and_one_line() -> None:
    assert_refuses_to_start("cmd_vel_node", "linear.x.max_deceleration",
                            BAD_PARAMETERS["linear.x.max_deceleration"])


# --- nonsense never reaches the driver ----------------------------------------------------

PLAUSIBLE = 1e4  # max_plausible_wheel_velocity's default [rad/s]
TICKS_PER_REV = 4096.0
OFFSET = 0.1


def random_part(rng: random.Random) -> float:
    """One Twist component: mostly ordinary, often absurd, sometimes not a number."""
    kind = rng.random()
    sign = rng.choice((-1.0, 1.0))
    if kind < 0.35:
        return rng.uniform(-2.0, 2.0)
    if kind < 0.55:
        return sign * math.pow(10.0, rng.uniform(4.0, 308.0))  # huge but finite
    if kind < 0.65:
        return sign * math.pow(10.0, rng.uniform(1.0, 4.0))
    if kind < 0.75:
        return sign * rng.choice((5e-324, 2.2e-308, 1e-300, 1e-12))  # denormal / tiny
    if kind < 0.8:
        return sign * math.inf
    if kind < 0.85:
        return math.nan
    return 0.0


# (format, extra arguments, output units per rad/s, wheels per side, the reproduced case)
FUZZ_NODES = [
    ("float64_array", ["-p", f"control_point_offset:={OFFSET}",
                       "-p", "left_wheel_names:=['fl','rl']",
                       "-p", "right_wheel_names:=['fr','rr']"], 1.0, 2,
     twist(0.0, 0.0, vy=1e308)),  # w = vy / l overflowed in the timer and killed the node
    ("ticks_per_second", ["-p", f"ticks_per_revolution:={TICKS_PER_REV}",
                          "-p", "linear.x.max_acceleration:=50.0"],
     TICKS_PER_REV / (2 * math.pi), 1, twist(1e306, 0.0)),  # [inf, inf] after scaling
    ("joint_state", [], 1.0, 1, twist(1e300, 0.0)),  # forwarded as 3e306 rad/s
]


@pytest.mark.parametrize(("fmt", "extra", "k", "per_side", "reproduced"), FUZZ_NODES,
                         ids=[n[0] for n in FUZZ_NODES])
@pytest.mark.dds
@pytest.mark.process
def test_fuzzed_twists_never_reach_the_driver_and_a_normal_command_follows(
        fmt: str, extra: list[str], k: float, per_side: int, reproduced: Twist) -> None:
    args = ["-p", f"wheel_radius:={R}", "-p", f"wheel_separation:={B}",
            "-p", f"wheel_command_format:={fmt}", *extra]
    msg_type = JointState if fmt == "joint_state" else Float64MultiArray

    def values(m: Any) -> list[float]:
        return list(m.velocity if fmt == "joint_state" else m.data)

    with cmd_vel_node(args) as (proc, node, ex):
        sink = Sink()
        node.create_subscription(msg_type, "/wheel_commands", sink.add, 1000)
        pub = node.create_publisher(Twist, "/cmd_vel", 10)
        wait_connected(ex, pub, sink, proc)
        drive(ex, pub, lambda: reproduced, 0.3)
        rng = random.Random(9)
        for _ in range(400):
            msg = Twist()
            msg.linear.x, msg.linear.y, msg.linear.z = (random_part(rng) for _ in range(3))
            msg.angular.x, msg.angular.y, msg.angular.z = (random_part(rng) for _ in range(3))
            pub.publish(msg)
            spin_for(ex, 0.004)
        drive(ex, pub, lambda: reproduced, 0.3)
        assert proc.poll() is None, "node died: " + output(proc)

        v, w = 0.5, 1.0
        left, right = (v - w * B / 2) / R * k, (v + w * B / 2) / R * k
        expected = [left] * per_side + [right] * per_side
        normal = twist(v, 0.0, vy=w * OFFSET) if "control_point_offset" in str(extra) \
            else twist(v, w)
        assert spin_until(ex, lambda: (pub.publish(normal), values(sink.msgs[-1][1]))[1]
                          == pytest.approx(expected), 10.0), values(sink.msgs[-1][1])
        assert proc.poll() is None, "node died: " + output(proc)
    bound = PLAUSIBLE * k
    outputs = [values(m) for _, m in sink.msgs]
    bad = [x for out in outputs for x in out if not (math.isfinite(x) and abs(x) <= bound)]
    print(f"{fmt}: {len(outputs)} wheel commands, largest "
          f"{max(abs(x) for out in outputs for x in out if math.isfinite(x)):.6g}, "
          f"bound {bound:.6g}")
    assert not bad, bad[:5]
    assert "implausible cmd_vel refused" in output(proc)
