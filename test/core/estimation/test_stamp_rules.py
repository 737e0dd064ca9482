"""A driver's clock and its stamps, without DDS: bursts of far-future stamps, a clock that
changes for good, a clock that was never synced (``stamp_source``), malformed arrays.

The robot drives one circle: constant wheel speeds (4 and 6 rad/s, r = 0.1 m,
b = 0.4 m: 0.5 m/s and 0.5 rad/s), so the pose after any stretch of motion is one arc
of the oracle's closed form, however the readings are grouped. Whatever happens to the
stamps, the encoder positions are the true cumulative wheel angles.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import numpy as np
import pytest
from circledrive import (
    NAMES,
    PERIOD,
    T0,
    B,
    R,
    V,
    W,
    assert_pose,
    circle,
    ns,
    positions,
)

from diffdrive_odom.core.bulk import batch
from diffdrive_odom.core.bulk.readings import JointReading
from diffdrive_odom.core.estimation.config import OdometrySettings
from diffdrive_odom.core.estimation.pipeline import ReadingPipeline
from diffdrive_odom.core.estimation.results import Outcome
from diffdrive_odom.core.estimation.stamps import CLOCK_OFFSET_WARN_S, StampSource
from diffdrive_odom.core.estimation.wheels.config import EstimatorConfig
from diffdrive_odom.core.estimation.wheels.encoders import EncoderConfig, Reason
from diffdrive_odom.core.estimation.wheels.estimator import OdometryEstimator
from diffdrive_odom.core.estimation.wheels.timeline import ADOPT_CLOCK_AFTER_S, Status
from diffdrive_odom.core.geometry.integration import Pose2D
from diffdrive_odom.core.geometry.kinematics import Geometry
from diffdrive_odom.settings.errors import ParameterError
from diffdrive_odom.tools.bags import bagio, bagwriter
from diffdrive_odom.tools.cli import main as cli
from diffdrive_odom.tools.cmdline.args import load_settings
from diffdrive_odom.tools.replaying.readings import replay_readings
from diffdrive_odom.tools.replaying.sinks import Published

import oracle
from bagutil import mcap_messages, write_params

BURST = 1000.0  # s the driver's clock jumps ahead
T = TypeVar("T")


def estimator() -> OdometryEstimator:
    return OdometryEstimator(Geometry(wheel_radius=R, wheel_separation=B),
                             EncoderConfig(("left_wheel_joint",), ("right_wheel_joint",)),
                             EstimatorConfig())


def pipeline(tmp_path: Path, **extra: object) -> ReadingPipeline:
    return ReadingPipeline(settings(tmp_path, **extra))


def settings(tmp_path: Path, **extra: object) -> OdometrySettings:
    values = {"wheel_radius": R, "wheel_separation": B, **extra}
    return load_settings(write_params(tmp_path / "p.yaml", values))


def burst_stamp(t: float) -> float:
    """The issue's driver: one second (1.0 <= t < 2.0) stamped 1000 s ahead."""
    return t + BURST if 1.0 <= t < 2.0 - 1e-9 else t


def drive(feed: Callable[[int, list[float], int], T], seconds: float,
          stamp: Callable[[float], float] = lambda t: t) -> list[T]:
    """Readings every PERIOD from true time 0 to ``seconds``: stamp(t), received at t."""
    return [feed(ns(stamp(PERIOD * k)), positions(PERIOD * k), ns(PERIOD * k))
            for k in range(round(seconds / PERIOD) + 1)]


# ------------------------------------------------ a burst of far-future stamps (item 4)


def test_a_burst_of_far_future_stamps_costs_neither_the_timeline_nor_the_pose() -> None:
    """No receive times (a caller that has none): on main the burst was adopted as a
    driver restart and the return taken as a time reset, back at the origin."""
    est = estimator()
    verdicts = drive(lambda s, p, _r: est.update(s, NAMES, p), 3.0, burst_stamp)
    statuses = [v.status for v in verdicts]
    assert Status.TIME_RESET not in statuses
    back = verdicts[100]  # t = 2.0: the old timeline again
    assert back.status is Status.UPDATED and back.code is Reason.FUTURE_STAMP
    assert back.count == 50 and back.dropped_code is Reason.FUTURE_STAMP
    assert "1000.020 s after the last usable one" in back.reason and back.warning == "dropped"
    assert_pose(est.pose, circle(3.0))
    assert est.linear == pytest.approx(V, rel=1e-9)
    assert est.angular == pytest.approx(W, rel=1e-9)


def test_the_burst_is_integrated_from_the_old_reading_when_it_returns() -> None:
    """At the return the pose is exactly the circle at t = 2 s: the step from the last
    reading before the burst covers every motion since (positions are cumulative)."""
    est = estimator()
    for k in range(101):
        t = PERIOD * k
        est.update(ns(burst_stamp(t)), NAMES, positions(t))
    assert_pose(est.pose, circle(2.0))
    assert est.stamp_ns == ns(2.0) and not est.on_trial


def test_with_receive_times_the_burst_is_never_published(tmp_path: Path) -> None:
    """Received in real time: the stamps jumped 1000 s in 20 ms, no pause. Nothing
    stamped in the future goes out (tf2 would refuse the real stamps after it for its
    whole cache), the burst's 50 readings are counted, the pose is the circle."""
    pipe = pipeline(tmp_path)
    outcomes = drive(
        lambda s, p, r: pipe.feed(s, NAMES, p, (), r), 3.0, burst_stamp)
    published = [o.stamp_ns for o in outcomes if o.publish]
    assert max(published) == ns(3.0) and len(published) == 151 - 50
    held = outcomes[51].verdict
    assert held.status is Status.HELD and held.code is Reason.CLOCK_JUMP
    assert held.warning == "held" and "1000.020 s ahead while 0.020 s passed" in held.reason
    assert all(not o.verdict.warning for o in outcomes[52:100])  # said once
    s = pipe.stats
    assert s.dropped == {"future_stamp": 50}
    assert (s.time_resets, s.gap_reanchors, s.reanchors) == (0, 0, 0)
    assert_pose(pipe.estimator.pose, circle(3.0))


def test_a_jump_that_is_not_into_the_future_is_published_and_still_discarded(
        tmp_path: Path) -> None:
    """A driver whose clock is a day behind ours jumps 1000 s ahead, still in our past:
    nothing impossible (as a pause whose stamps were not seen to elapse, as tests fake
    it), so the new timeline is published at once, and the return still discards it."""
    pipe = pipeline(tmp_path)
    day = 86_400 * 10**9
    outcomes = drive(lambda s, p, r: pipe.feed(s - day, NAMES, p, (), r), 3.0, burst_stamp)
    # The counts went on over the jump (one period's motion): integrated, not a restart.
    assert outcomes[51].verdict.code is Reason.GAP_INTEGRATED and outcomes[51].publish
    assert all(o.publish for o in outcomes[52:])
    assert outcomes[100].verdict.code is Reason.FUTURE_STAMP
    assert pipe.stats.dropped == {"future_stamp": 50} and pipe.stats.time_resets == 0
    assert_pose(pipe.estimator.pose, circle(3.0))


def test_a_driver_restart_after_a_real_pause_is_still_taken_at_once(tmp_path: Path) -> None:
    """Stamps and receive time both jump 4 s: a pause, published from the next reading."""
    pipe = pipeline(tmp_path)
    outcomes: list[Outcome] = []
    for k in range(51):  # 1 s of driving
        t = PERIOD * k
        outcomes.append(pipe.feed(ns(t), NAMES, positions(t), (), ns(t)))
    for k in range(26):  # the driver back 4 s later, its counters from 0
        t = 5.0 + PERIOD * k
        rel = PERIOD * k
        outcomes.append(pipe.feed(ns(t), NAMES, positions(rel), (), ns(t)))
    assert outcomes[51].verdict.status is Status.HELD
    assert outcomes[52].verdict.code is Reason.GAP and outcomes[52].publish
    assert pipe.stats.gap_reanchors == 1
    # The circle to t = 1, then (the pause unknown) the circle's next 0.5 s from there.
    end = oracle.arc(V * 0.5, W * 0.5, oracle.arc(V * 1.0, W * 1.0))
    assert_pose(pipe.estimator.pose, Pose2D(*end))


def test_a_lasting_clock_change_is_taken_after_adopt_clock_after_s(tmp_path: Path) -> None:
    """The driver's clock jumps 1000 s ahead for good, unseen by the receiver: held for
    ADOPT_CLOCK_AFTER_S of its stamps, then taken (one gap re-anchor), and published;
    a reading back on the old clock after that is a time reset."""
    pipe = pipeline(tmp_path)
    def stamp(t: float) -> float:
        return t + BURST if t >= 1.0 else t
    outcomes = drive(
        lambda s, p, r: pipe.feed(s, NAMES, p, (), r), 8.0, stamp)
    adopted = 50 + round(ADOPT_CLOCK_AFTER_S / PERIOD)  # t = 6.0 s
    assert not any(o.publish for o in outcomes[50:adopted])
    taken = outcomes[adopted].verdict
    assert taken.code is Reason.GAP and "new clock" in taken.reason
    assert outcomes[adopted].publish and outcomes[adopted].stamp_ns == ns(6.0 + BURST)
    assert all(o.publish for o in outcomes[adopted:])
    assert pipe.stats.gap_reanchors == 1 and pipe.stats.dropped == {}
    # The one period over the jump (0.98 -> 1.0 s): its counts went on and are plausible
    # for the stamps' gap, so its motion is integrated too (issue 37); nothing is lost.
    assert_pose(pipe.estimator.pose, circle(8.0))
    again = pipe.feed(ns(8.02), NAMES, positions(8.02), (), ns(8.02))
    assert again.verdict.status is Status.TIME_RESET


def test_without_receive_times_a_return_after_the_trial_is_a_time_reset() -> None:
    """A pause taken as a restart (no receive times to tell): after ADOPT_CLOCK_AFTER_S
    of the new timeline, a jump back is a bag loop again (restart at the origin)."""
    est = estimator()
    def stamp(t: float) -> float:
        return t + BURST if t >= 1.0 else t
    drive(lambda s, p, _r: est.update(s, NAMES, p), 1.0 + ADOPT_CLOCK_AFTER_S, stamp)
    assert not est.on_trial
    t = 1.0 + ADOPT_CLOCK_AFTER_S + PERIOD
    assert est.update(ns(t), NAMES, positions(t)).status is Status.TIME_RESET


def test_a_bag_loop_during_a_trial_still_restarts() -> None:
    est = estimator()
    for k in range(61):  # into the burst
        t = PERIOD * k
        est.update(ns(burst_stamp(t)), NAMES, positions(t))
    assert est.on_trial
    verdict = est.update(ns(0.0), NAMES, positions(0.0))  # before the old timeline's last
    assert verdict.status is Status.TIME_RESET and not est.on_trial


def test_the_batch_path_takes_the_burst_back_too(tmp_path: Path) -> None:
    """Calibration's decoded steps: the burst's steps are removed when it is discarded."""
    readings = [JointReading(ns(burst_stamp(PERIOD * k)), ns(PERIOD * k), NAMES,
                                   positions(PERIOD * k), ()) for k in range(151)]
    steps = batch.wheel_steps(readings, settings(tmp_path))
    assert steps.segments == 1 and len(steps) == 150 - 50
    assert_pose(batch.final_pose(steps, Geometry(wheel_radius=R, wheel_separation=B)),
                circle(3.0))


def test_replay_of_the_burst_keeps_the_pose_and_writes_no_future_stamp(
        tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    """The exact scenario in a bag (logged on receipt, in true time), through the CLI."""
    bag = tmp_path / "burst"
    with bagwriter.BagWriter(bag) as w:
        w.add_topic("/joint_states", bagio.JOINT_STATE)
        t = w.typestore.types
        for k in range(151):
            true = PERIOD * k
            sec, nsec = divmod(ns(burst_stamp(true)), 10**9)
            w.write("/joint_states", ns(true), t[bagio.JOINT_STATE](
                header=t["std_msgs/msg/Header"](
                    stamp=t["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec), frame_id=""),
                name=NAMES, position=np.array(positions(true)), velocity=np.zeros(0),
                effort=np.zeros(0)))
    params = write_params(tmp_path / "p.yaml", {"wheel_radius": R, "wheel_separation": B})
    out = tmp_path / "out"
    assert cli(["replay", str(bag), "--params-file", str(params), "-o", str(out)]) == 0
    odom = [m for _, _, m in mcap_messages(out, ["/odom"])]
    stamps = [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in odom]
    assert max(stamps) == ns(3.0) and len(odom) == 151 - 50
    p = odom[-1].pose.pose
    end = circle(3.0)
    assert p.position.x == pytest.approx(end.x, abs=1e-9)
    assert p.position.y == pytest.approx(end.y, abs=1e-9)
    err = capfd.readouterr().err
    assert "50 x future_stamp" in err and "time_reset" not in err


# ------------------------------------------------- a driver's own clock (item 3)


def test_stamps_far_from_the_receive_time_are_named_once(tmp_path: Path) -> None:
    """The issue's driver: 1000 s + t on its clock, received at T0 + t on ours."""
    pipe = pipeline(tmp_path)
    outcomes = [pipe.feed(10**12 + round(PERIOD * k * 1e9), NAMES, positions(PERIOD * k), (),
                          ns(PERIOD * k)) for k in range(20)]
    warned = [o.warning for o in outcomes if o.warning]
    assert len(warned) == 1 and outcomes[0].warning == warned[0]
    offset = (T0 - 10**12) * 1e-9
    assert f"{offset:.3f} s behind the time they were received" in warned[0]
    assert "sync the driver's clock" in warned[0].lower()
    assert "stamp_source: receive_time" in warned[0]
    assert all(o.stamp_ns == 10**12 + round(PERIOD * k * 1e9) for k, o in enumerate(outcomes))


@pytest.mark.parametrize(("offset", "check_clock", "named"), [
    (-CLOCK_OFFSET_WARN_S * 0.9, True, False), (CLOCK_OFFSET_WARN_S * 1.1, True, True),
    (-CLOCK_OFFSET_WARN_S * 1.1, True, True), (1e4, False, False)])
def test_the_clock_is_named_beyond_clock_offset_warn_s_and_not_on_sim_time(
        tmp_path: Path, offset: float, check_clock: bool, named: bool) -> None:
    pipe = pipeline(tmp_path)
    out = pipe.feed(ns(offset), NAMES, [0.0, 0.0], (), ns(0.0), check_clock=check_clock)
    assert bool(out.warning) is named
    if named:
        assert ("ahead of" if offset > 0 else "behind") in out.warning


def test_stamp_source_receive_time_stamps_with_the_receive_time(tmp_path: Path) -> None:
    """The driver's clock is ignored (even an unstamped reading is used, as
    diff_drive_controller does): the pose is integrated over the receive times."""
    pipe = pipeline(tmp_path, stamp_source="receive_time")
    assert pipe.settings.stamp_source is StampSource.RECEIVE_TIME
    outcomes = [pipe.feed(0 if k % 2 else 10**12 + k, NAMES, positions(PERIOD * k), (),
                          ns(PERIOD * k)) for k in range(51)]
    assert all(o.publish and not o.warning for o in outcomes)
    assert [o.stamp_ns for o in outcomes] == [ns(PERIOD * k) for k in range(51)]
    assert_pose(pipe.estimator.pose, circle(1.0))
    assert pipe.estimator.linear == pytest.approx(V, rel=1e-9)


def test_replay_stamps_with_the_log_time_and_names_the_clock(tmp_path: Path) -> None:
    readings = [JointReading(10**12 + round(PERIOD * k * 1e9), ns(PERIOD * k), NAMES,
                                   positions(PERIOD * k), ()) for k in range(51)]
    out: list[Published] = []
    stats = replay_readings(readings, settings(tmp_path), out.append)
    assert len(stats.warnings) == 1 and "behind the time they were received" in stats.warnings[0]
    assert out[-1].stamp_ns == 10**12 + 10**9
    out.clear()
    stats = replay_readings(readings, settings(tmp_path, stamp_source="receive_time"),
                                   out.append)
    assert stats.warnings == [] and out[-1].stamp_ns == ns(1.0)


def test_stamp_source_is_refused_unless_header_or_receive_time(tmp_path: Path) -> None:
    with pytest.raises(ParameterError) as err:
        settings(tmp_path, stamp_source="now")
    assert "stamp_source" in str(err.value) and "header, receive_time" in str(err.value)


# ----------------------------------------------- more values than names (item 5)


@pytest.mark.parametrize(("position", "velocity"), [
    ([0.5, 0.6, 2.0], []), ([0.5, 0.6], [1.0, 1.0, 1.0]), ([], [1.0, 1.0, 9.0])])
def test_more_values_than_names_is_a_bad_array(
        tmp_path: Path, position: list[float], velocity: list[float]) -> None:
    """3 positions (or velocities) for 2 names: which value is which joint's is unknown;
    on main the first two were integrated (the issue's yaw jump of 0.21 rad)."""
    pipe = pipeline(tmp_path)
    pipe.feed(ns(0.0), NAMES, [0.0, 0.0])
    out = pipe.feed(ns(PERIOD), NAMES, position, velocity)
    assert out.verdict.status is Status.DROPPED and out.verdict.code is Reason.BAD_ARRAY
    assert out.verdict.warning == "dropped" and not out.publish
    assert "3 entries for 2 names" in out.verdict.reason
    assert pipe.stats.dropped == {"bad_array": 1}
    assert pipe.estimator.pose == Pose2D() and pipe.estimator.stamp_ns == ns(0.0)
