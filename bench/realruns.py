"""The real runs the gate benches judge, each with what judging it needs.

OptiOdom (Sousa et al., "OptiOdom: a Generic Approach for Odometry Calibration of Wheeled
Mobile Robots"; MIT): the two runs of ``../shared/data/optiodom`` and the 45 of
``optiodom_train`` (converted once into ``bench_calibration``'s cache folder), OptiTrack
ground truth of the robot's centre on the wheels' clock. PHIL (a TurtleBot2's raw 16-bit
counters; GPL-3.0, read in place, never copied): seven runs, Vicon on 0, 2 and 6 (a
marker body off the axle, its stamps later than the wheels' by ``phildata.vicon_lag``).
"""

from __future__ import annotations

import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "test"))
sys.path.insert(0, str(ROOT / "bench"))

import bench_calibration  # noqa: E402
import phildata  # noqa: E402
import relogged  # noqa: E402

from diffdrive_odom.core.evaluation.metrics import Trajectory  # noqa: E402
from diffdrive_odom.tools.bags import bagreadings, poses  # noqa: E402

OPTIODOM_PARAMS: dict[str, Any] = {"wheel_radius": 0.042, "wheel_separation": 0.200}


@dataclass(frozen=True)
class RealRun:
    """A run's rows, its robot and parameters, its ground truth (None: none)."""

    name: str
    recording: relogged.Recording
    robot: relogged.Robot
    params: dict[str, Any]
    truth: Trajectory | None
    truth_lag_ns: int = 0  # how much later the truth's stamps are than the wheels'
    centre: bool = True  # the truth is the robot's centre (else a marker off the axle)
    imu: tuple[bagreadings.ImuSample, ...] = ()  # the gyro's samples (PHIL)


def real_runs(quick: bool = False) -> Iterator[RealRun]:
    """The runs there are (the missing data said on stdout): OptiOdom, then PHIL.

    ``quick``: the two OptiOdom runs of ``../shared/data/optiodom`` and PHIL run 0.
    """
    bags = sorted(bench_calibration.TEST.glob("square_*"))
    if not quick and (bench_calibration.TRAIN / "to_rosbag2.py").exists():
        bags += sorted(p for p in bench_calibration.bags().glob("*_run-*") if p.is_dir())
    if not bags:
        print(f"OptiOdom skipped: {bench_calibration.TEST} not found")
    for bag in bags:
        yield RealRun(bag.name, relogged.load(bag, "left_wheel_joint", "right_wheel_joint"),
                      relogged.OPTIODOM, OPTIODOM_PARAMS,
                      poses.read_trajectory(bag, "/ground_truth/pose"))
    if not phildata.DATA.is_dir():
        print(f"PHIL skipped: {phildata.MISSING}")
        return
    for n in phildata.RUNS[:1] if quick else phildata.RUNS:
        bag = phildata.DATA / f"phil_trial_{n}"
        run = phildata.load(bag)
        lag = 0 if run.truth is None else round(phildata.vicon_lag(run, "/joint_states") * 1e9)
        imu = tuple(bagreadings.ImuSample(phildata.stamp(m), log, m.angular_velocity.x,
                                          m.angular_velocity.y, m.angular_velocity.z)
                    for topic, log, m in run.messages if topic == "/imu")
        yield RealRun(bag.name, relogged.load(bag, "wheel_left_joint", "wheel_right_joint"),
                      relogged.KOBUKI, dict(phildata.NOMINAL), run.truth, lag, centre=False,
                      imu=imu)
