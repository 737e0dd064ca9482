"""CDR bytes of the messages the odometry node handles per reading (and Imu's rates).

Why: in the running node, turning a JointState's bytes into rclpy objects and an
Odometry and a TFMessage back into bytes cost more Python work than the odometry
itself. Every rclpy subscriber and publisher can hand over the serialised message
instead; this module reads the few JointState fields the estimator needs and writes
Odometry and TFMessage from a prepared byte layout where only the numbers change.

The format is what ROS 2 publishes: a 4-byte encapsulation header, then little-endian
plain CDR (XCDR1) with each primitive aligned to its own size, counted from the end of
that header; a string is a uint32 length (the NUL included), the bytes and a NUL; a
sequence is a uint32 count and its elements. rclpy's own serialisation is the oracle in
the tests, on random messages. Anything else (big-endian, another encapsulation) is
left to the caller's fallback: :meth:`JointStateDecoder.decode` returns None for it.

No rclpy import: the decoder and layouts are plain data and struct calls, shared by the
node and by replay's bag output.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from diffdrive_odom.wire.conversions import split_ns, yaw_to_quaternion

CDR_LE = b"\x00\x01\x00\x00"  # encapsulation: plain CDR, little endian, no options
_ORIGIN = 4  # alignment counts from the end of the encapsulation header

_U32 = struct.Struct("<I")
_STAMP = struct.Struct("<iI")
_TWO = struct.Struct("<2d")
_ONE = struct.Struct("<d")
_COV = struct.Struct("<36d")


def _align(offset: int, size: int) -> int:
    rel = offset - _ORIGIN
    return offset + (-rel % size)


@dataclass(frozen=True)
class JointArrays:
    """What the estimator takes from one JointState: stamp, names and two arrays."""

    sec: int
    nanosec: int
    name: tuple[str, ...]
    position: tuple[float, ...]
    velocity: tuple[float, ...]


class JointStateDecoder:
    """sensor_msgs/JointState bytes -> :class:`JointArrays`.

    A driver sends the same joint names in every message: their bytes are compared
    with the last message's and decoded only when they differ.
    """

    def __init__(self) -> None:
        self._name_bytes = b""
        self._names: tuple[str, ...] = ()
        self._arrays: dict[int, struct.Struct] = {}

    def decode(self, buf: bytes) -> JointArrays | None:
        """The fields, or None if ``buf`` is not little-endian plain CDR.

        Raises ValueError if the bytes end early or a count cannot fit them, so a
        corrupt count can never make the decoder loop or allocate its way through it.
        """
        if buf[:2] != CDR_LE[:2]:
            return None
        try:
            sec, nanosec = _STAMP.unpack_from(buf, _ORIGIN)
            off = _ORIGIN + 8
            off += 4 + _U32.unpack_from(buf, off)[0]  # header.frame_id: skipped
            off = _align(off, 4)
            if buf.startswith(self._name_bytes, off) and self._name_bytes:
                names = self._names
                off += len(self._name_bytes)
            else:
                start = off
                names, off = self._strings(buf, off)
                self._name_bytes, self._names = buf[start:off], names
            position, off = self._doubles(buf, off)
            velocity, off = self._doubles(buf, off)
            self._doubles(buf, off)  # effort: checked for length, not used
        except struct.error as exc:
            raise ValueError(f"JointState bytes end early: {exc}") from None
        return JointArrays(sec, nanosec, names, position, velocity)

    @staticmethod
    def _strings(buf: bytes, off: int) -> tuple[tuple[str, ...], int]:
        (count,) = _U32.unpack_from(buf, off)
        off += 4
        if count * 5 > len(buf) - off:  # each string is at least a length and its NUL
            raise ValueError(f"JointState bytes end early: {count} names announced")
        out = []
        for _ in range(count):
            off = _align(off, 4)
            (length,) = _U32.unpack_from(buf, off)
            off += 4
            if off + length > len(buf):
                raise ValueError("JointState bytes end early: a name is cut off")
            out.append(buf[off:off + max(length - 1, 0)].decode("utf-8"))
            off += length
        return tuple(out), off

    def _doubles(self, buf: bytes, off: int) -> tuple[tuple[float, ...], int]:
        off = _align(off, 4)
        (count,) = _U32.unpack_from(buf, off)
        off += 4
        if count == 0:
            return (), off
        off = _align(off, 8)
        if off + 8 * count > len(buf):
            raise ValueError(f"JointState bytes end early: {count} values announced")
        fmt = self._arrays.get(count)
        if fmt is None:
            fmt = self._arrays[count] = struct.Struct(f"<{count}d")
        return fmt.unpack_from(buf, off), off + 8 * count


@dataclass(frozen=True)
class JointBlockArrays:
    """Many JointStates of one byte layout: stamps [ns], the names, (n, joints) arrays."""

    stamp_ns: npt.NDArray[np.int64]
    name: tuple[str, ...]
    position: npt.NDArray[np.float64]
    velocity: npt.NDArray[np.float64]


@dataclass(frozen=True)
class _JointLayout:
    """Where the numbers sit in one JointState's bytes; every other byte is fixed."""

    length: int
    name: tuple[str, ...]
    position: tuple[int, int]  # byte offset, count
    velocity: tuple[int, int]
    fixed: npt.NDArray[np.intp]  # indices of the bytes that must equal the first message's


class JointBlockDecoder:
    """Consecutive sensor_msgs/JointState bytes -> :class:`JointBlockArrays`, with numpy.

    Why: a driver's messages differ only in their stamp and numbers, so once one has
    been walked (with :class:`JointStateDecoder`'s rules), the others are views at the
    same offsets. A message joins the block only if it has the same length and every
    byte the decoder reads outside the stamp and the three double arrays equals the
    first one's (encapsulation, frame_id, names and counts; not the alignment padding),
    so each decodes to exactly what :meth:`JointStateDecoder.decode` gives it
    (test/tools/test_joint_blocks.py).
    """

    def __init__(self) -> None:
        self._one = JointStateDecoder()

    def decode(
        self, raws: Sequence[bytes], start: int = 0, min_run: int = 1
    ) -> tuple[int, JointBlockArrays | None]:
        """The longest run from ``raws[start]`` of one layout: (its length, its arrays).

        (n, None): decode the next ``n`` messages one by one. When the first ``min_run``
        messages are not alike (or ``raws[start]`` has no layout to share: not
        little-endian plain CDR, or malformed), ``n`` is ``min_run`` (or what is left):
        messages whose layouts alternate (two drivers on one topic) then cost one check
        per ``min_run`` messages, and the one-by-one decoder reads anything.
        """
        size = len(raws[start])
        first = min(start + max(min_run, 1), len(raws)) - start
        layout = None
        if _equal_lengths(raws, start, start + first, size) == first:
            layout = self._walk(raws[start])
        if layout is None or self._alike(raws, start, first, layout) < first:
            return first, None
        n = self._alike(raws, start, _equal_lengths(raws, start, len(raws), size), layout)
        joined = b"".join(raws[start:start + n])
        sec = np.ndarray((n,), dtype="<i4", buffer=joined, offset=_ORIGIN, strides=(size,))
        nsec = np.ndarray((n,), dtype="<u4", buffer=joined, offset=_ORIGIN + 4, strides=(size,))
        stamps = sec.astype(np.int64) * 1_000_000_000 + nsec.astype(np.int64)
        return n, JointBlockArrays(stamps, layout.name,
                                   _doubles_at(joined, n, size, layout.position),
                                   _doubles_at(joined, n, size, layout.velocity))

    @staticmethod
    def _alike(raws: Sequence[bytes], start: int, n: int, layout: _JointLayout) -> int:
        """How many of the ``n`` same-length messages from ``start`` share its fixed bytes.

        The fixed bytes are those the decoder reads, but the stamp and the numbers.
        """
        rows = np.frombuffer(b"".join(raws[start:start + n]), dtype=np.uint8)
        fixed = rows.reshape(n, layout.length)[:, layout.fixed]
        return _run_length((fixed == fixed[0]).all(axis=1))

    def _walk(self, buf: bytes) -> _JointLayout | None:
        """The offsets of ``buf``'s fields, walked as :meth:`JointStateDecoder.decode` does.

        The bytes a decoder reads are fixed, but for the stamp and the numbers; alignment
        padding is not (Fast CDR leaves it uninitialised, so it differs between messages).
        """
        try:
            if self._one.decode(buf) is None:
                return None
        except ValueError:
            return None
        fixed = np.zeros(len(buf), dtype=np.bool_)
        fixed[:2] = True  # the encapsulation kind (its options are not read)
        off = _ORIGIN + 8
        end = off + 4 + _U32.unpack_from(buf, off)[0]
        fixed[off:end] = True  # header.frame_id: length, text and NUL
        start = _align(end, 4)
        names, off = JointStateDecoder._strings(buf, start)
        fixed[start:start + 4] = True  # the names: count, each length and text, no padding
        at = start + 4
        for _ in names:
            at = _align(at, 4)
            end = at + 4 + _U32.unpack_from(buf, at)[0]
            fixed[at:end] = True
            at = end
        arrays = []
        for _ in range(3):
            off = _align(off, 4)
            (count,) = _U32.unpack_from(buf, off)
            fixed[off:off + 4] = True
            off += 4
            if count:
                off = _align(off, 8)
            arrays.append((off, count))
            off += 8 * count
        return _JointLayout(len(buf), names, arrays[0], arrays[1], np.flatnonzero(fixed))


def _equal_lengths(raws: Sequence[bytes], start: int, stop: int, size: int) -> int:
    """How many messages from ``start`` (before ``stop``) are ``size`` bytes long."""
    stop = min(stop, len(raws))
    for k in range(start, stop):
        if len(raws[k]) != size:
            return k - start
    return stop - start


def _run_length(same: npt.NDArray[np.bool_]) -> int:
    """Leading True values of ``same``."""
    return len(same) if same.all() else int(np.argmin(same))


def _doubles_at(
    joined: bytes, n: int, size: int, where: tuple[int, int]
) -> npt.NDArray[np.float64]:
    """The (n, count) doubles at byte offset ``where[0]`` of each ``size``-byte row."""
    off, count = where
    if count == 0:
        return np.zeros((n, 0), dtype=np.float64)
    view = np.ndarray((n, count), dtype="<f8", buffer=joined, offset=off, strides=(size, 8))
    return view.astype(np.float64)


_RATES = struct.Struct("<3d")
# After the header: orientation (4 doubles) and its covariance (9) before the rates,
# then the rates' covariance (9), linear_acceleration (3) and its covariance (9).
_TO_RATES, _AFTER_RATES = 8 * 13, 8 * (3 + 9 + 3 + 9)


def decode_imu(buf: bytes) -> tuple[int, int, float, float, float] | None:
    """sensor_msgs/Imu bytes -> (sec, nanosec, wx, wy, wz); None if not little-endian CDR.

    ``use_imu`` takes only the stamp and the angular velocity: at 1 kHz rclpy's object
    (with its three covariance arrays) costs several times the gyro's own work.
    Raises ValueError if the bytes end early.
    """
    if buf[:2] != CDR_LE[:2]:
        return None
    try:
        sec, nanosec = _STAMP.unpack_from(buf, _ORIGIN)
        off = _ORIGIN + 8
        off += 4 + _U32.unpack_from(buf, off)[0]  # header.frame_id: skipped
        off = _align(off, 8) + _TO_RATES
        if off + _AFTER_RATES > len(buf):
            raise ValueError(f"Imu bytes end early: {len(buf)} bytes")
        wx, wy, wz = _RATES.unpack_from(buf, off)
    except struct.error as exc:
        raise ValueError(f"Imu bytes end early: {exc}") from None
    return sec, nanosec, wx, wy, wz


class _Layout:
    """A message's bytes with the offsets of the fields that change."""

    def __init__(self) -> None:
        self.buf = bytearray(CDR_LE)

    def u32(self, value: int) -> int:
        return self.put(_U32, 4, value)

    def string(self, text: str) -> None:
        data = text.encode("utf-8") + b"\x00"
        self.u32(len(data))
        self.buf += data

    def doubles(self, *values: float) -> int:
        at = self._pad(8)
        self.buf += struct.pack(f"<{len(values)}d", *values)
        return at

    def _pad(self, size: int) -> int:
        at = _align(len(self.buf), size)
        self.buf += bytes(at - len(self.buf))
        return at

    def put(self, fmt: struct.Struct, size: int, *values: int) -> int:
        at = self._pad(size)
        self.buf += fmt.pack(*values)
        return at


class OdometryLayout:
    """nav_msgs/Odometry bytes for fixed frames: stamp, planar pose and twist change.

    Position z, orientation x and y, linear y and z and angular x and y stay 0 (a
    planar base); covariance is written only when given, and kept otherwise.
    """

    def __init__(self, frame_id: str, child_frame_id: str) -> None:
        lay = _Layout()
        self._stamp = lay.put(_STAMP, 4, 0, 0)
        lay.string(frame_id)
        lay.string(child_frame_id)
        self._xy = lay.doubles(0.0, 0.0, 0.0)  # pose.position
        self._qzw = lay.doubles(0.0, 0.0, 0.0, 1.0) + 16  # pose.orientation z, w
        self._pose_cov = lay.doubles(*(0.0,) * 36)
        self._linear = lay.doubles(0.0, 0.0, 0.0)  # twist.linear
        self._angular = lay.doubles(0.0, 0.0, 0.0) + 16  # twist.angular z
        self._twist_cov = lay.doubles(*(0.0,) * 36)
        self._buf = lay.buf

    def covariance(self, pose: Sequence[float], twist: Sequence[float]) -> None:
        """Set both 6x6 row-major covariances for this and the following messages."""
        _COV.pack_into(self._buf, self._pose_cov, *pose)
        _COV.pack_into(self._buf, self._twist_cov, *twist)

    def encode(self, sec: int, nanosec: int, x: float, y: float, qz: float, qw: float,
               linear: float, angular: float) -> bytes:
        """The message's bytes with these values."""
        buf = self._buf
        _STAMP.pack_into(buf, self._stamp, sec, nanosec)
        _TWO.pack_into(buf, self._xy, x, y)
        _TWO.pack_into(buf, self._qzw, qz, qw)
        _ONE.pack_into(buf, self._linear, linear)
        _ONE.pack_into(buf, self._angular, angular)
        return bytes(buf)

    def planar(self, stamp_ns: int, x: float, y: float, yaw: float, linear: float,
               angular: float) -> bytes:
        """The message of a planar pose and twist stamped ``stamp_ns`` (> 0)."""
        sec, nanosec = split_ns(stamp_ns)
        _, _, qz, qw = yaw_to_quaternion(yaw)
        return self.encode(sec, nanosec, x, y, qz, qw, linear, angular)


class TransformLayout:
    """tf2_msgs/TFMessage bytes of one planar transform between fixed frames."""

    def __init__(self, frame_id: str, child_frame_id: str) -> None:
        lay = _Layout()
        lay.u32(1)  # one TransformStamped
        self._stamp = lay.put(_STAMP, 4, 0, 0)
        lay.string(frame_id)
        lay.string(child_frame_id)
        self._xy = lay.doubles(0.0, 0.0, 0.0)  # translation
        self._qzw = lay.doubles(0.0, 0.0, 0.0, 1.0) + 16  # rotation z, w
        self._buf = lay.buf

    def encode(self, sec: int, nanosec: int, x: float, y: float, qz: float,
               qw: float) -> bytes:
        """The message's bytes with these values."""
        buf = self._buf
        _STAMP.pack_into(buf, self._stamp, sec, nanosec)
        _TWO.pack_into(buf, self._xy, x, y)
        _TWO.pack_into(buf, self._qzw, qz, qw)
        return bytes(buf)

    def planar(self, stamp_ns: int, x: float, y: float, yaw: float) -> bytes:
        """The message of a planar pose stamped ``stamp_ns`` (> 0)."""
        sec, nanosec = split_ns(stamp_ns)
        _, _, qz, qw = yaw_to_quaternion(yaw)
        return self.encode(sec, nanosec, x, y, qz, qw)


def _filled(template: bytes | bytearray, n: int) -> npt.NDArray[np.uint8]:
    """``n`` copies of a message's bytes, one row each, to fill in place."""
    return np.tile(np.frombuffer(bytes(template), dtype=np.uint8), (n, 1))


def _planar_rows(template: bytes | bytearray, at: tuple[int, int, int], fields: PlanarFields,
                 pose: npt.NDArray[np.float64]) -> npt.NDArray[np.uint8]:
    """Rows of ``template``, each pose's stamp, x, y and quaternion z, w filled in.

    ``at``: the offsets of the stamp, x and z (the fields Odometry and /tf share).
    """
    stamp, xy, qzw = at
    rows = _filled(template, len(fields.sec))
    _put(rows, stamp, "<i4", fields.sec)
    _put(rows, stamp + 4, "<u4", fields.nanosec)
    _put(rows, xy, "<f8", pose[:, :2])
    _put(rows, qzw, "<f8", fields.qzw)
    return rows


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
        rows = _planar_rows(self._buf, (self._stamp, self._xy, self._qzw), fields, pose)
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
        return _planar_rows(self._buf, (self._stamp, self._xy, self._qzw), fields, pose)
