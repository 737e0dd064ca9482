"""The Imu decoder of ``use_imu`` against rclpy's own serialisation (no DDS)."""

from __future__ import annotations

import random

import pytest
from rclpy.serialization import serialize_message
from sensor_msgs.msg import Imu

from diffdrive_odom.wire.imu import decode_imu


def imu(sec: int, nsec: int, frame: str, w: tuple[float, float, float]) -> Imu:
    msg = Imu()
    msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nsec
    msg.header.frame_id = frame
    msg.angular_velocity.x, msg.angular_velocity.y, msg.angular_velocity.z = w
    msg.orientation.w = 0.5
    msg.linear_acceleration.z = 9.81
    msg.angular_velocity_covariance[4] = 1e-6
    return msg


def test_decoder_reads_what_rclpy_wrote() -> None:
    rng = random.Random(5)
    for n in range(300):
        frame = "x" * rng.randint(0, 9) if n % 3 else "imu_link"
        sec, nsec = rng.randint(-2**31, 2**31 - 1), rng.randint(0, 999_999_999)
        w = (rng.uniform(-40, 40), rng.uniform(-40, 40), rng.uniform(-40, 40))
        cov = (0.0, 0.0, 0.0, 0.0, 1e-6, 0.0, 0.0, 0.0, 0.0)
        assert decode_imu(serialize_message(imu(sec, nsec, frame, w))) == (sec, nsec, *w, cov)


def test_cut_short_bytes_are_refused_and_another_encoding_left_to_rclpy() -> None:
    raw = serialize_message(imu(1, 2, "imu_link", (0.1, 0.2, 0.3)))
    for cut in range(len(raw)):
        if raw[:cut][:2] == raw[:2] and cut >= 2:
            with pytest.raises(ValueError):
                decode_imu(raw[:cut])
    assert decode_imu(b"\x00\x00" + raw[2:]) is None  # big-endian CDR
