"""Calibration leaves out the steps the gyro's slip test flags (core.evaluation.leftout).

The run is ``gyrostreams``' route with four scripted slips of a robot whose right wheel
is 0.5 % larger and whose track is 1 % wider than configured, the IMU on its own clock
(173 Hz, its own phase, stamps jittered, latency jittered; in receive order, put in stamp
order by replay's own reordering); its truth is integrated there, independently of the package, and
the expected geometry is that true one.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import pytest
from gyrostreams import ISSUE_ROUTE, NAMES, T0, TIMINGS, B, R, Route, stream, truth

from diffdrive_odom.core.bulk import batch
from diffdrive_odom.core.bulk.readings import JointReading
from diffdrive_odom.core.evaluation import calibration, leftout, umbmark
from diffdrive_odom.core.evaluation.metrics import Trajectory
from diffdrive_odom.core.evaluation.recorded_run import Run, with_values
from diffdrive_odom.settings.odometry import odometry_settings
from diffdrive_odom.tools.bags.reorder import REORDER_WINDOW, Reorder

TRUE = np.array([R, R * 1.005, B * 1.01])
JITTERED = {t.name: t for t in TIMINGS}["173 Hz jittered"]
PLAIN = odometry_settings({"wheel_radius": R, "wheel_separation": B})
GYRO = odometry_settings({"wheel_radius": R, "wheel_separation": B, "use_imu": True,
                          "online_calibration": "disabled"})


class Imu(NamedTuple):
    stamp_ns: int
    wx: float
    wy: float
    wz: float


def _items(route: Route) -> tuple[list[JointReading | Imu], Trajectory]:
    """The route's readings and gyro samples in stamp order, as replay's reordering puts
    what arrives (in receive order), and its truth."""
    tr = truth(route, *TRUE)
    order = Reorder(REORDER_WINDOW, 1_000_000_000)
    items: list[JointReading | Imu] = []
    for kind, rx, stamp, a, b in stream(route, JITTERED, math.radians(0.3), 3e-4, 1, tr):
        items += order.push(JointReading(stamp, rx, NAMES, (a, b), ()) if kind == "j"
                            else Imu(stamp, 0.0, 0.0, a))
    items += order.flush()
    every = slice(None, None, 100)  # 100 Hz
    ref = Trajectory.from_arrays(T0 + np.round(tr.t[every] * 1e9).astype(np.int64),
                                 tr.x[every], tr.y[every], tr.theta[every])
    return items, ref


@pytest.fixture(scope="module")
def runs() -> tuple[Run, Run]:
    items, ref = _items(ISSUE_ROUTE)
    return (Run("wheels", batch.wheel_steps(items, PLAIN), ref),
            Run("gyro", batch.wheel_steps(items, GYRO), ref))


def test_the_gyro_finds_the_four_scripted_slips_and_only_their_steps(
        runs: tuple[Run, Run]) -> None:
    plain, gyro = runs
    assert plain.steps.slip_spans is None and leftout.left_out(plain, PLAIN.geometry) is None
    np.testing.assert_array_equal(plain.steps.d_left, gyro.steps.d_left)  # same steps
    lo = leftout.left_out(gyro, PLAIN.geometry)
    assert lo is not None and lo.events == 4 and len(lo.bridges) == 4
    slipped = leftout.slipped(gyro.steps)
    t = (gyro.steps.stamp_ns[slipped] - T0) * 1e-9
    for s in ISSUE_ROUTE.slips:  # every flagged step ends within a slip (a step late at most)
        assert ((t > s.start) & (t <= s.start + s.seconds + 0.021)).sum() >= 0.8 * s.seconds * 50
    inside = np.zeros_like(t, dtype=bool)
    for s in ISSUE_ROUTE.slips:
        inside |= (t > s.start) & (t <= s.start + s.seconds + 0.021)
    assert inside.all()
    # The wheels claimed the slips' heading (R * rate * seconds / B each), the truth none.
    claimed = sum(abs(s.heading_error) for s in ISSUE_ROUTE.slips)
    assert lo.turn_rad == pytest.approx(claimed, rel=0.1)
    assert lo.reference_turn_rad < 0.01 * claimed


def test_the_fit_recovers_the_true_geometry_with_the_slips_left_out_not_without(
        runs: tuple[Run, Run]) -> None:
    plain, gyro = runs
    kept = calibration.fit([plain], PLAIN.geometry, figures=False).values
    left = calibration.fit([gyro], PLAIN.geometry, figures=False).values
    np.testing.assert_allclose(left, TRUE, rtol=2e-5)  # noise-free wheels: to the encoder math
    # The slips taken for geometry: the separation 1 % off (five times the 0.19 % session
    # drift calibrate's sigma carries).
    assert np.max(np.abs(kept / TRUE - 1.0)) > 0.009


def test_umbmark_bridges_the_slips_too(runs: tuple[Run, Run]) -> None:
    """UMBmark's end errors with the slips bridged: the geometry's alone (no square here,
    so only the bridged end pose is checked: the truth's, with the true geometry)."""
    plain, gyro = runs
    true = with_values(PLAIN.geometry, *TRUE)
    x, y, _ = leftout.integrate(gyro.steps, true, leftout.bridges(gyro))
    assert gyro.reference is not None
    end = umbmark.reference_end(gyro, gyro.reference)
    assert math.hypot(x[-1] - end[0], y[-1] - end[1]) < 1e-4
    # UMBmark's own end error (what its passes correct): bridged, none is left for the
    # true geometry; the same steps unjudged keep the slips' end error.
    assert math.hypot(*umbmark._end_error(gyro, true, end)) < 1e-4
    assert math.hypot(*umbmark._end_error(plain, true, end)) > 0.1


def test_without_bridges_the_integration_is_the_batch_paths_and_a_gap_widens_a_bridge(
        runs: tuple[Run, Run]) -> None:
    _, gyro = runs
    for a, b in zip(leftout.integrate(gyro.steps, PLAIN.geometry, ()),
                    batch.integrate_steps(gyro.steps, PLAIN.geometry), strict=True):
        np.testing.assert_array_equal(a, b)
    assert gyro.reference is not None
    first = leftout.bridges(gyro)[0]
    # With bridges, the piecewise integration is the batch path's up to the first bridge.
    for a, b in zip(leftout.integrate(gyro.steps, PLAIN.geometry, leftout.bridges(gyro)),
                    batch.integrate_steps(gyro.steps, PLAIN.geometry), strict=True):
        np.testing.assert_allclose(a[:first.start], b[:first.start], rtol=0, atol=1e-12)
    stamps = leftout.pose_stamps(gyro.steps)
    ref = gyro.reference
    at = stamps[first.start]  # 2 s of reference gone up to (and over) the slip's start
    hole = (ref.stamp_ns > at - 2 * 10**9) & (ref.stamp_ns <= at + 5_000_000)
    gappy = Trajectory(ref.stamp_ns[~hole], ref.x[~hole], ref.y[~hole], ref.yaw[~hole])
    wide = leftout.bridges(Run("gap", gyro.steps, gappy))[0]
    assert wide.start < first.start and wide.end == first.end
    assert stamps[first.start] - stamps[wide.start] >= 2 * 10**9
