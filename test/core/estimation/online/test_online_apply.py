"""``online_calibration: apply`` (issue 25 item 3): the estimate integrated with, no jump.

Streams: ``gyrostreams`` (the truth integrated there) and the simulator driven on its
own clocks (``simstreams``; the truth is the sim's true geometry and pose). Expected
values are closed forms: the applied radii from the estimated ratios with the
configured mean radius held (``r_R = 2 m u / (u + v)``, ``r_L = 2 m v / (u + v)``,
``b = 2 m / (u + v)``), the step after the switch as a textbook arc (``oracle``).
"""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
from gyrostreams import ISSUE_ROUTE, NAMES, TIMINGS, B, R, Route, stream, truth
from simstreams import SIM_TIMING, sim_stream, true_ratios

from diffdrive_odom.core.estimation.online.online_apply import APPLIED_NOTE, CONFIGURED_NOTE
from diffdrive_odom.core.estimation.pipeline import ReadingPipeline
from diffdrive_odom.core.geometry.integration import Pose2D
from diffdrive_odom.ros.geometry_estimate import estimate_message
from diffdrive_odom.settings.odometry import APPLY_NEEDS_IMU, odometry_settings, online_warning

from oracle import arc, mahalanobis2

MIXED = Route(ISSUE_ROUTE.segments * 2)
LEFT_ONLY = Route(((8.0, 0.4, 0.0), (10.0, 0.3, 0.4), (8.0, 0.4, 0.0), (10.0, 0.3, 0.5)))
TRUE = (R, R * 1.005, B * 1.01)
ALIGNED = TIMINGS[0]  # each step's samples in before its reading: judged at once, no debt


def pipeline(mode: str, use_imu: bool = True, values: dict[str, object] | None = None
             ) -> ReadingPipeline:
    return ReadingPipeline(odometry_settings(
        {"wheel_radius": R, "wheel_separation": B, "use_imu": use_imu,
         "online_calibration": mode, **(values or {})}))


def as_tuple(p: Pose2D) -> tuple[float, float, float]:
    return (p.x, p.y, p.theta)


def test_the_switch_changes_the_steps_after_it_not_the_pose() -> None:
    msgs = stream(MIXED, ALIGNED, math.radians(0.3), 3e-4, 1, truth(MIXED, *TRUE))
    monitor, apply = pipeline("monitor"), pipeline("apply")
    configured = apply.settings.geometry
    before: tuple[float, float, float] | None = None
    last: tuple[float, float] | None = None
    switched = False
    for kind, rx, stamp, a, b in msgs:
        if kind == "i":
            monitor.feed_imu(stamp, 0.0, 0.0, a, receive_ns=rx)
            apply.feed_imu(stamp, 0.0, 0.0, a, receive_ns=rx)
            continue
        online = apply.online
        assert online is not None
        ready = online.applied is not None  # taken at this reading's step
        if ready:
            est = online.estimate()
            assert est.determined
            u, v = est.ratios
            assert math.sqrt(est.covariance[0]) < 0.002 * u
            assert math.sqrt(est.covariance[3]) < 0.002 * v
        monitor.feed(stamp, NAMES, (a, b), receive_ns=rx)
        out = apply.feed(stamp, NAMES, (a, b), receive_ns=rx)
        assert out.note.startswith(APPLIED_NOTE) == ready  # said once, at the switch
        now = as_tuple(apply.estimator.pose)
        if not ready:
            assert now == as_tuple(monitor.estimator.pose)  # bit for bit until the switch
        else:
            g = apply.estimator.geometry
            m = 0.5 * (configured.left_radius + configured.right_radius)
            assert g.right_radius == pytest.approx(2 * m * u / (u + v), rel=1e-12)
            assert g.left_radius == pytest.approx(2 * m * v / (u + v), rel=1e-12)
            assert g.separation == pytest.approx(2 * m / (u + v), rel=1e-12)
            assert before is not None and last is not None
            # The step from the pose before: the wheels' distance in the applied radii.
            d_left, d_right = a - last[0], b - last[1]
            ds = 0.5 * (g.left_radius * d_left + g.right_radius * d_right)
            step = apply.estimator.last_step
            assert step is not None and step.ds == pytest.approx(ds, rel=1e-12)
            want = arc(ds, step.dtheta, before)
            assert now == pytest.approx(want, abs=1e-12)
            # Against monitor's pose: no more than this one step's share of the change.
            assert math.dist(now[:2], as_tuple(monitor.estimator.pose)[:2]) < 0.01 * abs(ds)
            switched = True
            break
        before, last = now, (a, b)
    assert switched
    stats = apply.stats.online
    assert stats is not None and stats.applied
    msg = estimate_message(stats)  # ~/geometry_estimate's last field, by name
    assert dict(zip(msg.layout.dim[0].label.split(","), msg.data, strict=True))["applied"] == 1.0
    assert "applied" in stats.line()
    assert monitor.stats.online is not None and not monitor.stats.online.applied


@pytest.mark.parametrize("timing", ["173 Hz jittered", "30 ms behind", "one period late"])
def test_no_jump_at_the_switch_on_late_and_jittered_imu(timing: str) -> None:
    """With the IMU late or jittered, steps are judged again once their samples come and
    what that changes is added to a later step: the switch can fall while some are
    pending. Still: bit for bit a monitor run's pose until it, and from it on the pose
    drifts from monitor's by no more than 1 % of each step's travel (the geometry's
    share), never a jump."""
    t = {x.name: x for x in TIMINGS}[timing]
    msgs = stream(MIXED, t, math.radians(0.3), 3e-4, 1, truth(MIXED, *TRUE))
    monitor, apply = pipeline("monitor"), pipeline("apply")
    gap, after = 0.0, 0
    for kind, rx, stamp, a, b in msgs:
        if kind == "i":
            monitor.feed_imu(stamp, 0.0, 0.0, a, receive_ns=rx)
            apply.feed_imu(stamp, 0.0, 0.0, a, receive_ns=rx)
            continue
        monitor.feed(stamp, NAMES, (a, b), receive_ns=rx)
        out = apply.feed(stamp, NAMES, (a, b), receive_ns=rx)
        now, other = as_tuple(apply.estimator.pose), as_tuple(monitor.estimator.pose)
        if not after and not out.note.startswith(APPLIED_NOTE):
            assert now == other  # bit for bit until the switch
            continue
        after += 1
        step = apply.estimator.last_step
        assert step is not None
        dist = math.dist(now[:2], other[:2])
        assert dist - gap <= 0.01 * abs(step.ds) + 1e-12, (after, dist, gap)
        gap = dist
        if after == 50:
            break
    assert after == 50  # it switched, and 50 steps after it were watched


def feed_all(pipe: ReadingPipeline, route: Route, timing: int = 2) -> None:
    for kind, rx, stamp, a, b in stream(route, TIMINGS[timing], math.radians(0.3), 3e-4, 1,
                                        truth(route, *TRUE)):
        if kind == "i":
            pipe.feed_imu(stamp, 0.0, 0.0, a, receive_ns=rx)
        else:
            pipe.feed(stamp, NAMES, (a, b), receive_ns=rx)


@pytest.mark.parametrize(("route", "values"), [
    (LEFT_ONLY, {}),  # never determined: turning one way only
    (MIXED, {"online_calibration_apply_sigma": 1e-5}),  # never precise enough
], ids=["left only", "sigma above the threshold"])
def test_not_applied_until_determined_and_precise(route: Route,
                                                  values: dict[str, object]) -> None:
    pipe = pipeline("apply", values=values)
    feed_all(pipe, route)
    est = pipe.stats.online
    assert est is not None and not est.applied
    assert pipe.estimator.geometry is pipe.settings.geometry
    unc = pipe.estimator.uncertainty
    assert unc is not None and unc.geometry_covariance is None


def test_without_the_gyro_it_is_disabled_and_said() -> None:
    pipe = pipeline("apply", use_imu=False)
    assert pipe.online is None and online_warning(pipe.settings) == APPLY_NEEDS_IMU


def test_back_to_monitor_at_runtime_keeps_pose_and_covariance() -> None:
    pipe = pipeline("apply")
    feed_all(pipe, MIXED)
    assert pipe.stats.online is not None and pipe.stats.online.applied
    unc = pipe.estimator.uncertainty
    assert unc is not None and unc.geometry_covariance is not None
    pose = pipe.estimator.pose
    cov = pipe.covariances()[0]
    pipe.reconfigure(pipeline("monitor").settings)
    # The next reading's step takes the configured geometry again; nothing jumps before.
    stamp = pipe.estimator.stamp_ns
    assert stamp is not None
    assert pipe.feed(stamp + 20_000_000, NAMES, (0.0, 0.0)).note == CONFIGURED_NOTE
    assert pipe.estimator.geometry is pipe.settings.geometry
    assert unc.geometry_covariance is None and pipe.estimator.pose == pose
    after = pipe.covariances()[0]
    for i in (0, 7, 35):  # x, y, yaw: the stretch folded in, not dropped
        assert after[i] == pytest.approx(cov[i], rel=1e-9)


def test_in_the_sim_the_ratios_are_within_0p1_percent_and_covered() -> None:
    """The issue's figure on one seed (the bench runs 100): 53 m, slips on."""
    for seed in (1,):
        s = sim_stream(MIXED, seed)
        pipe = pipeline("monitor")
        for kind, rx, stamp, a, b in s.messages:
            if kind == "i":
                pipe.feed_imu(stamp, 0.0, 0.0, a, receive_ns=rx)
            else:
                pipe.feed(stamp, NAMES, (a, b), receive_ns=rx)
        est = pipe.stats.online
        assert est is not None and est.determined
        (tu, tv), (u, v) = true_ratios(), est.ratios
        assert abs(u - tu) < 0.001 * tu and abs(v - tv) < 0.001 * tv
        assert mahalanobis2(est.ratios, est.covariance, (tu, tv)) < 11.83  # joint 3 sigma


def test_in_the_sim_apply_cuts_the_wheels_heading_error_fivefold() -> None:
    """100 m, slips off, one seed, the IMU at 97 Hz (the bench: 200 m, ten seeds, 173 Hz):
    the heading the wheels give with the geometry in use at each step, against the sim's
    true heading."""
    route = Route(ISSUE_ROUTE.segments * 4)
    s = sim_stream(route, 3, replace(SIM_TIMING, imu_hz=97.0), slips=False)
    pipe = pipeline("apply")
    configured = pipe.settings.geometry
    used = conf = 0.0
    stamp = 0
    for kind, rx, stamp, a, b in s.messages:
        if kind == "i":
            pipe.feed_imu(stamp, 0.0, 0.0, a, receive_ns=rx)
            continue
        out = pipe.feed(stamp, NAMES, (a, b), receive_ns=rx)
        inc = pipe.estimator.last_increment
        if out.verdict.has_new_pose and inc is not None:
            g = pipe.estimator.geometry
            used += (g.right_radius * inc.d_right - g.left_radius * inc.d_left) / g.separation
            conf += ((configured.right_radius * inc.d_right
                      - configured.left_radius * inc.d_left) / configured.separation)
    heading = s.truth[max(s.truth)][2]
    assert pipe.stats.online is not None and pipe.stats.online.applied
    assert abs(used - heading) <= 0.2 * abs(conf - heading)
