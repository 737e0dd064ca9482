"""Open-loop odometry against closed forms: commanded routes, the timeout, the covariance.

Expected poses come from test/oracle.py (textbook arcs ``R (sin - sin)``, never the
package's chord step): each command held from its arrival to the next arrival (or its
timeout) is one arc. Commands come from a sender on its own clock (a 20 Hz period with
jitter, a phase, a transport latency) and publication instants from a timer at a rate
that is no multiple of it, interleaved in arrival order as the node sees them.
"""

from __future__ import annotations

import math
import random

import pytest

from diffdrive_odom.core.errors import ConfigError
from diffdrive_odom.core.estimation.open_loop import (
    DEFAULT_OPEN_LOOP_RATE,
    NO_CLOCK,
    NON_FINITE,
    STALE_STAMP,
    TIME_RESET,
    OpenLoopConfig,
    OpenLoopOdometry,
    publication_rate,
    publication_times,
)
from diffdrive_odom.core.estimation.setpose import PoseRefusal, PoseRequest
from diffdrive_odom.core.geometry.kinematics import Geometry
from diffdrive_odom.core.motion import routes

import oracle

GEOMETRY = Geometry(wheel_radius=0.05, wheel_separation=0.3)
T0 = 1_700_000_000_123_456_789  # an epoch stamp [ns], not a round number
SENDER_HZ = 20.0
TIMER_HZ = 33.0  # the publication timer: no multiple of the sender's rate


def make(timeout: float = 0.5, noise: float = 0.05) -> OpenLoopOdometry:
    return OpenLoopOdometry(OpenLoopConfig(timeout=timeout, noise=noise), GEOMETRY)


def sent_commands(route: routes.Route, seed: int) -> list[tuple[int, float, float]]:
    """(arrival ns, v, w): the route sampled by a jittered 20 Hz sender, then delivered."""
    rng = random.Random(seed)
    out = []
    t = rng.uniform(0.0, 0.05)  # the sender's phase
    while t < route.duration + 0.3:
        v, w = route.command_at(t)
        latency = rng.uniform(0.001, 0.003)
        out.append((T0 + round((t + latency) * 1e9), v, w))
        t += 1.0 / SENDER_HZ + rng.gauss(0.0, 0.002)
    return out


def held_arcs(commands: list[tuple[int, float, float]], end_ns: int,
              timeout_ns: int) -> list[tuple[float, float]]:
    """Each command's arc: held until the next arrival, its timeout or the end."""
    arcs = []
    for k, (t, v, w) in enumerate(commands):
        stop = commands[k + 1][0] if k + 1 < len(commands) else end_ns
        if timeout_ns > 0:
            stop = min(stop, t + timeout_ns)
        dt = max(0, min(stop, end_ns) - t) * 1e-9
        arcs.append((v * dt, w * dt))
    return arcs


def run(odo: OpenLoopOdometry, commands: list[tuple[int, float, float]],
        ticks: list[int]) -> list[tuple[int, float, float, float]]:
    """Commands and timer ticks in time order, as the node's callbacks run; poses at ticks."""
    events = sorted([(t, 0, v, w) for t, v, w in commands] + [(t, 1, 0.0, 0.0) for t in ticks])
    poses = []
    for t, kind, v, w in events:
        if kind == 0:
            assert odo.command(t, v, w) == ""
        else:
            assert odo.advance(t) == ""
            poses.append((t, odo.pose.x, odo.pose.y, odo.pose.theta))
    return poses


def pose_error(got: tuple[float, float, float], want: oracle.Pose) -> float:
    return max(abs(got[0] - want[0]), abs(got[1] - want[1]),
               abs(math.remainder(got[2] - want[2], math.tau)))


ROUTES = {
    "square": routes.square(1.0),
    "umbmark": routes.umbmark_both(4.0),
    "circle": routes.circle(1.0, laps=1.5),
    "figure_eight": routes.figure_eight(0.8),
}


@pytest.mark.parametrize("name", sorted(ROUTES))
def test_a_commanded_route_is_integrated_exactly(name: str) -> None:
    """Every published pose equals the held commands' arcs to rounding (< 1e-12 m)."""
    route = ROUTES[name]
    commands = sent_commands(route, seed=len(name))
    odo = make(timeout=0.5)
    end = commands[-1][0] + 10**9
    ticks = list(publication_times(commands[0][0] + 7_000_000, end, TIMER_HZ))
    poses = run(odo, commands, ticks)
    worst = 0.0
    for k in range(0, len(poses), 37):  # every 37th pose and the last
        t, x, y, th = poses[k]
        want = oracle.integrate(held_arcs(commands, t, 500_000_000))
        worst = max(worst, pose_error((x, y, th), want))
    t, x, y, th = poses[-1]
    worst = max(worst, pose_error((x, y, th), oracle.integrate(
        held_arcs(commands, t, 500_000_000))))
    assert worst < 1e-12, worst


@pytest.mark.parametrize("name", sorted(ROUTES))
def test_one_command_per_segment_ends_where_the_route_does(name: str) -> None:
    """Commands at the segment boundaries (no timeout): the route's own end pose, to the
    rounding of the boundaries to whole nanoseconds."""
    route = ROUTES[name]
    odo = make(timeout=0.0)
    t = 0.0
    for seg in route.segments:
        assert odo.command(T0 + round(t * 1e9), seg.linear, seg.angular) == ""
        t += seg.duration
    odo.advance(T0 + round(t * 1e9))
    got = (odo.pose.x, odo.pose.y, odo.pose.theta)
    # ns rounding: each boundary is off by <= 0.5 ns, at <= 0.6 rad/s over a lever <= 8 m.
    assert pose_error(got, oracle.route_end(route.segments)) < 2e-9


def test_no_command_for_the_timeout_stops_the_robot() -> None:
    odo = make(timeout=0.5)
    odo.command(T0, 0.4, 0.0)
    assert odo.stats.commanding
    odo.advance(T0 + 2 * 10**9)
    assert odo.pose.x == pytest.approx(0.2, abs=1e-15)  # 0.4 m/s for 0.5 s, then zero
    assert (odo.linear, odo.angular) == (0.0, 0.0)
    assert not odo.stats.commanding


def test_a_stamped_command_expires_from_its_stamp_as_in_the_cmd_vel_node() -> None:
    odo = make(timeout=0.5)
    odo.command(T0, 0.4, 0.0, stamp_ns=T0 - 200_000_000)  # sent 0.2 s before it arrived
    odo.advance(T0 + 2 * 10**9)
    assert odo.pose.x == pytest.approx(0.4 * 0.3, abs=1e-15)


def test_timeout_zero_holds_the_command_forever() -> None:
    odo = make(timeout=0.0)
    odo.command(T0, 0.0, 0.5)
    odo.advance(T0 + 4 * 10**9)
    assert odo.pose.theta == pytest.approx(math.remainder(2.0, math.tau), abs=1e-15)
    assert odo.angular == 0.5


def test_refused_commands_leave_the_one_before_in_force() -> None:
    odo = make(timeout=0.5)
    odo.command(T0, 0.4, 0.0)
    assert odo.command(T0 + 100_000_000, math.nan, 0.0) == NON_FINITE
    assert odo.command(T0 + 200_000_000, 9.0, 0.0, stamp_ns=T0 - 10**9) == STALE_STAMP
    odo.advance(T0 + 400_000_000)
    assert odo.pose.x == pytest.approx(0.4 * 0.4, abs=1e-15)
    assert dict(odo.stats.dropped) == {NON_FINITE: 1, STALE_STAMP: 1}
    assert odo.stats.commands == 3


def test_time_far_back_restarts_at_the_origin_and_a_little_back_is_now() -> None:
    odo = make(timeout=0.0)
    odo.command(T0, 0.5, 0.0)
    odo.advance(T0 + 10**9)
    assert odo.command(T0 + 990_000_000, 1.0, 0.0) == ""  # 10 ms back: from where it is
    odo.advance(T0 + 2 * 10**9)
    assert odo.pose.x == pytest.approx(0.5 + 1.0, abs=1e-15)
    assert odo.advance(T0) == TIME_RESET  # a bag played in a loop
    assert (odo.pose.x, odo.linear, odo.stats.time_resets) == (0.0, 0.0, 1)
    odo.advance(T0 + 10**9)
    assert odo.pose.x == 0.0  # no command held after the restart


def test_reset_keeps_the_command_in_force() -> None:
    odo = make(timeout=0.0)
    odo.command(T0, 0.5, 0.0)
    odo.advance(T0 + 10**9)
    odo.reset()
    odo.advance(T0 + 2 * 10**9)
    assert odo.pose.x == pytest.approx(0.5, abs=1e-15)


def test_the_covariance_of_a_straight_command_grows_as_its_closed_form() -> None:
    """One draw of each wheel's relative error e_l, e_r ~ N(0, s^2) over a straight d:
    x = d (1 + (e_l + e_r) / 2), heading (e_r - e_l) d / b, y = (e_r - e_l) d^2 / (2 b)."""
    s, b, d = 0.05, GEOMETRY.wheel_separation, 2.0
    odo = make(timeout=0.0, noise=s)
    odo.command(T0, 0.5, 0.0)
    for k in range(1, 41):  # 40 steps of 0.1 s
        odo.advance(T0 + k * 100_000_000)
    pose_cov, twist_cov = odo.covariances()
    assert pose_cov[0] == pytest.approx(s * s * d * d / 2, rel=1e-9)
    assert pose_cov[7] == pytest.approx(s * s * d**4 / (2 * b * b), rel=1e-9)
    assert pose_cov[35] == pytest.approx(2 * s * s * d * d / (b * b), rel=1e-9)
    v = 0.5
    assert twist_cov[0] == pytest.approx(s * s * v * v / 2, rel=1e-9)
    assert twist_cov[35] == pytest.approx(2 * s * s * v * v / (b * b), rel=1e-9)
    # Grows fast: after 2 m the heading is known to 0.47 rad (1 sigma), not to
    # the encoders' default of about 0.1.
    assert math.sqrt(pose_cov[35]) > 0.4


def test_at_rest_the_covariance_does_not_grow() -> None:
    odo = make()
    odo.command(T0, 0.0, 0.0)
    odo.advance(T0 + 60 * 10**9)
    pose_cov, twist_cov = odo.covariances()
    assert max(pose_cov[0], pose_cov[7], pose_cov[35]) < 1e-11
    assert twist_cov[0] < 1e-11


def test_publication_times_are_the_node_timer_offline() -> None:
    assert publication_rate(0.0) == DEFAULT_OPEN_LOOP_RATE
    assert publication_rate(20.0) == 20.0
    times = list(publication_times(T0, T0 + 10**9, 30.0))
    assert len(times) == 31 and times[0] == T0 and times[-1] == T0 + 10**9
    assert times[1] - times[0] == 33_333_333


@pytest.mark.parametrize(("field", "kwargs"), [
    ("open_loop_source", {"source": "joint_states"}),
    ("cmd_vel_timeout", {"timeout": -1.0}),
    ("open_loop_noise", {"noise": math.nan}),
])
def test_bad_settings_name_the_parameter(field: str, kwargs: dict[str, object]) -> None:
    with pytest.raises(ConfigError) as err:
        OpenLoopConfig(**kwargs)  # type: ignore[arg-type]
    assert err.value.field == field


def test_covariance_model_static_publishes_the_diagonals_as_ddc() -> None:
    pose_diag, twist_diag = (0.002,) * 5 + (0.02,), (0.003,) * 5 + (0.03,)
    odo = OpenLoopOdometry(OpenLoopConfig(static=(pose_diag, twist_diag)), GEOMETRY)
    odo.command(T0, 0.5, 0.3)
    odo.advance(T0 + 10 * 10**9)
    pose_cov, twist_cov = odo.covariances()
    assert pose_cov[::7] == list(pose_diag) and twist_cov[::7] == list(twist_diag)
    assert sum(pose_cov) == sum(pose_diag)  # nothing off the diagonal


def test_a_command_before_the_clock_started_is_refused() -> None:
    """Simulated time before the first /clock reads zero: integrating from there would add
    a timeout's worth (or, with no timeout, decades) of motion at the first real tick."""
    odo = make(timeout=0.0)
    assert odo.command(0, 0.5, 0.0) == NO_CLOCK
    assert odo.advance(0) == ""
    odo.advance(T0)
    odo.advance(T0 + 10**9)
    assert odo.pose.x == 0.0 and dict(odo.stats.dropped) == {NO_CLOCK: 1}


def _request(stamp_ns: int, x: float, y: float, yaw: float, frame: str = "odom",
             var: float = 0.01) -> PoseRequest:
    cov = [0.0] * 36
    for i in (0, 7, 35):
        cov[i] = var
    return PoseRequest(stamp_ns, frame, (x, y, 0.0), (0.0, 0.0, math.sin(yaw / 2),
                                                      math.cos(yaw / 2)), cov)


def test_set_pose_now_and_ahead_then_the_commanded_arc_from_there() -> None:
    odo = make(timeout=0.0)
    odo.command(T0, 0.5, 0.0)
    odo.advance(T0 + 10**9)
    line = odo.set_pose(_request(0, 3.0, -1.0, 0.0), "odom")  # stamp 0: now
    assert isinstance(line, str) and "as the pose at" in line
    assert (odo.pose.x, odo.pose.y) == (3.0, -1.0)
    pose_cov, _ = odo.covariances()
    assert pose_cov[0] == pytest.approx(0.01, rel=1e-9)  # the given covariance, then grows
    # Ahead: held until the clock reaches it, then the held command's arc from there.
    line = odo.set_pose(_request(T0 + 2 * 10**9, 1.0, 2.0, math.pi / 2), "odom")
    assert isinstance(line, str) and "held" in line
    odo.advance(T0 + 3 * 10**9)
    want = oracle.arc(0.5 * 1.0, 0.0, (1.0, 2.0, math.pi / 2))
    assert pose_error((odo.pose.x, odo.pose.y, odo.pose.theta), want) < 1e-15


def test_set_pose_refusals_change_nothing() -> None:
    odo = make()
    odo.advance(T0)
    refused = odo.set_pose(_request(0, 1.0, 1.0, 0.0, frame="map"), "odom")
    assert isinstance(refused, PoseRefusal) and refused.code == "frame"
    assert (odo.pose.x, odo.pose.y) == (0.0, 0.0)
