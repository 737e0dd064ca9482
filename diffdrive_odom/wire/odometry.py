"""nav_msgs/Odometry and tf2_msgs/TFMessage bytes: what the node publishes per reading.

Why: building rclpy's Odometry and TFMessage objects and serialising them cost more
Python work than the odometry itself. The frames never change between messages, so a
message's bytes are laid out once (:class:`OdometryLayout`, :class:`TransformLayout`)
and only the stamp and the numbers are written into them; the bulk forms fill many rows
at once for replay's bag output. No rclpy import: plain data, struct calls and numpy,
shared by the node and by replay's sinks.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from diffdrive_odom.wire.cdr import CDR_LE, STAMP, U32, align
from diffdrive_odom.wire.conversions import split_ns, yaw_to_quaternion

_TWO = struct.Struct("<2d")
_ONE = struct.Struct("<d")
_COV = struct.Struct("<36d")


class _Layout:
    """A message's bytes with the offsets of the fields that change."""

    def __init__(self) -> None:
        self.buf = bytearray(CDR_LE)

    def u32(self, value: int) -> int:
        return self.put(U32, 4, value)

    def string(self, text: str) -> None:
        data = text.encode("utf-8") + b"\x00"
        self.u32(len(data))
        self.buf += data

    def doubles(self, *values: float) -> int:
        at = self._pad(8)
        self.buf += struct.pack(f"<{len(values)}d", *values)
        return at

    def _pad(self, size: int) -> int:
        at = align(len(self.buf), size)
        self.buf += bytes(at - len(self.buf))
        return at

    def put(self, fmt: struct.Struct, size: int, *values: int) -> int:
        at = self._pad(size)
        self.buf += fmt.pack(*values)
        return at


class _PlanarLayout:
    """What Odometry and /tf share: a stamp, two frames, x, y and the quaternion's z, w."""

    def __init__(self, lay: _Layout, frame_id: str, child_frame_id: str) -> None:
        self._stamp = lay.put(STAMP, 4, 0, 0)
        lay.string(frame_id)
        lay.string(child_frame_id)
        self._xy = lay.doubles(0.0, 0.0, 0.0)  # position / translation
        self._qzw = lay.doubles(0.0, 0.0, 0.0, 1.0) + 16  # orientation / rotation z, w
        self._buf = lay.buf  # grows in place with the fields a subclass adds

    def _pose(self, sec: int, nanosec: int, x: float, y: float, qz: float,
              qw: float) -> bytearray:
        """The bytes with the stamp and the pose written in (the caller copies them)."""
        buf = self._buf
        STAMP.pack_into(buf, self._stamp, sec, nanosec)
        _TWO.pack_into(buf, self._xy, x, y)
        _TWO.pack_into(buf, self._qzw, qz, qw)
        return buf

    def _planar_rows(self, fields: PlanarFields,
                     pose: npt.NDArray[np.float64]) -> npt.NDArray[np.uint8]:
        """Rows of the bytes, each pose's stamp, x, y and quaternion z, w filled in."""
        rows = np.tile(np.frombuffer(bytes(self._buf), dtype=np.uint8), (len(fields.sec), 1))
        _put(rows, self._stamp, "<i4", fields.sec)
        _put(rows, self._stamp + 4, "<u4", fields.nanosec)
        _put(rows, self._xy, "<f8", pose[:, :2])
        _put(rows, self._qzw, "<f8", fields.qzw)
        return rows


def _stamp_yaw(stamp_ns: int, yaw: float) -> tuple[int, int, float, float]:
    """(sec, nanosec, qz, qw) of a stamp [ns] (> 0) and a planar heading."""
    _, _, qz, qw = yaw_to_quaternion(yaw)
    return (*split_ns(stamp_ns), qz, qw)


class OdometryLayout(_PlanarLayout):
    """nav_msgs/Odometry bytes for fixed frames: stamp, planar pose and twist change.

    Position z, orientation x and y, linear y and z and angular x and y stay 0 (a
    planar base); covariance is written only when given, and kept otherwise.
    """

    def __init__(self, frame_id: str, child_frame_id: str) -> None:
        lay = _Layout()
        super().__init__(lay, frame_id, child_frame_id)
        self._pose_cov = lay.doubles(*(0.0,) * 36)
        self._linear = lay.doubles(0.0, 0.0, 0.0)  # twist.linear
        self._angular = lay.doubles(0.0, 0.0, 0.0) + 16  # twist.angular z
        self._twist_cov = lay.doubles(*(0.0,) * 36)

    def covariance(self, pose: Sequence[float], twist: Sequence[float]) -> None:
        """Set both 6x6 row-major covariances for this and the following messages."""
        _COV.pack_into(self._buf, self._pose_cov, *pose)
        _COV.pack_into(self._buf, self._twist_cov, *twist)

    def encode(self, sec: int, nanosec: int, x: float, y: float, qz: float, qw: float,
               linear: float, angular: float) -> bytes:
        """The message's bytes with these values."""
        buf = self._pose(sec, nanosec, x, y, qz, qw)
        _ONE.pack_into(buf, self._linear, linear)
        _ONE.pack_into(buf, self._angular, angular)
        return bytes(buf)

    def planar(self, stamp_ns: int, x: float, y: float, yaw: float, linear: float,
               angular: float) -> bytes:
        """The message of a planar pose and twist stamped ``stamp_ns`` (> 0)."""
        sec, nanosec, qz, qw = _stamp_yaw(stamp_ns, yaw)
        return self.encode(sec, nanosec, x, y, qz, qw, linear, angular)


class TransformLayout(_PlanarLayout):
    """tf2_msgs/TFMessage bytes of one planar transform between fixed frames."""

    def __init__(self, frame_id: str, child_frame_id: str) -> None:
        lay = _Layout()
        lay.u32(1)  # one TransformStamped
        super().__init__(lay, frame_id, child_frame_id)

    def encode(self, sec: int, nanosec: int, x: float, y: float, qz: float,
               qw: float) -> bytes:
        """The message's bytes with these values."""
        return bytes(self._pose(sec, nanosec, x, y, qz, qw))

    def planar(self, stamp_ns: int, x: float, y: float, yaw: float) -> bytes:
        """The message of a planar pose stamped ``stamp_ns`` (> 0)."""
        sec, nanosec, qz, qw = _stamp_yaw(stamp_ns, yaw)
        return self.encode(sec, nanosec, x, y, qz, qw)


def _put(rows: npt.NDArray[np.uint8], at: int, dtype: str, values: npt.ArrayLike) -> None:
    """Write one field (or a run of them, a 2-D ``values``) of every row at byte ``at``."""
    col = np.ascontiguousarray(values, dtype=dtype)
    width = col.itemsize * (col.shape[1] if col.ndim == 2 else 1)
    rows[:, at:at + width] = col.reshape(len(rows), -1).view(np.uint8)


@dataclass(frozen=True)
class PlanarFields:
    """sec, nanosec and the quaternion's (z, w) of many stamped planar poses."""

    sec: npt.NDArray[np.int32]
    nanosec: npt.NDArray[np.uint32]
    qzw: npt.NDArray[np.float64]


def planar_fields(stamp_ns: Sequence[int], yaw: Sequence[float]) -> PlanarFields:
    """The stamp and quaternion fields of many stamps and headings (Odometry and /tf share them).

    ``math.sin``/``math.cos`` one by one (not numpy's, whose last bit may differ), so
    the bytes are those :meth:`OdometryLayout.planar` writes.
    """
    ns = np.asarray(stamp_ns, dtype=np.int64)
    sec, nanosec = np.divmod(ns, 1_000_000_000)
    half = [0.5 * t for t in yaw]
    qzw = np.array([(math.sin(h), math.cos(h)) for h in half], dtype=np.float64).reshape(-1, 2)
    return PlanarFields(sec.astype(np.int32), nanosec.astype(np.uint32), qzw)


class BulkOdometry(OdometryLayout):
    """:class:`OdometryLayout` for many messages at once: one row of bytes per message."""

    def rows(self, fields: PlanarFields, pose: npt.NDArray[np.float64],
             twist: npt.NDArray[np.float64], pose_cov: npt.NDArray[np.float64],
             twist_cov: npt.NDArray[np.float64]) -> npt.NDArray[np.uint8]:
        """(n, size) bytes: ``pose`` (n, 3), ``twist`` (n, 2), covariances (n, 36).

        ``fields``: the stamps and headings' fields (:func:`planar_fields`).
        """
        rows = self._planar_rows(fields, pose)
        _put(rows, self._linear, "<f8", twist[:, 0])
        _put(rows, self._angular, "<f8", twist[:, 1])
        _put(rows, self._pose_cov, "<f8", pose_cov)
        _put(rows, self._twist_cov, "<f8", twist_cov)
        return rows


class BulkTransform(TransformLayout):
    """:class:`TransformLayout` for many messages at once: one row of bytes per message."""

    def rows(self, fields: PlanarFields, pose: npt.NDArray[np.float64]) -> npt.NDArray[np.uint8]:
        """(n, size) bytes of the transforms of ``pose`` (n, 3).

        ``fields``: the stamps and headings' fields (:func:`planar_fields`).
        """
        return self._planar_rows(fields, pose)
