"""The fast lane (core.bulk.fastlane, core.uncertainty.fastcov) publishes what the pipeline does.

The pipeline (core.estimation.pipeline.ReadingPipeline) is the definition of every rule; the fast
lane integrates in bulk only the stretches where none can fire. Proven here by
property tests: streams holding every reason code (zero stamps, missing joints, NaN,
bursts of speed, driver restarts, gaps, time resets, far-future stamps and bursts of
them, stale stamps, counter wraps, two wheels a side, velocity-only readings, a
driver's clock far off, readings held and released late, gaps whose counts went on,
restarts from a kept count), replayed both ways: the same poses (1e-12 m and rad), the
same covariances (1e-9 of the matrix's largest entry), the same stamps, statuses,
reason counts and counters (the interval each step is judged over included). Also on
every bag in test/data. The covariance's closed form (cumulative sums) against the
scalar recursion, far from the origin.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from diffdrive_odom.core.bulk import batch, fastlane
from diffdrive_odom.core.bulk.readings import JointBlock, JointReading
from diffdrive_odom.core.estimation.config import OdometrySettings
from diffdrive_odom.core.estimation.pipeline import ReadingPipeline
from diffdrive_odom.core.estimation.wheels.encoders import Reason
from diffdrive_odom.core.geometry.integration import Pose2D, chord_array, compose
from diffdrive_odom.core.geometry.kinematics import Geometry, body_increment
from diffdrive_odom.core.geometry.se2 import wrap_angle
from diffdrive_odom.core.uncertainty.fastcov import (
    BulkModel,
    BulkSteps,
    CovarianceState,
    bulk_covariance,
)
from diffdrive_odom.core.uncertainty.noise import NoiseModel
from diffdrive_odom.core.uncertainty.propagation import PoseUncertainty, pose_message_covariance
from diffdrive_odom.settings.odometry import odometry_settings
from diffdrive_odom.tools.bags import bagreadings
from diffdrive_odom.tools.replaying.readings import replay_readings
from diffdrive_odom.tools.replaying.sinks import Published
from diffdrive_odom.tools.replaying.stats import ReplayStats

from bagutil import OPTIODOM_PARAMS, TB3_PARAMS
from rosutil import DATA


@dataclass(frozen=True)
class Reading:
    stamp_ns: int
    log_ns: int
    names: Sequence[str]
    position: Sequence[float]
    velocity: Sequence[float]


EVENTS = ("zero_stamp", "missing_joint", "nan", "burst", "restart", "restart_paused", "gap",
          "time_reset", "future", "future_burst", "stale", "duplicate", "velocity",
          "velocity_nan", "bad_array", "clock_offset", "slow_driver", "no_data", "out_of_range",
          "wheels_disagree", "hold", "moving_gap", "restart_jump")


def _stream(seed: int, events: list[tuple[str, int]], wheels: int, ticks: float,
            bits: int) -> list[Reading]:
    """Readings of a robot driving at varying wheel speeds, with ``events`` after runs."""
    rng = np.random.default_rng(seed)
    names = tuple(f"l{k}" for k in range(wheels)) + tuple(f"r{k}" for k in range(wheels))
    unit = ticks / (2 * math.pi) if ticks else 1.0
    angle = rng.uniform(-3, 3, 2 * wheels)
    wall = 10**12
    offset = 0  # header stamp - wall clock (ns)
    log_offset = 1_000_000
    out: list[Reading] = []

    def pos() -> list[float]:
        counts = angle * unit
        if bits:
            counts = np.mod(np.round(counts), 2.0**bits)
        return [float(v) for v in counts]

    def emit(stamp: int | None = None, names_: Sequence[str] = names,
             position: Sequence[float] | None = None, velocity: Sequence[float] = ()) -> None:
        out.append(Reading(wall + offset if stamp is None else stamp, wall + log_offset,
                           names_, pos() if position is None else position, velocity))

    for event, run in events:
        speed = np.repeat(rng.uniform(-15, 15, 2), wheels) + rng.normal(0, 0.2, 2 * wheels)
        period = int(rng.uniform(5e6, 20e6))
        for _ in range(run):
            wall += period + int(rng.integers(-200_000, 200_000))
            angle += speed * period * 1e-9
            emit()
        wall += period
        angle += speed * period * 1e-9
        if event == "zero_stamp":
            emit(stamp=0)
        elif event == "missing_joint":
            emit(names_=names[:-1], position=pos()[:-1])
        elif event == "nan":
            p = pos()
            p[0] = math.nan
            emit(position=p)
        elif event == "burst":
            angle[0] += 40.0
            emit()
        elif event in ("restart", "restart_paused"):
            if event == "restart_paused":
                wall += 1_500_000_000
            angle[:] = 0.0
            emit()
        elif event == "gap":
            wall += 2_500_000_000
            emit()
        elif event == "time_reset":
            offset -= 5_000_000_000
            emit()
        elif event == "future":
            emit(stamp=wall + offset + 10**12)
        elif event == "future_burst":
            for k in range(int(rng.integers(2, 6))):
                emit(stamp=wall + offset + 10**12 + k * period)
                wall += period
        elif event == "stale":
            emit(stamp=out[-1].stamp_ns - 2_000_000 if out else None)
        elif event == "duplicate":
            emit(stamp=out[-1].stamp_ns if out else None)
        elif event == "velocity":
            for _ in range(int(rng.integers(1, 5))):
                emit(position=(), velocity=speed.tolist())
                wall += period
                angle += speed * period * 1e-9
        elif event == "velocity_nan":
            emit(position=[math.nan] * len(names), velocity=speed.tolist())
        elif event == "bad_array":
            emit(position=[*pos(), 0.0])
        elif event == "clock_offset":
            log_offset = 5_000_000_000 - log_offset
            emit()
        elif event == "no_data":
            emit(position=(), velocity=())
        elif event == "out_of_range":
            # one counter span up: unwrapped, a plausible step; as a count, impossible
            emit(position=[v + 2.0**bits if bits else 1e300 for v in pos()])
        elif event == "wheels_disagree":  # a side's mean is plausible, one wheel is not
            angle[0] += 20.0
            angle[wheels - 1] -= 20.0 if wheels > 1 else 0.0
            emit()
        elif event == "slow_driver":
            wall += 600_000_000
            emit()
        elif event == "hold":  # a logger repeats the counts, then writes the moved ones
            held = pos()
            for _ in range(int(rng.integers(2, 16))):
                out.append(Reading(wall + offset, wall + log_offset, names, held, ()))
                wall += period
                angle += speed * period * 1e-9
            wall = out[-1].stamp_ns - offset + 1_000_000  # 1 ms after the last row
            emit()
        elif event == "moving_gap":  # no rows for seconds, the counts going on
            pause = int(rng.uniform(1.2e9, 4e9))
            wall += pause
            angle += speed * pause * 1e-9
            emit()
        elif event == "restart_jump":  # after a pause, counting again from a kept value
            wall += 1_500_000_000
            angle -= 60.0
            emit()
        wall += period
        angle += speed * period * 1e-9
    for _ in range(20):  # the last event is followed by plain readings too
        wall += 10_000_000
        angle += speed * 0.01
        emit()
    return out


def _settings(wheels: int, ticks: float, bits: int, rate: float, window: int, model: str,
              source: str) -> OdometrySettings:
    return odometry_settings({
        "wheel_radius": 0.05, "wheel_separation": 0.3, "left_wheel_sign": 1,
        "left_wheel_names": [f"l{k}" for k in range(wheels)],
        "right_wheel_names": [f"r{k}" for k in range(wheels)],
        "ticks_per_revolution": ticks, "encoder_counter_bits": bits, "publish_rate": rate,
        "velocity_rolling_window_size": window, "covariance_model": model,
        "stamp_source": source, "max_wheel_speed": 30.0,
        "rotation_noise_k": 1e-4,  # both lanes' rotation term (0 by default)
    })


def _both(readings: Sequence[Any], cfg: OdometrySettings, chunk: int,
          monkeypatch: pytest.MonkeyPatch) -> int:
    """Replay both ways, check they agree; how many readings the fast lane took in bulk."""
    monkeypatch.setattr(fastlane, "CHUNK", chunk)
    slow: list[Published] = []
    fast: list[Published] = []
    a = replay_readings(readings, cfg, slow.append, fast=False)  # type: ignore[arg-type]
    b = replay_readings(readings, cfg, fast.append, fast=True)  # type: ignore[arg-type]
    _agree(a, b, slow, fast)
    # The same stream with its alike runs as JointBlocks (as bagblocks.iter_joint_blocks
    # gives them): the same again, though stretches now start elsewhere.
    blocks = _blocks(readings, chunk)
    blocked: list[Published] = []
    _agree(a, replay_readings(blocks, cfg, blocked.append, fast=True), slow, blocked)
    opened: list[Published] = []  # and one by one, blocks opened: the very same
    replay_readings(blocks, cfg, opened.append, fast=False)
    assert opened == slow
    scalar, warned = _scalar_lane(readings, cfg, chunk)
    pipe = ReadingPipeline(cfg)
    assert warned == [(k, w) for k, r in enumerate(readings)
                      if (w := pipe.feed(r.stamp_ns, r.names, r.position, r.velocity,
                                         r.log_ns).warning)]  # named at the same reading
    return b.readings - scalar


def _agree(a: ReplayStats, b: ReplayStats, slow: list[Published],
           fast: list[Published]) -> None:
    """Replay ``b`` (and what it published) is replay ``a``'s, to the issue's bounds."""
    for field in ("readings", "published", "statuses", "reasons", "examples", "refused",
                  "warnings", "final_stamp_ns"):
        assert getattr(a, field) == getattr(b, field), field
    pa, pb = a.pipeline, b.pipeline
    assert (pa.readings, pa.published, dict(pa.dropped), pa.reanchors, pa.gap_reanchors,
            pa.time_resets, pa.last_usable_stamp_ns, pa.velocity_fallback) == (
        pb.readings, pb.published, dict(pb.dropped), pb.reanchors, pb.gap_reanchors,
        pb.time_resets, pb.last_usable_stamp_ns, pb.velocity_fallback)
    _same_pose(a.final_pose, b.final_pose)
    assert len(slow) == len(fast)
    for s, f in zip(slow, fast, strict=True):
        assert (s.stamp_ns, s.log_ns, s.status) == (f.stamp_ns, f.log_ns, f.status)
        _same_pose(s.pose, f.pose)
        for u, v in ((s.linear, f.linear), (s.angular, f.angular)):
            assert abs(u - v) <= 1e-12 * max(1.0, abs(u)), (u, v)
        for cs, cf in ((s.pose_covariance, f.pose_covariance),
                       (s.twist_covariance, f.twist_covariance)):
            x, y = np.asarray(cs), np.asarray(cf)
            assert np.all(np.abs(x - y) <= 1e-9 * np.abs(x).max()), (x, y)


def _blocks(readings: Sequence[Any], cut: int) -> list[JointReading | JointBlock]:
    """Runs of readings alike in names and array lengths as blocks of up to ``cut + 3``."""
    out: list[JointReading | JointBlock] = []
    run: list[Any] = []

    def close() -> None:
        if len(run) > 1:
            out.append(JointBlock(
                np.array([r.stamp_ns for r in run], dtype=np.int64),
                np.array([r.log_ns for r in run], dtype=np.int64), tuple(run[0].names),
                np.array([r.position for r in run], dtype=np.float64).reshape(len(run), -1),
                np.array([r.velocity for r in run], dtype=np.float64).reshape(len(run), -1)))
        else:
            out.extend(JointReading(r.stamp_ns, r.log_ns, tuple(r.names), tuple(r.position),
                                    tuple(r.velocity)) for r in run)
        run.clear()

    for r in readings:
        if run and (tuple(r.names) != tuple(run[0].names) or len(run) > cut + 2
                    or (len(r.position), len(r.velocity)) != (len(run[0].position),
                                                             len(run[0].velocity))):
            close()
        run.append(r)
    close()
    return out


def _scalar_lane(readings: Sequence[Any], cfg: OdometrySettings, chunk: int
                 ) -> tuple[int, list[tuple[int, str]]]:
    """Readings the fast lane left to the pipeline, and its warnings by reading index."""
    pipe = ReadingPipeline(cfg)
    scalar, at, warned = 0, 0, []
    for item in fastlane.lanes(pipe, readings, chunk=chunk):
        if isinstance(item, fastlane.Stretch):
            at += item.count
            continue
        if item[1].warning:
            warned.append((at, item[1].warning))
        scalar += 1
        at += 1
    return scalar, warned


def _same_pose(a: Pose2D, b: Pose2D) -> None:
    assert abs(a.x - b.x) <= 1e-12 and abs(a.y - b.y) <= 1e-12, (a, b)
    assert abs(a.theta - b.theta) <= 1e-12, (a, b)  # both wrapped the same way


@settings(derandomize=True, max_examples=150, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(
    seed=st.integers(0, 2**32 - 1),
    events=st.lists(st.tuples(st.sampled_from(EVENTS), st.integers(0, 40)), min_size=1,
                    max_size=10),
    wheels=st.sampled_from((1, 2)),
    encoder=st.sampled_from(((0.0, 0), (4096.0, 0), (4096.0, 12))),
    rate=st.sampled_from((0.0, 30.0)),
    window=st.sampled_from((1, 3)),
    model=st.sampled_from(("propagated", "static")),
    source=st.sampled_from(("header", "receive_time")),
    chunk=st.sampled_from((5, 37, 1024)),
)
def test_both_lanes_publish_the_same(
    monkeypatch: pytest.MonkeyPatch, seed: int, events: list[tuple[str, int]], wheels: int,
    encoder: tuple[float, int], rate: float, window: int, model: str, source: str, chunk: int,
) -> None:
    ticks, bits = encoder
    readings = _stream(seed, events, wheels, ticks, bits)
    _both(readings, _settings(wheels, ticks, bits, rate, window, model, source), chunk,
          monkeypatch)


@pytest.mark.parametrize("event", EVENTS)
@pytest.mark.parametrize("config", [(1, 0.0, 0, 0.0, 1, "propagated", "header"),
                                    (2, 4096.0, 12, 30.0, 3, "static", "receive_time")])
def test_each_event_alone(monkeypatch: pytest.MonkeyPatch, event: str,
                          config: tuple[int, float, int, float, int, str, str]) -> None:
    """Each event between plain runs, and once before the driver's clock is found off."""
    wheels, ticks, bits = config[:3]
    readings = _stream(11, [(event, 30), ("clock_offset", 30), (event, 30)], wheels, ticks,
                       bits)
    _both(readings, _settings(*config), 16, monkeypatch)


def test_every_event_kind_and_most_readings_in_bulk(monkeypatch: pytest.MonkeyPatch) -> None:
    """One stream with every event: the lanes agree and the fast lane does the most of
    what it may take: plain steps, not on a timeline's trial after a gap (the pipeline
    has it pending: :meth:`ReadingPipeline.handover`)."""
    events = [(e, 60) for e in EVENTS] * 2
    readings = _stream(7, events, 2, 4096.0, 12)
    cfg = _settings(2, 4096.0, 12, 0.0, 3, "propagated", "header")
    bulk = _both(readings, cfg, 256, monkeypatch)
    pipe = ReadingPipeline(cfg)
    eligible = 0
    for r in readings:
        code = pipe.feed(r.stamp_ns, r.names, r.position, r.velocity, r.log_ns).verdict.code
        eligible += code is Reason.UPDATED and not pipe.estimator.on_trial
    assert bulk > 0.8 * eligible, (bulk, eligible, len(readings))


def test_with_the_gyro_nothing_goes_in_bulk_and_the_lanes_agree(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """use_imu: each step's heading is the gyro's decision, so the lane takes nothing in bulk
    (here with no IMU sample at all: the pipeline's silent-IMU rule, reading by reading)."""
    readings = _stream(7, [(e, 60) for e in EVENTS], 2, 4096.0, 12)
    cfg = odometry_settings({
        "wheel_radius": 0.05, "wheel_separation": 0.3, "ticks_per_revolution": 4096.0,
        "encoder_counter_bits": 12, "left_wheel_names": ["l0", "l1"],
        "right_wheel_names": ["r0", "r1"], "max_wheel_speed": 30.0, "use_imu": True})
    assert cfg.gyro is not None
    assert _both(readings, cfg, 256, monkeypatch) == 0
    pipe = ReadingPipeline(cfg)
    assert not any(isinstance(item, fastlane.Stretch)
                   for item in fastlane.lanes(pipe, readings, chunk=256))


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_calibration_steps_in_both_lanes(monkeypatch: pytest.MonkeyPatch, seed: int) -> None:
    """batch.wheel_steps (calibrate's decode-once path) through the lane, and without it."""
    events = [(EVENTS[(seed * 5 + k) % len(EVENTS)], 50) for k in range(12)]
    readings = _stream(seed, events, 2, 4096.0, 12)
    cfg = _settings(2, 4096.0, 12, 0.0, 1, "propagated", "header")
    fast = batch.wheel_steps(readings, cfg)  # type: ignore[arg-type]
    monkeypatch.setattr(fastlane, "_bulk", lambda *args: None)  # every reading one by one
    slow = batch.wheel_steps(readings, cfg)  # type: ignore[arg-type]
    assert fast.segments == slow.segments and len(fast) > 0.5 * len(readings)
    for name in ("stamp_ns", "segment", "dt", "d_left", "d_right"):
        assert np.array_equal(getattr(fast, name), getattr(slow, name)), name


BAGS = [(DATA / "optiodom" / run, OPTIODOM_PARAMS) for run in
        ("square_231220200029_run-01", "square_231220200029_run-04")] + [
    (DATA / "turtlebot3_sim" / "turtlebot3.bag", TB3_PARAMS)]


@pytest.mark.parametrize(("bag", "params"), BAGS, ids=lambda v: getattr(v, "name", ""))
@pytest.mark.parametrize("extra", [{}, {"publish_rate": 5.0, "velocity_rolling_window_size": 4}])
def test_bags_in_both_lanes(monkeypatch: pytest.MonkeyPatch, bag: Path,
                            params: dict[str, object], extra: dict[str, object]) -> None:
    cfg = odometry_settings({**params, **extra})
    readings = list(bagreadings.read_joint_states(bag))
    bulk = _both(readings, cfg, fastlane.CHUNK, monkeypatch)
    assert bulk > 0.5 * len(readings)


@settings(derandomize=True, max_examples=300, deadline=None)
@given(start=st.floats(-math.pi, math.pi), seed=st.integers(0, 2**32 - 1),
       n=st.integers(1, 400), scale=st.floats(1e-5, 2.0), drift=st.floats(-1.0, 1.0))
def test_headings_in_bulk_are_the_wrapped_sum_bit_for_bit(
        start: float, seed: int, n: int, scale: float, drift: float) -> None:
    """fastlane._headings (cumulative sums away from +-pi) is wrap_angle(t + d), step by step."""
    steps = np.random.default_rng(seed).normal(drift * scale, scale, n)
    expected = [start]
    for d in steps.tolist():
        expected.append(wrap_angle(expected[-1] + d))
    assert fastlane._headings(start, steps).tolist() == expected


@pytest.mark.parametrize("k_rot", [0.0, 2e-3])
def test_covariance_cumulative_form_equals_the_recursion(k_rot: float) -> None:
    """P, J and the twist window after 1000 steps, far from the origin, both ways; with
    and without the rotation term."""
    rng = np.random.default_rng(3)
    geo = Geometry(wheel_radius=0.05, wheel_separation=0.3)
    model = NoiseModel(0.002, 0.003, 0.01, 0.02, k_rot)
    m = 1000
    d_left = rng.uniform(-0.3, 0.6, m)
    d_right = rng.uniform(-0.3, 0.6, m)
    dt = rng.uniform(0.005, 0.02, m)
    ds, dth = body_increment(geo, d_left, d_right)
    unc = PoseUncertainty(model, 4096.0, 2, 3)
    unc.covariance = ((0.3, 0.01, 0.02), (0.01, 0.2, -0.03), (0.02, -0.03, 0.05))
    unc.sensitivity = ((1.0, 2.0, -3.0), (0.5, -1.0, 2.0), (0.1, -0.1, 0.2))
    start = CovarianceState(covariance=unc.covariance, sensitivity=unc.sensitivity,
                            rates=unc.rates)
    pose = Pose2D(500.0, -300.0, 2.5)
    before, after, published = [], [], []
    for k in range(m):
        before.append(pose.theta)
        unc.propagate(pose, geo, ds=float(ds[k]), dtheta=float(dth[k]),
                      d_left=float(d_left[k]), d_right=float(d_right[k]), dt=float(dt[k]))
        pose = compose(pose, float(ds[k]), float(dth[k]))
        after.append(pose.theta)
        published.append(unc.pose_covariance(pose, geo))
    sinc_half, chord = chord_array(ds, dth)
    out = bulk_covariance(
        BulkModel(noise=model, geometry=geo, ticks_per_revolution=4096.0, wheels_per_side=2,
                  window=3),
        start,
        BulkSteps(dt=dt, ds=ds, dtheta=dth, d_left=d_left, d_right=d_right, sinc_half=sinc_half,
                  chord=chord, before=np.array(before), after=np.array(after)))
    assert out is not None
    rows, twist = out.pose, out.twist
    p_end, j_end, rates = out.end.covariance, out.end.sensitivity, out.end.rates
    for k in (0, 1, 499, m - 1):
        want = np.asarray(pose_message_covariance(published[k]))
        got = np.asarray(pose_message_covariance(
            ((rows[k, 0], rows[k, 1], rows[k, 2]), (rows[k, 1], rows[k, 3], rows[k, 4]),
             (rows[k, 2], rows[k, 4], rows[k, 5]))))
        assert np.all(np.abs(want - got) <= 1e-9 * np.abs(want).max()), k
    for want_m, got_m in ((unc.covariance, p_end), (unc.sensitivity, j_end)):
        w, g = np.asarray(want_m), np.asarray(got_m)
        assert np.all(np.abs(w - g) <= 1e-9 * np.abs(w).max())
    tw = np.asarray(unc.twist_covariance())
    assert np.allclose(tw, [[twist[-1, 0], twist[-1, 1]], [twist[-1, 1], twist[-1, 2]]],
                       rtol=1e-12, atol=0.0)
    assert np.allclose(np.asarray(rates), np.asarray(unc.rates), rtol=1e-12, atol=0.0)
