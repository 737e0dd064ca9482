"""The array form of the count rules is the scalar one, step by step (issue 37, item 1).

The fast lane judges a stretch of readings with :func:`counts.judged_steps` (the interval
since the counts last changed, and whether a released reading fits the wheels carrying
on) and :func:`plausibility.plausible_steps`; the node's estimator judges one reading at a
time with :meth:`CountTrack.judged` and :func:`plausibility.implausible`. Fed the same
readings, a logger's holds released 1 ms after the previous row, a driver repeating
every other reading, spikes landing on released readings and on plain ones, the two must
agree on every step: the same interval, the same verdict. As the fast lane does, the
array form starts from the state the estimator hands over (``changed_ns``, the last step
that moved) and runs until the first step the estimator does not integrate, then again
from there.
"""

from __future__ import annotations

import numpy as np
import pytest

from diffdrive_odom.core.estimation.wheels.config import EstimatorConfig
from diffdrive_odom.core.estimation.wheels.counts import judged_steps
from diffdrive_odom.core.estimation.wheels.encoders import EncoderConfig, position_increments
from diffdrive_odom.core.estimation.wheels.estimator import OdometryEstimator
from diffdrive_odom.core.estimation.wheels.plausibility import plausible_steps
from diffdrive_odom.core.estimation.wheels.timeline import Status
from diffdrive_odom.core.geometry.kinematics import Geometry, wheel_arcs

NAMES = ["left_wheel_joint", "right_wheel_joint"]
STAND = (5.0, 6.5)  # s: the wheels stand, read all along
GEOMETRY = Geometry(0.035, 0.23)


def _stream(seed: int, repeats: bool) -> tuple[np.ndarray, np.ndarray]:
    """Stamps [ns] and positions [rad] of a robot whose wheels speed up, slow down and
    reverse (within +-12 rad/s), standing 1.5 s, read near 50 Hz: holds of 0.1-0.3 s every 1-3 s
    released 1 ms after the row before, a 40 rad spike on some released readings and
    on some plain ones; with ``repeats`` every other reading repeats the one before."""
    rng = np.random.default_rng(seed)
    t, angle, speed = 0.0, rng.uniform(-3, 3, 2), rng.uniform(-6, 6, 2)
    stamps: list[int] = []
    rows: list[list[float]] = []
    hold_until, next_hold, held = -1.0, rng.uniform(0.5, 2.0), None
    for k in range(600):
        dt = 0.02 + rng.uniform(-0.002, 0.002)
        speed = np.clip(speed + rng.normal(0, 0.3, 2), -12, 12)
        t += dt
        if not STAND[0] <= t < STAND[1]:  # a standstill longer than max_reading_gap
            angle = angle + speed * dt
        values = angle.copy()
        quiet = STAND[0] - 0.5 <= t < STAND[1] + 0.5  # no hold nor spike about the stand
        if held is None and t >= next_hold and not quiet:
            held, hold_until = rows[-1] if rows else list(values), t + rng.uniform(0.1, 0.3)
        if held is not None and t < hold_until:
            rows.append(list(held))
            stamps.append(round(t * 1e9))
            continue
        stamp = round(t * 1e9)
        if held is not None:  # released: its own counts, 1 ms after the row before
            stamp = stamps[-1] + 1_000_000
            held, next_hold = None, t + rng.uniform(1.0, 3.0)
            if rng.random() < 0.3:
                values[0] += 40.0
        elif rng.random() < 0.01 and not quiet:
            values[1] += 40.0
        if repeats and k % 2 and rows:
            values = np.array(rows[-1])
        rows.append(list(values))
        stamps.append(stamp)
    return np.array(stamps, dtype=np.int64) + 10**18, np.array(rows)


@pytest.mark.parametrize("repeats", [False, True], ids=["plain", "driver repeats"])
@pytest.mark.parametrize("seed", range(12))
def test_the_array_form_judges_every_step_as_the_estimator(seed: int, repeats: bool) -> None:
    cfg = EstimatorConfig()  # 200 rad/s: a spike over a hold can pass the speed check
    encoders = EncoderConfig(("left_wheel_joint",), ("right_wheel_joint",))
    est = OdometryEstimator(GEOMETRY, encoders, cfg)
    stamps, values = _stream(seed, repeats)
    status = [est.update(int(stamps[0]), NAMES, list(values[0])).status]
    dts = [0.0]
    handed = [(est.counts.changed_ns, est.counts.moved)]
    for stamp, row in zip(stamps[1:], values[1:], strict=True):
        status.append(est.update(int(stamp), NAMES, list(row)).status)
        dts.append(est.last_step.dt if est.last_step is not None else 0.0)
        handed.append((est.counts.changed_ns, est.counts.moved))
    skipped = sum(s is Status.REANCHORED for s in status)
    long_steps = capped = 0
    start = 0
    while start < len(stamps) - 1:  # a stretch from the state handed over at ``start``
        v, s = values[start:], stamps[start:]
        d_left, d_right, peak = position_increments(encoders, v)
        step_dt = (s[1:] - s[:-1]) * 1e-9
        judged = judged_steps(v, s, handed[start], step_dt, (d_left, d_right), cfg)
        plain = judged.carried_on & plausible_steps(
            cfg, judged.dt, d_left, d_right, peak, wheel_arcs(GEOMETRY, d_left, d_right))
        for k in range(len(step_dt)):
            got = status[start + k + 1]
            assert got in (Status.UPDATED, Status.REANCHORED), (start + k + 1, got)
            assert bool(plain[k]) == (got is Status.UPDATED), (seed, start + k + 1, got)
            if got is not Status.UPDATED:
                start += k + 1
                break
            assert judged.dt[k] == pytest.approx(dts[start + k + 1], rel=1e-12, abs=0.0)
            long_steps += judged.dt[k] > step_dt[k] + 1e-9
            capped += bool(judged.moved[k]) and judged.dt[k] == cfg.max_reading_gap
        else:
            break
    # each kind was met: spikes skipped, released readings and the standstill's end
    # judged over more than their step (capped)
    assert skipped >= 1 and long_steps >= 5 and capped == 1, (skipped, long_steps, capped)
