"""Every count counted (issue 37): a held reading released late, a gap in the log.

The robot drives :mod:`circledrive`'s circle, so the pose after any stretch is the
oracle's arc however the readings are grouped, held or lost. A logger holds a
reading (repeats its counts) and writes the moved counts 1 ms after its previous row;
it stops writing for seconds while the counts go on. Restarts are what a driver does:
counters back at zero or at their start, or a jump no wheel could drive.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest
from circledrive import (
    NAMES,
    PERIOD,
    B,
    R,
    V,
    W,
    assert_pose,
    circle,
    ns,
    positions,
)

from diffdrive_odom.core.estimation.pipeline import ReadingPipeline
from diffdrive_odom.core.estimation.wheels.config import EstimatorConfig
from diffdrive_odom.core.estimation.wheels.encoders import EncoderConfig, Reason
from diffdrive_odom.core.estimation.wheels.estimator import OdometryEstimator
from diffdrive_odom.core.estimation.wheels.timeline import Status, Verdict
from diffdrive_odom.core.geometry.integration import Pose2D
from diffdrive_odom.core.geometry.kinematics import Geometry
from diffdrive_odom.core.geometry.se2 import wrap_angle
from diffdrive_odom.core.health.diagnostics import ReadingHealth, odometry_report
from diffdrive_odom.core.uncertainty.noise import NoiseModel, unknown_path
from diffdrive_odom.settings.odometry import odometry_settings

import oracle

RELEASE = 0.001  # s: the moved counts, written 1 ms after the previous row


def estimator(noise: NoiseModel | None = None, **config: float) -> OdometryEstimator:
    return OdometryEstimator(Geometry(R, B), EncoderConfig(("left_wheel_joint",),
                                                           ("right_wheel_joint",)),
                             EstimatorConfig(**config), noise)  # type: ignore[arg-type]


Row = tuple[float, list[float]]  # stamp [s after T0], positions


def held_rows(hold_from: float, hold_to: float, end: float) -> list[Row]:
    """Readings every PERIOD to ``end``; from ``hold_from`` the counts are held until
    the row before ``hold_to``, whose moved counts come 1 ms after that row."""
    rows: list[Row] = []
    k = 0
    while PERIOD * k <= end + 1e-9:
        t = PERIOD * k
        if hold_from < t < hold_to:
            rows.append((t, positions(hold_from)))
            if t + PERIOD >= hold_to:  # released: the counts of its own stamp
                rows.append((t + RELEASE, positions(t + RELEASE)))
        else:
            rows.append((t, positions(t)))
        k += 1
    return rows


def feed(est: OdometryEstimator, rows: list[Row]) -> list[Verdict]:
    return [est.update(ns(t), NAMES, p) for t, p in rows]


# ---------------------------------------------------------- held readings (item 1)


def test_a_held_reading_released_1_ms_later_is_integrated_not_skipped() -> None:
    """0.28 s held then released 1 ms after the last row: 1.7 rad of the right wheel in
    1 ms is 1700 rad/s over the step, but 6 rad/s over the 0.28 s since the counts last
    changed. Nothing is skipped, the pose is the circle, the twist the true one."""
    est = estimator()
    rows = held_rows(1.0, 1.3, 2.0)
    verdicts = feed(est, rows)
    assert all(v.status in (Status.REFERENCE, Status.UPDATED) for v in verdicts), [
        v.reason for v in verdicts if v.status is not Status.UPDATED]
    at = next(k for k, (t, _) in enumerate(rows) if round(t * 1e3) % 20)  # the release
    replay = estimator()
    feed(replay, rows[:at + 1])
    assert_pose(replay.pose, circle(rows[at][0]))
    assert replay.linear == pytest.approx(V, rel=1e-9)  # over the whole 0.28 s
    assert replay.angular == pytest.approx(W, rel=1e-9)
    assert replay.last_step is not None
    assert replay.last_step.dt == pytest.approx(rows[at][0] - 1.0, abs=1e-9)
    assert_pose(est.pose, circle(2.0))


def test_the_hold_changes_nothing_but_the_poses_while_held() -> None:
    """The stream with the held rows and the same stream without them (the row before
    the hold, then the release): the same pose, twist and covariances after the release
    (the twist and its covariance take the interval since the counts last changed)."""
    rows = held_rows(1.0, 1.3, 1.5)
    plain = [r for r in rows if not (1.0 < r[0] < 1.28)]
    a, b = estimator(NoiseModel()), estimator(NoiseModel())
    feed(a, rows)
    feed(b, plain)
    assert_pose(a.pose, b.pose, 1e-12)
    assert (a.linear, a.angular) == pytest.approx((b.linear, b.angular), rel=1e-12)
    ua, ub = a.uncertainty, b.uncertainty
    assert ua is not None and ub is not None
    assert np.allclose(ua.covariance, ub.covariance, rtol=1e-12, atol=0.0)
    assert np.allclose(ua.twist_covariance(), ub.twist_covariance(), rtol=1e-12, atol=0.0)


def test_the_interval_is_capped_at_max_reading_gap() -> None:
    """Counts standing 5 s, then 5 rad in one reading with max_wheel_speed 4: over the
    5 s since they last changed that is 1 rad/s, but the interval is capped at
    max_reading_gap (1 s): 5 rad/s, skipped; 3 rad passes."""
    rows = [(PERIOD * k, [0.0, 0.0]) for k in range(251)]  # 5 s standing
    for moved, status in ((5.0, Status.REANCHORED), (3.0, Status.UPDATED)):
        est = estimator(max_wheel_speed=4.0)
        feed(est, rows)
        verdict = est.update(ns(5.0 + PERIOD), NAMES, [moved, moved])
        assert verdict.status is status, verdict.reason
    assert "in 1 s" in feed(estimator(max_wheel_speed=4.0), [*rows, (5.02, [5.0, 5.0])])[-1].reason


def test_a_spike_on_a_released_reading_is_judged_over_its_own_step() -> None:
    """40 rad on the left wheel of the reading that ends a 0.28 s hold: over the hold
    that is 143 rad/s (under max_wheel_speed), but no wheel at 4 rad/s before it gets
    there within max_wheel_acceleration 20 rad/s^2: judged over its own 1 ms, skipped.
    The readings after it come back: the pose is the circle less those two steps."""
    rows = held_rows(1.0, 1.3, 2.0)
    at = next(k for k, (t, _) in enumerate(rows) if round(t * 1e3) % 20)
    rows[at] = (rows[at][0], [rows[at][1][0] + 40.0, rows[at][1][1]])
    est = estimator()
    verdicts = feed(est, rows)
    assert verdicts[at].code is Reason.TOO_FAST and "in 0.001 s" in verdicts[at].reason
    assert verdicts[at + 1].code is Reason.TOO_FAST  # back from the spike: skipped too
    assert all(v.status is Status.UPDATED for v in verdicts[at + 2:])
    # Lost: the motion of the hold (1.0 -> release) and of the step after it.
    lost = (rows[at + 1][0] - 1.0)
    want = oracle.arc(V * (2.0 - lost), W * (2.0 - lost))
    assert_pose(est.pose, Pose2D(*want))


# --------------------------------------------------------------- gaps (item 2)


def drive_with_gap(est: OdometryEstimator, gap_from: float, gap_to: float, end: float,
                   after: Callable[[float], list[float]] = positions) -> list[Verdict]:
    """Readings every PERIOD to ``end`` but none in (gap_from, gap_to); ``after``: the
    positions from ``gap_to`` on (the counts going on: the true angles)."""
    out = []
    for k in range(round(end / PERIOD) + 1):
        t = PERIOD * k
        if gap_from < t < gap_to - 1e-9:
            continue
        out.append(est.update(ns(t), NAMES, positions(t) if t <= gap_from else after(t)))
    return out


@pytest.mark.parametrize("gap_s", [1.5, 3.0, 5.0])
def test_a_gap_whose_counts_went_on_is_integrated_as_one_arc(gap_s: float) -> None:
    """On a circle one arc is the exact path: the pose is the circle at the end."""
    est = estimator()
    verdicts = drive_with_gap(est, 1.0, 1.0 + gap_s, 1.0 + gap_s + 1.0)
    codes = [v.code for v in verdicts]
    assert codes.count(Reason.GAP_INTEGRATED) == 1 and Reason.GAP not in codes
    named = next(v for v in verdicts if v.code is Reason.GAP_INTEGRATED)
    assert named.status is Status.UPDATED and named.warning == "after a gap"
    assert f"{gap_s:.3f} s without a reading" in named.reason
    assert_pose(est.pose, circle(2.0 + gap_s))
    assert est.linear == pytest.approx(V, rel=1e-9)  # the steps after it, not the gap's


def test_an_integrated_gap_is_named_once_in_the_log_and_in_diagnostics() -> None:
    """The node's pipeline fed the circle with a 2 s gap: one warning (the log), one
    ``gap_integrated`` in its counters, and /diagnostics' report names it in the second
    that saw it, not in the next one, while its count stays in the values."""
    pipe = ReadingPipeline(odometry_settings({"wheel_radius": R, "wheel_separation": B}))
    warned = []
    for k in range(round(4.0 / PERIOD) + 1):
        t = PERIOD * k
        if not 1.0 < t < 3.0 - 1e-9:
            out = pipe.feed(ns(t), NAMES, positions(t))
            warned += [out.verdict.code] if out.verdict.warning else []
    assert warned == [Reason.GAP_INTEGRATED]
    stats = pipe.stats
    assert stats.gaps_integrated == 1 and stats.gap_reanchors == 0 and stats.reanchors == 0

    def health(uptime: float) -> ReadingHealth:
        return ReadingHealth(uptime_s=uptime, reading_rate_hz=50.0, since_last_reading_s=0.01,
                             dropped=dict(stats.dropped), reanchors=stats.reanchors,
                             causes=dict(stats.causes), gap_reanchors=stats.gap_reanchors,
                             gaps_integrated=stats.gaps_integrated,
                             time_resets=stats.time_resets)

    first = odometry_report(health(4.0))
    assert first.message == "1 gaps in the readings, their motion integrated from the counts"
    later = odometry_report(health(5.0), health(4.0))
    assert "gap" not in later.message, later.message
    assert dict(later.values)["gaps integrated"] == "1"


def test_the_gaps_covariance_grows_by_the_unknown_path() -> None:
    """The covariance after the gap is the one-arc step's propagation plus
    ``unknown_path`` of that arc (which test_unknown_path checks against quadrature):
    the same estimator fed the gap's two readings as one ordinary step (max_reading_gap
    off) has exactly that much less."""
    gap = estimator(NoiseModel())
    drive_with_gap(gap, 1.0, 3.0, 3.02)  # the held reading and the one that continues it
    plain = estimator(NoiseModel(), max_reading_gap=math.inf)
    drive_with_gap(plain, 1.0, 3.0, 3.02)
    assert_pose(gap.pose, plain.pose, 1e-12)
    ug, up = gap.uncertainty, plain.uncertainty
    assert ug is not None and up is not None
    added = np.asarray(unknown_path(circle(1.0).theta, V * 2.0, W * 2.0))
    assert added[0, 0] > 0.0 and added[1, 1] > 0.0
    # The step after the gap carries a term of no heading variance along unchanged
    # (its Jacobian moves x, y by the heading's variance only).
    assert np.allclose(np.asarray(ug.covariance) - np.asarray(up.covariance), added,
                       rtol=1e-9, atol=1e-18)


GAP_END = 2.5  # s: the gap from 1.0 s, past max_reading_gap


@pytest.mark.parametrize(("back", "why"), [
    (lambda t: positions(t - GAP_END), "back at zero"),
    (lambda t: [7.0 + a for a in positions(t - GAP_END)], "back at their start values"),
    (lambda t: [1.0 + a for a in positions(t - GAP_END)], "mean speed over the gap"),
], ids=["zero", "start", "jump back"])
def test_a_driver_restart_after_a_gap_is_a_new_reference(
        back: Callable[[float], list[float]], why: str) -> None:
    """Counters from 7 rad at the start; 1.5 s without readings; then counting again
    from 0, from 7 (the start), or from 1 (a jump back of 10 and 12 rad, no wheel driving
    4 and 6 rad/s before and after drives that in 1.5 s with max_wheel_acceleration 20):
    the pose carries on from before the gap, the step after the held reading added."""
    est = estimator()
    for k in range(51):
        est.update(ns(PERIOD * k), NAMES, [7.0 + a for a in positions(PERIOD * k)])
    before = est.pose
    assert est.update(ns(GAP_END), NAMES, back(GAP_END)).status is Status.HELD
    verdict = est.update(ns(GAP_END + PERIOD), NAMES, back(GAP_END + PERIOD))
    assert verdict.code is Reason.GAP and why in verdict.reason, verdict.reason
    assert "driver restart" in verdict.reason and verdict.warning == "re-anchored"
    d = [b - a for a, b in zip(back(GAP_END), back(GAP_END + PERIOD), strict=True)]
    want = oracle.arc(R * (d[0] + d[1]) / 2, R * (d[1] - d[0]) / B,
                      (before.x, before.y, before.theta))
    assert_pose(est.pose, Pose2D(*want))


COUNTER = EncoderConfig(("left_wheel_joint",), ("right_wheel_joint",), 4096.0, 16)
WRAP = 65536 * 2 * math.pi / 4096  # rad of wheel angle a 16-bit counter spans: 100.5


def counter(angles: list[float]) -> list[float]:
    return [float(round(a * 4096 / (2 * math.pi)) % 65536) for a in angles]


@pytest.mark.parametrize(("acceleration", "integrated"), [(20.0, True), (100.0, False)])
def test_a_wrapping_counters_gap_is_read_by_the_wheels_speeds(
        acceleration: float, integrated: bool) -> None:
    """Wheels at 24 and 26 rad/s, a 3 s gap: 72 and 78 rad, more than half the
    counter's 100.5 rad, so the shortest difference would read -28.5 and -22.5 rad.
    Read within what the speeds before and after allow (+-15 rad/s of mean speed with
    max_wheel_acceleration 20 over 3 s), one whole wrap more is the only reading: the
    motion is integrated. With 100, several readings fit: a restart, the counts cannot
    tell (the gap's motion lost)."""
    speeds = (24.0, 26.0)
    est = OdometryEstimator(Geometry(R, B), COUNTER,
                            EstimatorConfig(max_wheel_acceleration=acceleration))
    verdicts = {}
    for k in range(round(5.0 / PERIOD) + 1):
        t = PERIOD * k
        if not 1.0 < t < 4.0 - 1e-9:
            verdicts[k] = est.update(ns(t), NAMES, counter([w * t for w in speeds]))
    verdict = verdicts[round(4.02 / PERIOD)]
    assert verdict.code is (Reason.GAP_INTEGRATED if integrated else Reason.GAP), verdict
    if not integrated:
        assert "16-bit counter makes the gap ambiguous" in verdict.reason, verdict.reason
    q = 2 * math.pi / 4096

    def turned(t0: float, t1: float) -> float:  # the counts' own heading change
        left, right = (round(w * t1 / q) - round(w * t0 / q) for w in speeds)
        return R * q * (right - left) / B

    want = turned(0.0, 5.0) if integrated else turned(0.0, 1.0) + turned(4.0, 5.0)
    assert est.pose.theta == pytest.approx(wrap_angle(want), abs=1e-9)


def test_unknown_path_is_the_spread_of_the_headings_over_the_turn() -> None:
    """Against a midpoint quadrature of (cos phi, sin phi), phi uniform on [0, dtheta],
    rotated by the start heading; zero for a straight gap and a turn on the spot."""
    for theta, ds, dtheta in [(0.3, 0.5, 1.2), (-2.0, 1.5, -0.4), (1.0, 0.2, 3.0),
                              (0.7, 2.0, 0.004), (0.0, 1.0, -1e-7)]:
        phi = (np.arange(200_000) + 0.5) / 200_000 * dtheta
        pts = ds * np.column_stack((np.cos(phi + theta), np.sin(phi + theta)))
        want = np.cov(pts.T, bias=True)
        got = np.asarray(unknown_path(theta, ds, dtheta))
        assert np.allclose(got[:2, :2], want, rtol=1e-6, atol=1e-14), (theta, ds, dtheta)
        assert not got[2].any() and not got[:, 2].any()
    assert not np.asarray(unknown_path(0.4, 2.0, 0.0)).any()
    assert not np.asarray(unknown_path(0.4, 0.0, 1.0)).any()
