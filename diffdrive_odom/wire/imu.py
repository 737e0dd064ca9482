"""sensor_msgs/Imu bytes -> the stamp, the angular velocity and its covariance (``use_imu``).

Why: the gyro takes only the stamp and the rates, and at 1 kHz rclpy's message object
(with its three covariance arrays) costs several times the gyro's own work. The header
is read by :func:`diffdrive_odom.wire.cdr.header`, as every decoder's is.
"""

from __future__ import annotations

import struct

from diffdrive_odom.wire.cdr import align, header

_RATES = struct.Struct("<12d")  # the rates, then their covariance (REP-145)
ImuFields = tuple[int, int, float, float, float, tuple[float, ...]]
# After the header: orientation (4 doubles) and its covariance (9) before the rates,
# then the rates' covariance (9), linear_acceleration (3) and its covariance (9).
_TO_RATES, _AFTER_RATES = 8 * 13, 8 * (3 + 9 + 3 + 9)


def decode_imu(buf: bytes) -> ImuFields | None:
    """sensor_msgs/Imu bytes -> (sec, nanosec, wx, wy, wz, angular_velocity_covariance).

    None if not little-endian CDR.

    Raises ValueError if the bytes end early.
    """
    head = header(buf, "Imu")
    if head is None:
        return None
    sec, nanosec, off = head
    off = align(off, 8) + _TO_RATES
    if off + _AFTER_RATES > len(buf):
        raise ValueError(f"Imu bytes end early: {len(buf)} bytes")
    wx, wy, wz, *cov = _RATES.unpack_from(buf, off)
    return sec, nanosec, wx, wy, wz, tuple(cov)
