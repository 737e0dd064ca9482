"""Which time a reading is stamped with, and the check of a driver's clock against ours.

Used by :class:`~diffdrive_odom.core.estimation.pipeline.ReadingPipeline`, so the
node, ``replay`` (with the bag's log time as the receive time) and the demo agree, and
by the fast lane through the same :func:`in_sync`.

A driver that stamps its readings from its own clock (a microcontroller counting from
its boot, 1000 s + t, with no time sync) makes odometry stamped in that clock: every TF
lookup downstream then fails, and nothing in the odometry itself looks wrong. So the
first reading whose stamp is further than :data:`CLOCK_OFFSET_WARN_S` from the
receiver's clock is named once, with the offset and the two fixes. ``stamp_source:
receive_time`` is the second fix: stamp each reading with the time it was received,
as ros2_controllers' diff_drive_controller stamps with its control loop's time (the
measurement time is then lost, transport delay and jitter included).
"""

from __future__ import annotations

from typing import overload

import numpy as np
import numpy.typing as npt

from diffdrive_odom.core.compat import StrEnum

# s between a reading's stamp and its receive time beyond which the driver's clock is
# named. Transport takes milliseconds; a TF lookup at a stamp a second off the rest of
# the system already fails (tf2 keeps 10 s and does not extrapolate), and a clock that
# was never synced is off by far more.
CLOCK_OFFSET_WARN_S = 1.0


class StampSource(StrEnum):
    """The ``stamp_source`` parameter's values."""

    HEADER = "header"  # the JointState's header stamp: the measurement time (default)
    RECEIVE_TIME = "receive_time"  # when the reading arrived, on the receiver's clock


def clock_offset_text(offset_ns: int, topic: str = "joint_states") -> str:
    """The one warning about a driver's clock ``offset_ns`` off the receiver's.

    ``topic``: ``joint_states`` (the wheels, ``stamp_source``) or ``imu``
    (``imu_stamp_source``: its samples are then placed against the wheels' steps).
    """
    seconds = offset_ns * 1e-9
    side = "ahead of" if seconds > 0 else "behind"
    if topic == "imu":
        harm, param = ("the gyro's samples are placed against the wheels' steps by them, so "
                       "they are refused or miss every step (wheels only, no bias "
                       "estimate)"), "imu_stamp_source"
    else:
        harm, param = ("odometry and TF are stamped with them, so TF lookups elsewhere "
                       "fail"), "stamp_source"
    return (
        f"{topic} header stamps are {abs(seconds):.3f} s {side} the time they were "
        f"received (this node's clock; in a bag, the log time): {harm}. Sync the "
        "driver's clock with this computer's (chrony/NTP, or stamp with ROS time), or set "
        f"{param}: receive_time to stamp them when they arrive"
    )


@overload
def in_sync(offset_ns: int, limit_s: float = CLOCK_OFFSET_WARN_S) -> bool: ...
@overload
def in_sync(offset_ns: npt.NDArray[np.int64],
            limit_s: float = CLOCK_OFFSET_WARN_S) -> npt.NDArray[np.bool_]: ...
def in_sync(offset_ns: int | npt.NDArray[np.int64],
            limit_s: float = CLOCK_OFFSET_WARN_S) -> bool | npt.NDArray[np.bool_]:
    """True where a header stamp is within ``limit_s`` of its receive time.

    ``offset_ns``: stamp minus receive time, one (the node's check) or an array of them
    (the fast lane's), by the same arithmetic. ``limit_s``: CLOCK_OFFSET_WARN_S, or for
    the IMU ``imu_timeout`` where that is shorter.
    """
    limit = limit_s * 1e9
    if isinstance(offset_ns, np.ndarray):
        return np.abs(offset_ns) <= limit
    return abs(offset_ns) <= limit


class ClockOffsetCheck:
    """Names a driver's clock once: the first reading stamped far from its receive time."""

    def __init__(self, topic: str = "joint_states", limit_s: float = CLOCK_OFFSET_WARN_S) -> None:
        self.offset_ns: int | None = None  # the offset named, once it has been
        self.topic = topic
        self.limit_s = limit_s  # the IMU's: imu_timeout where that is shorter

    def check(self, stamp_ns: int, receive_ns: int) -> str:
        """The warning for this reading ('' if none): said the first time only."""
        if self.offset_ns is not None:
            return ""
        offset = stamp_ns - receive_ns
        if in_sync(offset, self.limit_s):
            return ""
        self.offset_ns = offset
        return clock_offset_text(offset, self.topic)
