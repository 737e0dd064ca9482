"""sensor_msgs/JointState bytes -> what the estimator takes: one message, or a block of many.

Why: in the running node, turning a JointState's bytes into an rclpy object cost more
Python work than the odometry itself, and replay reads millions of them. Every rclpy
subscriber can hand over the serialised message instead; :class:`JointStateDecoder`
reads the few fields the estimator needs, and :class:`JointBlockDecoder` reads a run of
messages of one byte layout with numpy views. Both read the layout through one walker
(:meth:`JointStateDecoder.walk`), so they cannot disagree on where a field sits: the
block decoder's output is exactly what the one-by-one decoder gives each message
(test/tools/bags/test_joint_blocks.py, with rosbags' deserialisation as the oracle).

Bytes that are not little-endian plain CDR are left to the caller's fallback (the
decoders return None for them); cut-off or inconsistent bytes raise ValueError.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from diffdrive_odom.wire.cdr import FRAME_ID, ORIGIN, U32, align, header

# Where a double sequence's values sit in a message: (byte offset, count).
Span = tuple[int, int]


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
        got = self.walk(buf)
        if got is None:
            return None
        sec, nanosec, names, (at_p, n_p), (at_v, n_v) = got
        structs = self._arrays
        fmt_p = structs.get(n_p) or self._struct(n_p)
        fmt_v = structs.get(n_v) or self._struct(n_v)
        return JointArrays(sec, nanosec, names, fmt_p.unpack_from(buf, at_p),
                           fmt_v.unpack_from(buf, at_v))

    def walk(
        self, buf: bytes, fixed: npt.NDArray[np.bool_] | None = None
    ) -> tuple[int, int, tuple[str, ...], Span, Span] | None:
        """The JointState layout, the one definition both decoders read.

        (sec, nanosec, names, position's span, velocity's span); the effort is checked
        for length, not read. None and ValueError as :meth:`decode`. With ``fixed`` (a
        bool per byte of ``buf``), every byte read here but the stamp is marked: the
        encapsulation kind, frame_id, the names with their counts and lengths, and the
        three sequences' counts; not the alignment padding, which Fast CDR leaves
        uninitialised, so it differs between messages.
        """
        head = header(buf, "JointState")
        if head is None:
            return None
        sec, nanosec, end = head
        try:
            off = align(end, 4)
            # The last message's names when their bytes recur (not when marking: each
            # name's own bytes are marked, the padding between them is not).
            if fixed is None and buf.startswith(self._name_bytes, off) and self._name_bytes:
                names = self._names
                off += len(self._name_bytes)
            else:
                start = off
                names, off = _strings(buf, off, fixed)
                self._name_bytes, self._names = buf[start:off], names
            position, off = _doubles(buf, off, fixed)
            velocity, off = _doubles(buf, off, fixed)
            _doubles(buf, off, fixed)  # effort: checked for length, not used
        except struct.error as exc:
            raise ValueError(f"JointState bytes end early: {exc}") from None
        if fixed is not None:
            fixed[:2] = True  # the encapsulation kind (its options are not read)
            fixed[FRAME_ID:end] = True  # header.frame_id: length, text and NUL
        return sec, nanosec, names, position, velocity

    def _struct(self, count: int) -> struct.Struct:
        """The struct of ``count`` doubles, made once (of none: the empty tuple)."""
        fmt = self._arrays[count] = struct.Struct(f"<{count}d")
        return fmt


def _strings(
    buf: bytes, off: int, fixed: npt.NDArray[np.bool_] | None
) -> tuple[tuple[str, ...], int]:
    """A sequence of strings at ``off``: the texts and the offset after them."""
    count, off = _count(buf, off, fixed)
    if count * 5 > len(buf) - off:  # each string is at least a length and its NUL
        raise ValueError(f"JointState bytes end early: {count} names announced")
    out = []
    for _ in range(count):
        off = align(off, 4)
        (length,) = U32.unpack_from(buf, off)
        off += 4
        if off + length > len(buf):
            raise ValueError("JointState bytes end early: a name is cut off")
        if fixed is not None:
            fixed[off - 4:off + length] = True
        out.append(buf[off:off + max(length - 1, 0)].decode("utf-8"))
        off += length
    return tuple(out), off


def _count(buf: bytes, off: int, fixed: npt.NDArray[np.bool_] | None) -> tuple[int, int]:
    """A sequence's uint32 count at ``off`` (marked fixed) and the offset after it."""
    (count,) = U32.unpack_from(buf, off)
    if fixed is not None:
        fixed[off:off + 4] = True
    return count, off + 4


def _doubles(buf: bytes, off: int, fixed: npt.NDArray[np.bool_] | None) -> tuple[Span, int]:
    """A sequence of doubles at ``off`` (after padding): its span and the offset after it."""
    count, off = _count(buf, align(off, 4), fixed)
    if count == 0:
        return (off, 0), off
    off = align(off, 8)
    if off + 8 * count > len(buf):
        raise ValueError(f"JointState bytes end early: {count} values announced")
    return (off, count), off + 8 * count


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
    position: Span
    velocity: Span
    fixed: npt.NDArray[np.intp]  # indices of the bytes that must equal the first message's


class JointBlockDecoder:
    """Consecutive sensor_msgs/JointState bytes -> :class:`JointBlockArrays`, with numpy.

    Why: a driver's messages differ only in their stamp and numbers, so once one has
    been walked (:meth:`JointStateDecoder.walk`), the others are views at the same
    offsets. A message joins the block only if it has the same length and every byte
    the walk reads outside the stamp and the three double arrays equals the first one's
    (encapsulation, frame_id, names and counts; not the alignment padding), so each
    decodes to exactly what :meth:`JointStateDecoder.decode` gives it.
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
            layout = self._layout(raws[start])
        if layout is None or self._alike(raws, start, first, layout) < first:
            return first, None
        n = self._alike(raws, start, _equal_lengths(raws, start, len(raws), size), layout)
        joined = b"".join(raws[start:start + n])
        sec = np.ndarray((n,), dtype="<i4", buffer=joined, offset=ORIGIN, strides=(size,))
        nsec = np.ndarray((n,), dtype="<u4", buffer=joined, offset=ORIGIN + 4, strides=(size,))
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

    def _layout(self, buf: bytes) -> _JointLayout | None:
        """``buf``'s layout as :meth:`JointStateDecoder.walk` reads it; None if it has none."""
        fixed = np.zeros(len(buf), dtype=np.bool_)
        try:
            got = self._one.walk(buf, fixed)
        except ValueError:
            return None
        if got is None:
            return None
        _, _, names, position, velocity = got
        return _JointLayout(len(buf), names, position, velocity, np.flatnonzero(fixed))


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


def _doubles_at(joined: bytes, n: int, size: int, where: Span) -> npt.NDArray[np.float64]:
    """The (n, count) doubles at byte offset ``where[0]`` of each ``size``-byte row."""
    off, count = where
    if count == 0:
        return np.zeros((n, 0), dtype=np.float64)
    view = np.ndarray((n, count), dtype="<f8", buffer=joined, offset=off, strides=(size, 8))
    return view.astype(np.float64)
