"""Plain CDR as ROS 2 publishes it: encapsulation, alignment and a message's Header.

Why a module of its own: every codec of this layer (the JointState and Imu decoders,
the Odometry and /tf encoders) starts its bytes the same way, so these rules are written
once, here, and no two decoders can disagree on where a message's fields begin.

The format: a 4-byte encapsulation header, then little-endian plain CDR (XCDR1) with
each primitive aligned to its own size, counted from the end of that header; a string
is a uint32 length (the NUL included), the bytes and a NUL; a sequence is a uint32 count
and its elements. rclpy's own serialisation is the oracle in the tests, on random
messages. Anything else (big-endian, another encapsulation) is left to the caller's
fallback: :func:`header` returns None for it, and so do the decoders.
"""

from __future__ import annotations

import struct

CDR_LE = b"\x00\x01\x00\x00"  # encapsulation: plain CDR, little endian, no options
ORIGIN = 4  # alignment counts from the end of the encapsulation header
FRAME_ID = ORIGIN + 8  # std_msgs/Header: the stamp (sec, nanosec), then frame_id
_KIND = CDR_LE[:2]  # what is read of the encapsulation (its options are not)

U32 = struct.Struct("<I")
STAMP = struct.Struct("<iI")


def align(offset: int, size: int) -> int:
    """``offset`` moved up to the next multiple of ``size`` counted from :data:`ORIGIN`."""
    rel = offset - ORIGIN
    return offset + (-rel % size)


def header(buf: bytes, what: str) -> tuple[int, int, int] | None:
    """The std_msgs/Header a message starts with: (sec, nanosec, offset after frame_id).

    The frame_id (its length, text and NUL) spans :data:`FRAME_ID` to that offset; it
    is skipped, not decoded. None if ``buf`` is not little-endian plain CDR; ValueError
    naming the message type ``what`` if the bytes end before the frame_id's length.
    """
    if buf[:2] != _KIND:
        return None
    try:
        sec, nanosec = STAMP.unpack_from(buf, ORIGIN)
        (length,) = U32.unpack_from(buf, FRAME_ID)
    except struct.error as exc:
        raise ValueError(f"{what} bytes end early: {exc}") from None
    return sec, nanosec, FRAME_ID + 4 + length
