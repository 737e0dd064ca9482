"""Every published 6x6 pose and twist covariance is positive definite (numpy's Cholesky).

robot_localization, and anything that inverts or factors a covariance, needs positive
definite matrices. The model alone gives none at the start (all zero), none after the
first step (rank 2 of 3), and a lateral velocity ``vy`` of exactly zero (the rolling
constraint): so vy gets a stated variance and the observed diagonal a floor. Checked on
a stream that starts at rest, goes straight and turns, and on a recorded bag, in both
replay lanes; the fast lane's array form of the message matrices (tools/sinks.py) gives
the very floats of the scalar form (core/uncertainty/propagation.py).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pytest

from diffdrive_odom.core.bulk import fastlane
from diffdrive_odom.core.bulk.readings import JointReading
from diffdrive_odom.core.estimation.pipeline import ReadingPipeline
from diffdrive_odom.core.uncertainty.propagation import (
    COVARIANCE_FLOOR,
    ROLLING_CONSTRAINT_VARIANCE,
    UNOBSERVED_VARIANCE,
)
from diffdrive_odom.settings.odometry import odometry_settings
from diffdrive_odom.tools.bags import bagreadings
from diffdrive_odom.tools.replaying import sinks
from diffdrive_odom.tools.replaying.readings import replay_readings

from bagutil import TB3_PARAMS
from rosutil import DATA

NAMES = ("wheel_left_joint", "wheel_right_joint")
STEP_NS = 20_000_000


def rest_straight_turn() -> list[JointReading]:
    """1 s at rest, 1 s straight (2 rad/s both wheels), 1 s turning on the spot."""
    out, left, right = [], 0.0, 0.0
    for k in range(150):
        if 50 <= k < 100:
            left, right = left + 0.04, right + 0.04
        elif k >= 100:
            left, right = left - 0.03, right + 0.03
        stamp = 1_000_000_000 + k * STEP_NS
        out.append(JointReading(stamp, stamp, NAMES, (left, right), ()))
    return out


def published(readings: Sequence[JointReading], fast: bool) -> list[sinks.Published]:
    out: list[sinks.Published] = []
    replay_readings(readings, odometry_settings(TB3_PARAMS), out.append, fast=fast)
    return out


def assert_positive_definite(out: list[sinks.Published]) -> None:
    assert out
    for p in out:
        for flat in (p.pose_covariance, p.twist_covariance):
            m = np.asarray(flat, dtype=np.float64).reshape(6, 6)
            assert (m == m.T).all()
            np.linalg.cholesky(m)  # raises LinAlgError unless positive definite
        twist = np.asarray(p.twist_covariance).reshape(6, 6)
        assert twist[1, 1] == ROLLING_CONSTRAINT_VARIANCE
        for m in (np.asarray(p.pose_covariance).reshape(6, 6), twist):
            assert [m[i, i] for i in (2, 3, 4)] == [UNOBSERVED_VARIANCE] * 3


@pytest.mark.parametrize("fast", [False, True], ids=["one_by_one", "fast_lane"])
def test_from_rest_through_the_first_steps(fast: bool) -> None:
    out = published(rest_straight_turn(), fast)
    first = np.asarray(out[0].pose_covariance).reshape(6, 6)
    # At the start the model knows the pose exactly: the floor alone keeps it definite.
    np.testing.assert_array_equal(first[np.ix_([0, 1, 5], [0, 1, 5])],
                                  COVARIANCE_FLOOR * np.eye(3))
    assert_positive_definite(out)


@pytest.mark.parametrize("fast", [False, True], ids=["one_by_one", "fast_lane"])
def test_on_a_recorded_bag(fast: bool) -> None:
    readings = list(bagreadings.read_joint_states(DATA / "turtlebot3_sim" / "turtlebot3.bag"))
    assert_positive_definite(published(readings, fast))  # type: ignore[arg-type]


def test_the_array_form_gives_the_scalar_forms_floats() -> None:
    """tools/sinks' (n, 36) rows of a stretch are, bit for bit, its pose-by-pose matrices."""
    pipe = ReadingPipeline(odometry_settings(TB3_PARAMS))
    stretches = [s for s in fastlane.lanes(pipe, rest_straight_turn())
                 if isinstance(s, fastlane.Stretch)]
    assert stretches
    for st in stretches:
        rows = list(st.poses())
        pose, twist = sinks._covariances(st, len(rows))
        np.testing.assert_array_equal(pose, np.array([r[5] for r in rows]))
        np.testing.assert_array_equal(twist, np.array([r[6] for r in rows]))
