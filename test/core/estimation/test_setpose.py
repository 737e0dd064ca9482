"""~/set_pose's rule (core.estimation.setpose) through the reading pipeline.

Readings drive straight (both wheels 0.1 rad a step, radius 0.1 m: 1 cm a step, on a
50 Hz clock with a phase); expected poses are the requested ones and, after them, the
oracle's arcs from there (test/oracle.py), never the package's own step.
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from diffdrive_odom.core.bulk import fastlane
from diffdrive_odom.core.bulk.readings import JointReading
from diffdrive_odom.core.estimation.pipeline import SET_POSE_DROPPED, ReadingPipeline
from diffdrive_odom.core.estimation.setpose import PoseRefusal, PoseRequest
from diffdrive_odom.core.geometry.integration import Pose2D
from diffdrive_odom.core.uncertainty.propagation import COVARIANCE_FLOOR
from diffdrive_odom.tools.cmdline.args import load_settings

import oracle
from bagutil import write_params

NAMES = ["left_wheel_joint", "right_wheel_joint"]
T0 = 1_700_000_000 * 10**9 + 3_100_000
STEP = 20_000_000
DS = 0.01  # m per reading
YAW = 0.7


def _pipe(tmp_path: Path, **extra: object) -> ReadingPipeline:
    return ReadingPipeline(load_settings(write_params(tmp_path / "p.yaml", {
        "wheel_radius": 0.1, "wheel_separation": 0.4, **extra})))


def _feed(pipe: ReadingPipeline, k: int) -> bool:
    return pipe.feed(T0 + k * STEP, NAMES, [0.1 * k, 0.1 * k]).publish


def _cov(xx: float = 0.04, xy: float = 0.01, yy: float = 0.09, tt: float = 0.0025,
         xt: float = 0.0) -> list[float]:
    c = [0.0] * 36
    c[0], c[1], c[6], c[7], c[35] = xx, xy, xy, yy, tt
    c[5] = c[30] = xt
    c[14] = c[21] = c[28] = 1e6  # z, roll, pitch: unobserved, as robot_localization's users send
    return c


def _request(stamp_ns: int, x: float = 2.0, y: float = -1.0, yaw: float = YAW,
             frame: str = "odom", cov: list[float] | None = None,
             q: tuple[float, float, float, float] | None = None) -> PoseRequest:
    quat = q or (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))
    return PoseRequest(stamp_ns, frame, (x, y, 0.0), quat, cov if cov is not None else _cov())


def _close(p: Pose2D, want: tuple[float, float, float]) -> bool:
    x, y, th = want
    return (math.isclose(p.x, x, abs_tol=1e-12) and math.isclose(p.y, y, abs_tol=1e-12)
            and abs(math.remainder(p.theta - th, math.tau)) < 1e-12)


@pytest.mark.parametrize("stamp", [0, T0 + 10 * STEP, T0 + 3 * STEP])
def test_a_pose_at_or_before_the_last_reading_is_the_pose_at_it(tmp_path: Path,
                                                                stamp: int) -> None:
    """Stamped 0 (now), at the last reading, or earlier: nothing is re-integrated."""
    pipe = _pipe(tmp_path, publish_rate=1.0)
    for k in range(11):
        _feed(pipe, k)
    line = pipe.set_pose(_request(stamp))
    assert isinstance(line, str) and "last reading" in line and "x=2 m" in line
    assert _close(pipe.estimator.pose, (2.0, -1.0, YAW))
    assert _feed(pipe, 11)  # published at once, whatever publish_rate
    assert _close(pipe.estimator.pose, oracle.arc(DS, 0.0, (2.0, -1.0, YAW)))
    assert not _feed(pipe, 12)  # and the schedule goes on from there


def test_a_pose_stamped_ahead_is_held_until_a_reading_reaches_it(tmp_path: Path) -> None:
    pipe = _pipe(tmp_path, publish_rate=2.0)
    _feed(pipe, 0)
    ahead = T0 + 5 * STEP + 7_000_000  # between readings 5 and 6
    line = pipe.set_pose(_request(ahead))
    assert isinstance(line, str) and "held" in line
    for k in range(1, 6):
        _feed(pipe, k)
        assert _close(pipe.estimator.pose, (k * DS, 0.0, 0.0))  # not yet
    assert pipe.handover().reference is None  # the fast lane waits for it too
    assert _feed(pipe, 6)  # reached: the pose at reading 6, published
    assert _close(pipe.estimator.pose, (2.0, -1.0, YAW))
    _feed(pipe, 7)
    assert _close(pipe.estimator.pose, oracle.arc(DS, 0.0, (2.0, -1.0, YAW)))


def test_the_covariance_is_the_requested_block(tmp_path: Path) -> None:
    """Propagated: the (x, y, yaw) block, then grown by the steps; static: the diagonal."""
    pipe = _pipe(tmp_path)
    for k in range(30):
        _feed(pipe, k)
    cov = _cov(xt=0.003)
    assert isinstance(pipe.set_pose(_request(0, cov=cov)), str)
    pose_cov, _ = pipe.covariances()
    for i in (0, 7, 35):
        assert pose_cov[i] == pytest.approx(cov[i] + COVARIANCE_FLOOR, rel=1e-12)
    for i in (1, 5, 6, 30):
        assert pose_cov[i] == pytest.approx(cov[i], rel=1e-12)
    _feed(pipe, 30)
    # Driving on, it goes through the step from there: P' = F P F^T + (wheel noise, ~1e-8),
    # F = [[1, 0, -dy], [0, 1, dx], [0, 0, 1]] for the world displacement (dx, dy).
    a, b = -DS * math.sin(YAW), DS * math.cos(YAW)
    after = pipe.covariances()[0]
    assert after[0] == pytest.approx(cov[0] + 2 * a * cov[5] + a * a * cov[35], abs=1e-7)
    assert after[7] == pytest.approx(cov[7] + b * b * cov[35], abs=1e-7)
    assert after[5] == pytest.approx(cov[5] + a * cov[35], abs=1e-7)
    static = _pipe(tmp_path, covariance_model="static")
    _feed(static, 0)
    before = static.covariances()
    line = static.set_pose(_request(0))
    assert isinstance(line, str) and "static" in line
    assert static.covariances() == before and _close(static.estimator.pose, (2.0, -1.0, YAW))


@pytest.mark.parametrize(("request_", "code"), [
    (_request(0, frame="map"), "frame"),
    (_request(0, frame=""), "frame"),
    (_request(0, x=math.nan), "non_finite"),
    (_request(0, q=(0.0, 0.0, 0.0, 2.0)), "quaternion"),
    (_request(0, q=(0.0, 0.0, 0.0, 0.0)), "quaternion"),
    (_request(0, q=(0.0, 0.0, math.inf, 1.0)), "non_finite"),
    (_request(0, cov=_cov(xx=-0.01)), "covariance"),
    (_request(0, cov=_cov(xx=0.01, yy=0.01, xy=0.02)), "covariance"),  # |xy| > sqrt(xx yy)
    (_request(0, cov=[*_cov()[:35], math.nan]), "covariance"),
    (_request(0, cov=_cov()[:9]), "covariance"),
    (PoseRequest(0, "odom", (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0),
                 [*_cov()[:1], 0.5, *_cov()[2:]]), "covariance"),  # not symmetric
])
def test_what_is_refused_changes_nothing(tmp_path: Path, request_: PoseRequest,
                                         code: str) -> None:
    pipe = _pipe(tmp_path)
    for k in range(3):
        _feed(pipe, k)
    before = pipe.covariances()
    out = pipe.set_pose(request_)
    assert isinstance(out, PoseRefusal) and out.code == code and out.reason
    assert _close(pipe.estimator.pose, (2 * DS, 0.0, 0.0)) and pipe.covariances() == before
    if code == "frame":
        assert "'odom'" in out.reason


def test_the_yaw_of_any_unit_quaternion_and_a_near_unit_one(tmp_path: Path) -> None:
    """Roll and pitch are dropped: the yaw of q = yaw(a) * pitch(b), and |q|^2 = 1.005."""
    pipe = _pipe(tmp_path)
    _feed(pipe, 0)
    a, b = -2.9, 0.2
    qz = (0.0, 0.0, math.sin(a / 2), math.cos(a / 2))
    qy = (0.0, math.sin(b / 2), 0.0, math.cos(b / 2))
    x1, y1, z1, w1 = qz
    x2, y2, z2, w2 = qy
    q = (w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2, w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
         w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2, w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2)
    assert isinstance(pipe.set_pose(_request(0, q=q)), str)
    assert abs(math.remainder(pipe.estimator.pose.theta - a, math.tau)) < 1e-12
    s = math.sqrt(1.005)
    scaled = (qz[0] * s, qz[1] * s, qz[2] * s, qz[3] * s)
    assert isinstance(pipe.set_pose(_request(0, q=scaled)), str)
    assert abs(math.remainder(pipe.estimator.pose.theta - a, math.tau)) < 1e-12


def test_a_held_pose_is_dropped_by_a_reset_or_a_time_reset(tmp_path: Path) -> None:
    pipe = _pipe(tmp_path)
    _feed(pipe, 100)
    pipe.set_pose(_request(T0 + 200 * STEP))
    pipe.reset()
    for k in range(101, 202):
        _feed(pipe, k)
    assert _close(pipe.estimator.pose, (101 * DS, 0.0, 0.0))  # never set
    pipe.set_pose(_request(T0 + 300 * STEP))
    out = pipe.feed(T0, NAMES, [0.0, 0.0])  # 4 s back: a bag looping
    assert out.note == SET_POSE_DROPPED
    for k in range(1, 400):
        _feed(pipe, k)
    assert _close(pipe.estimator.pose, (399 * DS, 0.0, 0.0))


def test_before_any_reading_a_pose_waits_for_the_first(tmp_path: Path) -> None:
    pipe = _pipe(tmp_path)
    assert "held" in str(pipe.set_pose(_request(0)))
    assert _feed(pipe, 0)
    assert _close(pipe.estimator.pose, (2.0, -1.0, YAW))


def test_the_fast_lane_meets_a_held_pose_as_the_pipeline_does(tmp_path: Path) -> None:
    """Replay's fast lane and the per-reading path, with a pose held mid-stream."""
    readings = [JointReading(T0 + k * STEP, 0, tuple(NAMES), (0.1 * k, 0.1 * k), ())
                for k in range(2000)]
    slow, fast = _pipe(tmp_path, publish_rate=7.0), _pipe(tmp_path, publish_rate=7.0)
    for pipe in (slow, fast):
        pipe.feed(T0 - STEP, NAMES, [-0.1, -0.1])
        pipe.set_pose(_request(T0 + 1234 * STEP + 5))
    for r in readings:
        slow.feed(r.stamp_ns, r.names, r.position)
    stretches = sum(isinstance(item, fastlane.Stretch)
                    for item in fastlane.lanes(fast, readings, receive=False))
    assert stretches > 0
    assert fast.estimator.pose == slow.estimator.pose
    assert _close(slow.estimator.pose, oracle.arc(764 * DS, 0.0, (2.0, -1.0, YAW)))
    assert fast.stats.published == slow.stats.published
