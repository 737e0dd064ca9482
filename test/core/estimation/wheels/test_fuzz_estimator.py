"""Fuzzing the reading path: whatever comes in, nothing escapes and nothing is non-finite.

Every configuration shape (one or two wheels per side, radians or counts, a wrapping
counter, no speed check, no gap check) gets arbitrary readings: huge finite values,
infinities, NaN, wrong lengths and names, stamps back, forward, far in the future,
zero. Then a clean drive follows; it must be tracked exactly relative to where it
started. Its expected poses are circle geometry computed here (constant wheel speeds
give constant curvature), never the estimator's own output. Seeded
(``derandomize=True``), so a run is repeatable.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import pytest
from fuzzing import examples
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from diffdrive_odom.core.estimation.config import OdometrySettings
from diffdrive_odom.core.estimation.pipeline import ReadingPipeline
from diffdrive_odom.core.estimation.wheels.config import EstimatorConfig
from diffdrive_odom.core.estimation.wheels.encoders import EncoderConfig, Reason
from diffdrive_odom.core.estimation.wheels.estimator import OdometryEstimator
from diffdrive_odom.core.estimation.wheels.timeline import Status, Verdict
from diffdrive_odom.core.geometry.integration import Pose2D
from diffdrive_odom.core.geometry.kinematics import Geometry
from diffdrive_odom.core.geometry.se2 import wrap_angle
from diffdrive_odom.core.uncertainty.noise import NoiseModel

import oracle

FUZZ = settings(derandomize=True, deadline=None, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
T0 = 1_700_000_000_000_000_000
PERIOD_NS = 20_000_000  # the clean drive's 50 Hz
R, B = 0.1, 0.4
TICKS = 4096.0


@dataclass(frozen=True)
class Shape:
    """One configuration shape the estimator must survive."""

    name: str
    wheels: int  # per side
    ticks: float = 0.0
    bits: int = 0
    max_wheel_speed: float = 200.0
    max_reading_gap: float = 1.0
    window: int = 1

    def encoders(self) -> EncoderConfig:
        left = tuple(f"left_{i}" for i in range(self.wheels))
        right = tuple(f"right_{i}" for i in range(self.wheels))
        return EncoderConfig(left, right, self.ticks, self.bits)

    def estimator(self) -> EstimatorConfig:
        return EstimatorConfig(max_wheel_speed=self.max_wheel_speed,
                               velocity_rolling_window_size=self.window,
                               max_reading_gap=self.max_reading_gap)

    def names(self) -> list[str]:
        enc = self.encoders()
        return [*enc.left_wheel_names, *enc.right_wheel_names]

    def raw(self, angle: float) -> float:
        """A joint angle (rad) as the driver reports it (radians or wrapped counts)."""
        if self.ticks == 0.0:
            return angle
        counts = angle * self.ticks / (2 * math.pi)
        if not self.bits:
            return counts
        wrapped = counts % 2.0**self.bits  # unsigned; -1e-166 rounds up to 2**bits
        return 0.0 if wrapped == 2.0**self.bits else wrapped


SHAPES = [
    Shape("one wheel, radians", 1),
    Shape("two wheels, radians", 2),
    Shape("one wheel, counts", 1, ticks=TICKS),
    Shape("two wheels, 16-bit counter", 2, ticks=TICKS, bits=16),
    Shape("no speed check", 1, max_wheel_speed=math.inf),
    Shape("two wheels, no speed check", 2, max_wheel_speed=math.inf),
    Shape("no gap check", 1, max_reading_gap=math.inf),
    Shape("no checks, wrapping counter", 1, ticks=TICKS, bits=16, max_wheel_speed=math.inf,
          max_reading_gap=math.inf),
    Shape("smoothed twist", 2, window=3),
]

BAD_FLOATS = [1.7e308, -1.7e308, 1e300, -1e300, math.inf, -math.inf, math.nan, 5e-324,
              2.0**64, -(2.0**63), 65536.0, -32769.0]
values = st.one_of(st.floats(-1e4, 1e4), st.sampled_from(BAD_FLOATS))
# Where the next stamp lands relative to the last one fed (ns), or an absolute stamp.
stamp_moves = st.one_of(
    st.integers(1, 60_000_000),  # forward, a normal period
    st.just(0),  # repeated
    st.integers(-900_000_000, -1),  # back, under time_jump_threshold
    st.integers(-10**13, -1_000_000_001),  # far back (bag loop)
    st.integers(1_000_000_001, 10**15),  # far ahead (up to ~11 days)
)
absolute_stamps = st.sampled_from([0, -1, -T0, 1])
# Built once, not at every reading drawn (a new strategy is validated anew each draw).
one_in_ten = st.integers(0, 9)
name_faults = st.sampled_from(["ok", "ok", "ok", "shuffled", "missing", "wrong"])
SIZE_FAULTS = {n: st.sampled_from([0, 0, 0, 0, -1, 1, -n]) for n in range(1, 6)}


@st.composite
def bad_reading(draw: st.DrawFn, shape: Shape, last_ns: int
                ) -> tuple[int, list[str], list[float], list[float]]:
    absolute = draw(one_in_ten) == 0  # one in ten: zero, negative, tiny
    stamp = draw(absolute_stamps) if absolute else last_ns + draw(stamp_moves)
    names = shape.names()
    kind = draw(name_faults)
    if kind == "shuffled":
        names = ["caster", *reversed(names)]
    elif kind == "missing":
        names = names[:-1]
    elif kind == "wrong":
        names = [f"wheel_{i}" for i in range(len(names))]
    size = len(names) + draw(SIZE_FAULTS[len(names)])
    position = draw(st.lists(values, min_size=size, max_size=size))
    velocity: list[float] = []
    if draw(st.booleans()):
        velocity = draw(st.lists(values, min_size=len(names), max_size=len(names)))
    return stamp, names, position, velocity


@st.composite
def bad_sequence(draw: st.DrawFn, shape: Shape
                 ) -> list[tuple[int, list[str], list[float], list[float]]]:
    out = []
    last = T0
    for _ in range(draw(st.integers(1, 25))):
        reading = draw(bad_reading(shape, last))
        out.append(reading)
        last = reading[0] if reading[0] > 0 else last
    return out


clean_drives = st.tuples(
    st.floats(-50.0, 50.0), st.floats(-50.0, 50.0),  # wheel speeds [rad/s]
    st.floats(-100.0, 100.0),  # where the wheel angles start [rad]
    st.integers(3, 30),  # readings
)


def expected_pose(start: Pose2D, arc: float, heading: float) -> Pose2D:
    """``start`` composed with a circle arc of length ``arc`` turning by ``heading``."""
    x, y, theta = oracle.arc(arc, heading, (start.x, start.y, start.theta))
    return Pose2D(x, y, wrap_angle(theta))


def finite(est: OdometryEstimator) -> bool:
    step = est.last_step
    nums = [est.pose.x, est.pose.y, est.pose.theta, est.linear, est.angular]
    if step is not None:
        nums += [step.dt, step.ds, step.dtheta]
    return all(math.isfinite(v) for v in nums)


def run(shape: Shape, feed: object, est: OdometryEstimator,
        bad: list[tuple[int, list[str], list[float], list[float]]],
        drive: tuple[float, float, float, int]) -> None:
    assert callable(feed)
    for stamp, names, position, velocity in bad:
        feed(stamp, names, position, velocity)
        assert finite(est), (stamp, names, position, velocity)
    after = max([T0, *(s for s, *_ in bad)])
    left_rate, right_rate, angle0, count = drive
    start_ns = after + 10 * 10**9  # ahead of everything fed: held, then continued
    base: tuple[Pose2D, int] | None = None  # pose and reading index the drive counts from
    for k in range(count):
        t = k * PERIOD_NS * 1e-9
        left, right = angle0 + left_rate * t, angle0 + right_rate * t
        position = [shape.raw(left)] * shape.wheels + [shape.raw(right)] * shape.wheels
        verdict = feed(start_ns + k * PERIOD_NS, shape.names(), position, [])
        status = verdict.status
        assert finite(est)
        if k == 0 or (k == 1 and (status is Status.REANCHORED
                                  or verdict.code is Reason.GAP_INTEGRATED)):
            # The first reading may be integrated from (or skipped against) whatever the
            # bad input left as reference (over the gap before the drive, if those counts
            # could be motion): the drive is judged from here.
            base = (est.pose, k)
            continue
        assert status is Status.UPDATED, (k, status)
        assert base is not None
        elapsed = (k - base[1]) * PERIOD_NS * 1e-9
        arc = R * (left_rate + right_rate) / 2 * elapsed
        heading = R * (right_rate - left_rate) / B * elapsed
        want = expected_pose(base[0], arc, heading)
        got = est.pose
        assert abs(got.x - want.x) <= 1e-9 and abs(got.y - want.y) <= 1e-9, (k, got, want)
        assert abs(wrap_angle(got.theta - want.theta)) <= 1e-9, (k, got, want)
        if k - base[1] >= shape.window + 1:
            assert math.isclose(est.linear, R * (left_rate + right_rate) / 2,
                                rel_tol=1e-9, abs_tol=1e-9)
            assert math.isclose(est.angular, R * (right_rate - left_rate) / B,
                                rel_tol=1e-9, abs_tol=1e-9)


shapes = st.sampled_from(SHAPES)


@pytest.mark.slow  # hypothesis: thousands of runs, 15-25 s
@settings(FUZZ, max_examples=examples(1500))
@given(data=st.data())
def test_the_estimator_survives_anything_and_then_tracks_a_clean_drive(
    data: st.DataObject,
) -> None:
    shape = data.draw(shapes, label="shape")
    est = OdometryEstimator(Geometry(R, B), shape.encoders(), shape.estimator())

    def feed(stamp: int, names: list[str], position: list[float],
             velocity: list[float]) -> Verdict:
        return est.update(stamp, names, position, velocity)

    run(shape, feed, est, data.draw(bad_sequence(shape), label="bad"),
        data.draw(clean_drives, label="drive"))


@pytest.mark.slow  # hypothesis: thousands of runs, 15-25 s
@settings(FUZZ, max_examples=examples(1000))
@given(data=st.data())
def test_the_pipeline_survives_anything_and_counts_every_reading(
    data: st.DataObject,
) -> None:
    shape = data.draw(shapes, label="shape")
    pipe = ReadingPipeline(OdometrySettings(
        Geometry(R, B), shape.encoders(), shape.estimator(), "odom", "base_link", True,
        data.draw(st.sampled_from([0.0, 10.0, 50.0]), label="publish_rate"),
        (0.001,) * 6, (0.001,) * 6, noise=NoiseModel(),
    ))
    fed = 0

    def feed(stamp: int, names: list[str], position: list[float],
             velocity: list[float]) -> Verdict:
        nonlocal fed
        fed += 1
        out = pipe.feed(stamp, names, position, velocity)
        assert not (out.publish and not out.verdict.has_new_pose)
        if out.publish:  # what the node would publish: the propagated covariance too
            assert all(math.isfinite(v) for m in pipe.covariances() for v in m)
        return out.verdict

    run(shape, feed, pipe.estimator, data.draw(bad_sequence(shape), label="bad"),
        data.draw(clean_drives, label="drive"))
    stats = pipe.stats
    assert stats.readings == fed
    assert stats.published <= fed and stats.dropped_total <= fed
