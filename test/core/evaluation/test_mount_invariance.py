"""Where the reference is mounted does not change the calibration (issue 38 item 3).

Real runs: the four OptiOdom squares of test/data (23 Dec 2020, two clockwise, two
counter-clockwise; Sousa et al., "OptiOdom: a Generic Approach for Odometry Calibration
of Wheeled Mobile Robots"), whose motion capture tracks the axle centre facing forward.
Their reference is moved onto a mount here with plain trigonometry (the point
``p + R(theta) (x, y)``, the heading ``theta + yaw``): the robot and its wheels are the
same, so the geometry must be. The full sweep over every optiodom_train experiment is
``bench/bench_mount.py``.
"""

from __future__ import annotations

import math
from functools import cache

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from diffdrive_odom.core.bulk import batch
from diffdrive_odom.core.evaluation import assessment, calibration, consistency, umbmark
from diffdrive_odom.core.evaluation.metrics import Trajectory
from diffdrive_odom.core.evaluation.recorded_run import Run
from diffdrive_odom.core.geometry.kinematics import Geometry
from diffdrive_odom.core.geometry.mount import Mount
from diffdrive_odom.settings.odometry import odometry_settings

from rosutil import DATA

NOMINAL = Geometry(0.042, 0.2)
SQUARES = ("square_231220200029_run-01", "square_231220200029_run-04",
           "square_231220200040_run-01", "square_231220200040_run-04")
LEVER, ANGLE = st.floats(-0.3, 0.3), st.floats(-math.pi, math.pi)


@cache
def _runs() -> tuple[Run, ...]:
    from diffdrive_odom.tools.bags import bagreadings, poses

    s = odometry_settings({"wheel_radius": 0.042, "wheel_separation": 0.2})
    return tuple(Run(n, batch.wheel_steps(bagreadings.read_joint_states(DATA / "optiodom" / n),
                                          s),
                     poses.read_trajectory(DATA / "optiodom" / n, "/ground_truth/pose"))
                 for n in SQUARES)


def mounted(run: Run, x: float, y: float, yaw: float) -> Run:
    ref = run.reference
    assert ref is not None
    c, s = np.cos(ref.yaw), np.sin(ref.yaw)
    return Run(run.name, run.steps, Trajectory(ref.stamp_ns, ref.x + c * x - s * y,
                                               ref.y + s * x + c * y, ref.yaw + yaw))


def composed(a: tuple[float, float, float], b: tuple[float, float, float]
             ) -> tuple[float, float, float]:
    """Mount ``b`` on top of mount ``a``."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], a[2] + b[2]


@cache
def _axle_fit() -> calibration.Fit:
    return calibration.fit(_runs()[:2], NOMINAL, mount=calibration.MountSpec(lever=True),
                           figures=False)


@settings(max_examples=6, deadline=None)
@given(x=LEVER, y=LEVER, yaw=ANGLE)
def test_the_fit_absorbs_any_rigid_mount_exactly(x: float, y: float, yaw: float) -> None:
    """One square each way, the lever arm fitted: the same multipliers to a millionth,
    and the mount found is the axle's own (the motion capture's millimetres) composed
    with the one given."""
    axle = _axle_fit()
    fit = calibration.fit([mounted(r, x, y, yaw) for r in _runs()[:2]], NOMINAL,
                          mount=calibration.MountSpec(lever=True), figures=False)
    assert fit.values == pytest.approx(axle.values, rel=1e-6)
    want = composed((axle.mount.x, axle.mount.y, axle.mount.yaw), (x, y, yaw))
    got = fit.mount
    assert (got.x, got.y) == pytest.approx(want[:2], abs=1e-6)
    assert math.remainder(got.yaw - want[2], math.tau) == pytest.approx(0.0, abs=1e-6)


@cache
def _axle() -> assessment.Assessment:
    return assessment.assess(_runs(), NOMINAL)


@pytest.mark.slow
@pytest.mark.parametrize(("x", "y", "yaw_deg"), [(-0.12, 0.20, 150.0)])
def test_calibrate_with_defaults_on_a_mount_is_calibrate_on_the_axle(
        x: float, y: float, yaw_deg: float) -> None:
    """calibrate's whole decision with its defaults (issue 38's first mount): the
    multipliers within half their printed sigma of the axle's, the same objective and
    verdict, and the mount it prints is the one given (the axle's found one composed with
    it) within its printed sigma. One mount here (each costs two of the suite's slowest
    half-minutes); bench/bench_mount.py sweeps mounts drawn over the whole range (lever
    arm up to 0.3 m each way, any yaw) on every optiodom_train experiment."""
    yaw = math.radians(yaw_deg)
    axle = _axle()
    got = assessment.assess([mounted(r, x, y, yaw) for r in _runs()], NOMINAL)
    assert axle.printed is not None and got.printed is not None
    sigma = np.sqrt(np.diag(axle.printed))
    assert np.all(np.abs(got.fit.values - axle.fit.values) <= 0.5 * sigma), (
        got.fit.values, axle.fit.values, sigma)
    assert got.choice.objective == axle.choice.objective
    assert got.verdict is not None and axle.verdict is not None
    assert (got.verdict.better, got.verdict.cannot_tell, got.refused) == (
        axle.verdict.better, axle.verdict.cannot_tell, axle.refused)
    assert not got.mount.lever_held and not got.mount.given
    a = axle.mount.mount
    want = composed((a.x, a.y, a.yaw), (x, y, yaw))
    m, (sx, sy, syaw) = got.mount.mount, got.mount.sigma
    assert abs(m.x - want[0]) < sx and abs(m.y - want[1]) < sy
    assert abs(math.remainder(m.yaw - want[2], math.tau)) < syaw


@settings(max_examples=6, deadline=None)
@given(x=LEVER, y=LEVER, yaw=ANGLE)
def test_umbmark_s_ends_and_the_consistency_terms_take_the_mount(
        x: float, y: float, yaw: float) -> None:
    """UMBmark's reference end and the consistency fit's final-pose error (what
    rotation_noise_k is fitted from) on a mounted reference, its mount given, are the
    axle's: the reference's own start frame, turned by the mount's yaw, never enters."""
    m = Mount(x, y, yaw)
    for run in _runs()[:2]:
        moved = mounted(run, x, y, yaw)
        assert run.reference is not None and moved.reference is not None
        assert umbmark.reference_end(moved, moved.reference, m) == pytest.approx(
            umbmark.reference_end(run, run.reference), abs=1e-9)
        got = consistency.run_terms(moved, NOMINAL, mount=m).error
        want = consistency.run_terms(run, NOMINAL).error
        assert got == pytest.approx(want, abs=1e-9)
