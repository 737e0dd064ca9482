"""ReadingPipeline: the one path every reading takes (node, replay, demo) and its counters.

Expected counts are the readings written here, one by one; expected poses are the
wheel angles times the radius (straight lines).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import pytest

from diffdrive_odom.core.bulk import batch
from diffdrive_odom.core.bulk.readings import JointReading
from diffdrive_odom.core.estimation.config import OdometrySettings
from diffdrive_odom.core.estimation.pipeline import VELOCITY_ON, ReadingPipeline
from diffdrive_odom.core.estimation.publication import (
    COVARIANCE_REFUSED,
    NON_FINITE,
    ODOMETRY_REFUSED,
    Publication,
    pipeline_publication,
    publication,
)
from diffdrive_odom.core.estimation.wheels.encoders import Reason
from diffdrive_odom.core.estimation.wheels.timeline import Status
from diffdrive_odom.core.geometry.integration import Pose2D
from diffdrive_odom.ros.throttle import KeyedThrottle
from diffdrive_odom.tools.cmdline.args import load_settings

from bagutil import write_params

NAMES = ["left_wheel_joint", "right_wheel_joint"]
T0 = 1_700_000_000 * 10**9
STEP = 20_000_000  # 50 Hz
R = 0.1


def settings(tmp_path: Path, **extra: object) -> OdometrySettings:
    values = {"wheel_radius": R, "wheel_separation": 0.4, **extra}
    return load_settings(write_params(tmp_path / "p.yaml", values))


def test_zero_and_negative_stamps_are_dropped_before_the_estimator(tmp_path: Path) -> None:
    pipe = ReadingPipeline(settings(tmp_path))
    for stamp in (0, -5):
        out = pipe.feed(stamp, NAMES, [0.0, 0.0])
        assert out.verdict.status is Status.DROPPED and out.verdict.code is Reason.ZERO_STAMP
        assert not out.publish and "stamp" in out.verdict.reason
    assert pipe.estimator.stamp_ns is None  # never became the reference
    assert pipe.stats.dropped == {"zero_stamp": 2}
    assert pipe.stats.last_usable_stamp_ns is None


def test_counters_count_each_rule_once(tmp_path: Path) -> None:
    pipe = ReadingPipeline(settings(tmp_path, publish_rate=10.0, max_wheel_speed=100.0))
    feeds = [
        (T0, NAMES, [0.0, 0.0]),  # reference, published
        (T0 + STEP, NAMES, [0.1, 0.1]),  # updated, gated (20 ms < 100 ms)
        (T0 + 2 * STEP, ["x", "y"], [0.1, 0.1]),  # missing_joint
        (T0 + 3 * STEP, NAMES, [0.1]),  # bad_array
        (T0 + 4 * STEP, NAMES, [math.nan, 0.1]),  # non_finite
        (T0 + STEP, NAMES, [0.1, 0.1]),  # stale_stamp
        (0, NAMES, [0.1, 0.1]),  # zero_stamp
        (T0 + 5 * STEP, NAMES, [50.0, 50.0]),  # too_fast: re-anchored
        (T0 + 6 * STEP, NAMES, [50.2, 50.2]),  # updated, published (120 ms after T0)
        (T0 + 6 * STEP + 100 * 10**9, NAMES, [60.0, 60.0]),  # 100 s ahead: held
        (T0 + 7 * STEP, NAMES, [50.4, 50.4]),  # back on time: the held one was an outlier
        (T0 + 7 * STEP + 3 * 10**9, NAMES, [0.0, 0.0]),  # 3 s ahead: held
        (T0 + 8 * STEP + 3 * 10**9, NAMES, [0.1, 0.1]),  # continued: gap, published
        # Back to before the gap (a return to the old timeline would be after its last
        # reading): time reset, published.
        (T0 + STEP // 2, NAMES, [0.0, 0.0]),
    ]
    outcomes = [pipe.feed(*f) for f in feeds]
    assert [o.publish for o in outcomes] == [True, False, False, False, False, False, False,
                                             False, True, False, False, False, True, True]
    s = pipe.stats
    assert s.readings == len(feeds) and s.published == 4
    assert s.dropped == {"missing_joint": 1, "bad_array": 1, "non_finite": 1,
                         "stale_stamp": 1, "zero_stamp": 1, "future_stamp": 1}
    assert s.dropped_total == 6
    assert (s.reanchors, s.gap_reanchors, s.time_resets) == (1, 1, 1)
    assert s.last_usable_stamp_ns == T0 + STEP // 2
    assert not s.velocity_fallback
    assert outcomes[9].verdict.status is Status.HELD
    assert outcomes[10].verdict.code is Reason.FUTURE_STAMP
    assert outcomes[12].verdict.code is Reason.GAP
    assert "max_reading_gap" in outcomes[12].verdict.reason


def test_the_snapshot_is_read_only_and_does_not_move(tmp_path: Path) -> None:
    pipe = ReadingPipeline(settings(tmp_path))
    pipe.feed(0, NAMES, [0.0, 0.0])
    snap = pipe.stats
    with pytest.raises(dataclasses.FrozenInstanceError):
        snap.readings = 7  # type: ignore[misc]
    with pytest.raises(TypeError):
        snap.dropped["zero_stamp"] = 9  # type: ignore[index]
    pipe.feed(0, NAMES, [0.0, 0.0])
    assert snap.readings == 1 and snap.dropped == {"zero_stamp": 1}
    assert pipe.stats.readings == 2


def test_velocity_fallback_is_noted_once_per_change(tmp_path: Path) -> None:
    pipe = ReadingPipeline(settings(tmp_path))
    nan2 = [math.nan, math.nan]
    notes = [pipe.feed(T0 + k * STEP, NAMES, nan2, [1.0, 1.0]).note for k in range(51)]
    assert notes[0] == VELOCITY_ON and not any(notes[1:])
    assert pipe.stats.velocity_fallback
    # 1 rad/s for 1 s on both wheels.
    assert math.isclose(pipe.estimator.pose.x, R * 1.0, abs_tol=1e-12)
    back = pipe.feed(T0 + 51 * STEP, NAMES, [3.0, 3.0], [1.0, 1.0])
    assert back.verdict.code is Reason.INPUT_SWITCH and "positions" in back.note
    assert not pipe.stats.velocity_fallback


def test_reset_and_reconfigure_go_through_the_pipeline(tmp_path: Path) -> None:
    pipe = ReadingPipeline(settings(tmp_path, publish_rate=1.0))
    assert pipe.feed(T0, NAMES, [0.0, 0.0]).publish
    assert not pipe.feed(T0 + STEP, NAMES, [1.0, 1.0]).publish  # gated
    pipe.reset()
    assert pipe.estimator.pose == Pose2D()
    out = pipe.feed(T0 + 2 * STEP, NAMES, [2.0, 2.0])
    assert out.publish  # the gate forgot: the reset pose goes out at once
    assert math.isclose(pipe.estimator.pose.x, R * 1.0, abs_tol=1e-12)
    # A new max_reading_gap: the pose carries on, the next reading is a reference.
    pipe.reconfigure(settings(tmp_path, publish_rate=0.0, max_reading_gap=0.5))
    assert pipe.estimator.config.max_reading_gap == 0.5
    assert pipe.feed(T0 + 3 * STEP, NAMES, [9.0, 9.0]).verdict.status is Status.REFERENCE
    assert math.isclose(pipe.estimator.pose.x, R * 1.0, abs_tol=1e-12)
    assert pipe.feed(T0 + 4 * STEP, NAMES, [9.5, 9.5]).publish  # rate 0: every reading
    assert math.isclose(pipe.estimator.pose.x, R * 1.5, abs_tol=1e-12)
    assert pipe.stats.readings == 5  # counters carry on across reset and reconfigure


def test_the_demo_reintegrates_through_the_same_rules(tmp_path: Path) -> None:
    """The demo's calibrated rows come from the batch path, which takes its steps from
    the pipeline: an unstamped reading is dropped there as in the node."""
    s = settings(tmp_path)
    readings = [JointReading(T0 + k * STEP, 0, tuple(NAMES), (0.1 * k, 0.1 * k), ())
                for k in range(51)]
    readings.insert(25, JointReading(0, 0, tuple(NAMES), (99.0, 99.0), ()))
    steps = batch.wheel_steps(readings, s)
    assert len(steps) == 50
    assert math.isclose(batch.final_pose(steps, s.geometry).x, R * 5.0, abs_tol=1e-12)


def test_the_publication_rule_refuses_anything_non_finite() -> None:
    """The one rule of what goes out (the node and replay both call it): a NaN or inf in
    the pose, the twist or either covariance keeps the pose back, with the reason."""
    zeros = [0.0] * 36
    ok = publication(Pose2D(1.0, 2.0, 0.5), 0.3, -0.1, zeros, zeros)
    assert isinstance(ok, Publication)
    assert (ok.pose, ok.linear, ok.angular) == (Pose2D(1.0, 2.0, 0.5), 0.3, -0.1)
    assert ok.pose_covariance is zeros and ok.twist_covariance is zeros  # as given
    for bad in (math.nan, math.inf, -math.inf):
        cov = [0.0] * 35 + [bad]
        assert publication(Pose2D(), 0.0, 0.0, cov, zeros) is COVARIANCE_REFUSED
        assert publication(Pose2D(), 0.0, 0.0, zeros, cov) is COVARIANCE_REFUSED
        for pose, linear, angular in ((Pose2D(bad, 0.0, 0.0), 0.0, 0.0),
                                      (Pose2D(0.0, 0.0, bad), 0.0, 0.0),
                                      (Pose2D(), bad, 0.0), (Pose2D(), 0.0, bad)):
            # The pose is checked first: its covariance is made from it.
            assert publication(pose, linear, angular, cov, cov) is ODOMETRY_REFUSED
    assert COVARIANCE_REFUSED.code == ODOMETRY_REFUSED.code == NON_FINITE
    assert COVARIANCE_REFUSED.reason == "non-finite covariance suppressed"
    assert ODOMETRY_REFUSED.reason == "non-finite odometry suppressed"


def test_a_valid_but_absurd_geometry_makes_the_covariance_non_finite_and_it_is_refused(
        tmp_path: Path) -> None:
    """Real input, no patching: a 4e-301 m axle (0.4 m times a separation multiplier of
    1e-300, which the parameter checks accept; a wheel_separation under 1 mm they refuse)
    driven straight keeps a finite pose, but heading variance ~ wheel variance / b**2
    overflows."""
    pipe = ReadingPipeline(settings(tmp_path, wheel_separation_multiplier=1e-300))
    first = pipe.feed(T0, NAMES, [0.0, 0.0])
    assert first.publish and isinstance(pipeline_publication(pipe), Publication)
    out = pipe.feed(T0 + STEP, NAMES, [0.1, 0.1])
    assert out.publish and pipe.estimator.pose == Pose2D(R * 0.1, 0.0, 0.0)
    pose_cov, twist_cov = pipe.covariances()
    assert not all(map(math.isfinite, [*pose_cov, *twist_cov]))
    assert pipeline_publication(pipe) is COVARIANCE_REFUSED


def test_keyed_throttle_holds_back_per_key_only() -> None:
    lines: list[str] = []

    class Logger:
        def warning(self, text: str) -> None:
            lines.append(text)

        def info(self, text: str) -> None:
            lines.append(text)

    now = [0.0]
    throttle = KeyedThrottle(Logger(), 5.0, clock=lambda: now[0])
    assert throttle.warning("bad_array", "short")
    assert throttle.warning("non_finite", "nan")  # another key: at once
    assert not throttle.warning("bad_array", "short")
    assert not throttle.warning("bad_array", "short")
    now[0] = 5.0
    assert throttle.warning("bad_array", "short")
    assert lines == ["short", "nan", "short (2 more like this since the last report)"]
