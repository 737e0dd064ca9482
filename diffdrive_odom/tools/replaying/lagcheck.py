"""The IMU lag's advice, checked on the bag: ``imu_time_offset`` advised only where it helps.

The lag between the IMU's stamps and the wheels' is measured from the two turns
(:mod:`diffdrive_odom.core.estimation.gyro.imulag`), which need not be the clocks' alone
(the simulated TurtleBot3 bag: +70 ms, and imu_time_offset 0.070 took its end error from
0.040 to 0.069 m). So replay names the value to set as the node does, unchecked, and
with ``--eval`` replays the bag once more with it and advises it only if the end error
(start aligned) is no worse. One figure: the run's last estimate, as in the summary;
the node's one-off line (an earlier estimate, said as it came) is left out.
"""

from __future__ import annotations

import argparse
import dataclasses

from diffdrive_odom.core.errors import ConfigError
from diffdrive_odom.core.estimation.config import OdometrySettings
from diffdrive_odom.core.estimation.gyro.imulag import LINE_START
from diffdrive_odom.core.evaluation import metrics
from diffdrive_odom.tools.replaying import bag
from diffdrive_odom.tools.replaying.stats import ReplayStats

__all__ = ["advice", "other_warnings"]


def other_warnings(stats: ReplayStats) -> list[str]:
    """The pipeline's one-off warnings but the lag's (said by :func:`advice` instead)."""
    return [w for w in stats.warnings if not w.startswith(LINE_START)]


def advice(args: argparse.Namespace, settings: OdometrySettings, stats: ReplayStats,
           ref: metrics.Trajectory | None, end_error_m: float | None) -> str | None:
    """The lag's line where it matters for the slip test, else None.

    ``ref`` and ``end_error_m`` (this replay's start-aligned end error against it): the
    bag replayed again with the setting the lag asks for, the two end errors compared.
    """
    gyro = stats.pipeline.gyro
    if gyro is None or gyro.lag is None or settings.gyro is None:
        return None
    lag = gyro.lag
    if not lag.matters(gyro.jitter):
        return None
    if ref is None or end_error_m is None:
        return lag.line(gyro.jitter)
    try:
        config = dataclasses.replace(settings.gyro, time_offset=lag.setting)
    except ConfigError:
        return lag.line(gyro.jitter)
    again = argparse.Namespace(**{**vars(args), "output": None, "csv": None, "eval": True,
                                  "keep_input": False, "progress": False})
    _, traj = bag.replay_bag(again, dataclasses.replace(settings, gyro=config))
    after = metrics.evaluate(traj.trajectory(), ref).final_position_error_aligned_m
    return lag.checked_line(gyro.jitter, end_error_m, after)
