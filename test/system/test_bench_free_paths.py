"""bench_free_paths' floor (a minimax fit) and its candidate fit, on simulated runs.

The bench's claims about the real free paths rest on two functions: ``best_worst`` (the
smallest worst final error any single geometry reaches: the floor no objective beats) and
``candidate_fit`` (calibrate's objective with other nuisances). Checked here against
closed forms: two straight runs whose wheels rolled with different radii, and a
reference tracked at a point off the axle.
"""

from __future__ import annotations

import math
import sys

import numpy as np

from diffdrive_odom.core.bulk import batch
from diffdrive_odom.core.bulk.readings import JointReading
from diffdrive_odom.core.evaluation.metrics import Trajectory
from diffdrive_odom.core.evaluation.recorded_run import Run, values_of, with_values
from diffdrive_odom.core.geometry.kinematics import Geometry, wheel_rates
from diffdrive_odom.core.motion import routes
from diffdrive_odom.settings.odometry import odometry_settings

import oracle
from paths import ROOT

sys.path.insert(0, str(ROOT / "bench"))
import bench_free_paths as bf

NOMINAL = Geometry(0.042, 0.200)  # the bench's robot (bench_calibration.NOMINAL)
SETTINGS = odometry_settings({"wheel_radius": 0.042, "wheel_separation": 0.200})
RATE = 20.0


def drive(route: routes.Route, true: Geometry, mount: tuple[float, float] = (0.0, 0.0)
          ) -> Run:
    """Readings of ``route`` at RATE (wheels at the nominal inverse kinematics' rates);
    the reference is the ``true`` base's pose by ``oracle``'s arcs, tracked at ``mount``
    (x, y on the robot)."""
    names = ("left_wheel_joint", "right_wheel_joint")
    dt, t0 = 1.0 / RATE, 10**9
    left = right = 0.0
    pose = oracle.ORIGIN
    readings, stamps, poses = [JointReading(t0, t0, names, (0.0, 0.0), ())], [t0], [pose]
    for k in range(1, round(route.duration * RATE) + 1):
        rate_l, rate_r = wheel_rates(NOMINAL, *route.command_at((k - 1) * dt))
        pose = oracle.wheel_arc(true.left_radius * rate_l * dt,
                                true.right_radius * rate_r * dt, true.separation, pose)
        left, right = left + rate_l * dt, right + rate_r * dt
        stamps.append(t0 + round(k * dt * 1e9))
        readings.append(JointReading(stamps[-1], stamps[-1], names, (left, right), ()))
        poses.append(pose)
    x, y, th = np.array(poses).T
    mx, my = mount
    x, y = x + np.cos(th) * mx - np.sin(th) * my, y + np.sin(th) * mx + np.cos(th) * my
    return Run(route.name, batch.wheel_steps(readings, SETTINGS),
               Trajectory.from_arrays(stamps, x, y, th))


def _line(radius_ratio: float) -> Run:
    true = with_values(NOMINAL, 0.042 * radius_ratio, 0.042 * radius_ratio, 0.200)
    return drive(routes.Route("line", (routes.Segment(2.0 / 0.4, 0.4, 0.0),)), true)


def test_best_worst_of_two_lines_is_the_mean_radius_and_half_their_difference() -> None:
    """The same wheel turns phi, rolled on radii r_A and r_B: a radius rho ends them
    |rho - r_A| phi and |rho - r_B| phi off; the worst is least at rho = (r_A + r_B) / 2,
    (r_B - r_A) phi / 2. With the mean radius held at s r0: max |s r0 - r_i| phi."""
    runs = [_line(1.0), _line(1.02)]
    phi = 2.0 / 0.042  # wheel turn [rad]: the nominal kinematics commanded 2 m
    worst, g = bf.best_worst(runs, NOMINAL)
    assert math.isclose(worst, 0.5 * 0.02 * 0.042 * phi, rel_tol=1e-4), worst
    assert np.allclose(values_of(g)[:2], 0.042 * 1.01, rtol=1e-5), values_of(g)
    held, _ = bf.best_worst(runs, NOMINAL, scale=1.0)
    assert math.isclose(held, 0.02 * 0.042 * phi, rel_tol=1e-4), held
    assert np.allclose(bf.end_errors(runs, g), worst, rtol=1e-4)


def test_candidate_fit_recovers_the_geometry_with_the_reference_off_the_axle() -> None:
    """A figure eight tracked 3 cm ahead and 2 cm left of the axle: with the mount
    fitted the geometry comes back to 1e-4; calibrate's objective (mount fixed at 0) is
    the same fit without it."""
    true = with_values(NOMINAL, 0.042 * 1.01, 0.042 * 0.995, 0.200 * 1.02)
    runs = [drive(routes.figure_eight(0.6, linear=0.3), true, mount=(0.03, 0.02))]
    fitted = values_of(bf.candidate_fit(runs, mount=True))
    assert np.allclose(fitted, values_of(true), rtol=1e-4), fitted / values_of(true) - 1
    plain = values_of(bf.candidate_fit(runs))
    assert np.max(np.abs(plain / values_of(true) - 1)) > 1e-3, plain / values_of(true) - 1
