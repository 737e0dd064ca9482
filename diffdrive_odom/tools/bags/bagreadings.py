"""A bag's JointState (and Imu) messages as the estimator's readings, in stamp order.

Why: replay, calibrate and evaluate take wheel readings, not messages. rosbag2 data is
decoded by the node's own CDR decoder (rosbags' full deserialisation is several times
slower), ROS 1 bags and whatever that decoder leaves by rosbags. Readings come out in
*header stamp* order (:class:`~diffdrive_odom.tools.bags.reorder.Reorder`), one at a time
(:func:`iter_readings`);
:mod:`diffdrive_odom.tools.bags.bagblocks` reads the same readings in blocks.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, overload

from rosbags.highlevel import AnyReader
from rosbags.interfaces import Connection

from diffdrive_odom.core.bulk.readings import JointReading
from diffdrive_odom.tools.bags.bagio import IMU, JOINT_STATE, ODOMETRY, connections_for, open_bag
from diffdrive_odom.tools.bags.reorder import REORDER_WINDOW, Reorder
from diffdrive_odom.wire.conversions import reference_pose, stamp_to_ns
from diffdrive_odom.wire.jointstate import JointStateDecoder


@dataclass(frozen=True)
class ImuSample:
    """One Imu message's angular velocity (its own frame) and stamps (``use_imu``)."""

    stamp_ns: int
    log_ns: int
    wx: float
    wy: float
    wz: float
    covariance: tuple[float, ...] = ()  # angular_velocity_covariance (REP-145)


@dataclass(frozen=True)
class ReferenceSample:
    """A reference pose for the online estimate's scale (its header stamp, x, y, yaw)."""

    stamp_ns: int
    log_ns: int
    x: float
    y: float
    yaw: float


REFERENCE_TYPES = (ODOMETRY, "geometry_msgs/msg/PoseStamped")
Reading = JointReading | ImuSample | ReferenceSample  # what iter_readings yields


def _reading(msg: Any, log_ns: int) -> JointReading:
    return JointReading(
        stamp_to_ns(msg.header.stamp), log_ns, msg.name, msg.position, msg.velocity
    )


class JointStateReader:
    """A bag's JointState bytes -> readings.

    The node's own CDR decoder for rosbag2 data (rosbags' full deserialisation is
    several times slower); rosbags' for ROS 1 bags and whatever that decoder leaves.
    """

    def __init__(self, reader: AnyReader) -> None:
        self._reader = reader
        self._decoder = JointStateDecoder() if reader.is2 else None

    def __call__(self, raw: bytes, msgtype: str, log_ns: int) -> JointReading:
        """The reading of one message of type ``msgtype`` logged at ``log_ns``."""
        if self._decoder is not None:
            try:
                got = self._decoder.decode(raw)
            except ValueError:
                got = None
            if got is not None:
                return JointReading(got.sec * 1_000_000_000 + got.nanosec, log_ns, got.name,
                                    got.position, got.velocity)
        return _reading(self._reader.deserialize(raw, msgtype), log_ns)


Passthrough = Callable[[Connection, int, bytes], None]


@dataclass(frozen=True)
class Stream:
    """How a bag's messages become readings, besides which topics are read.

    ``passthrough``: every message of the bag is also handed to it raw, in log time order
    (``replay --keep-input``). ``window`` and ``jump_back_ns``: the stamp-order rule's
    (:class:`Reorder`). ``imu_by_log_time`` (``imu_stamp_source: receive_time``): an Imu
    sample's stamp is its log time (the IMU's own stamps are on another clock).
    """

    passthrough: Passthrough | None = None
    window: int = REORDER_WINDOW
    jump_back_ns: int = 1_000_000_000
    imu_by_log_time: bool = False


REPLAY = Stream()  # the defaults: replay's own


# What is yielded narrows with the topics asked for: the wheels alone, with the gyro, with
# a reference too (the type checker then knows, e.g., what a batch decode may take).
@overload
def iter_readings(reader: AnyReader, topic: str = ..., imu_topic: None = None,
                  reference_topic: None = None, stream: Stream = ...) -> Iterator[JointReading]: ...


@overload
def iter_readings(reader: AnyReader, topic: str, imu_topic: str | None,
                  reference_topic: None = None, stream: Stream = ...
                  ) -> Iterator[JointReading | ImuSample]: ...


@overload
def iter_readings(reader: AnyReader, topic: str, imu_topic: str | None,
                  reference_topic: str | None, stream: Stream = ...) -> Iterator[Reading]: ...


def iter_readings(
    reader: AnyReader,
    topic: str = "/joint_states",
    imu_topic: str | None = None,
    reference_topic: str | None = None,
    stream: Stream = REPLAY,
) -> Iterator[Reading]:
    """An open reader's JointState readings by header stamp, streaming; more topics on request.

    ``imu_topic``: its Imu samples too (:class:`ImuSample`); ``reference_topic``: its
    Odometry or PoseStamped messages as :class:`ReferenceSample` (``replay
    --reference-topic``). All go through one reordering by stamp (:class:`Reorder`), so
    a wheel reading comes after the gyro samples up to its stamp.
    """
    joints = connections_for(reader, topic, (JOINT_STATE,))
    imus = [] if imu_topic is None else connections_for(reader, imu_topic, (IMU,))
    refs = [] if reference_topic is None else connections_for(reader, reference_topic,
                                                              REFERENCE_TYPES)
    passthrough = stream.passthrough
    conns = reader.connections if passthrough is not None else joints + imus + refs
    joint_ids, imu_ids = {id(c) for c in joints}, {id(c) for c in imus}
    ref_ids = {id(c) for c in refs}
    decode = JointStateReader(reader)
    order = Reorder(stream.window, stream.jump_back_ns)
    for conn, log_ns, raw in reader.messages(connections=conns):
        item: Reading
        if passthrough is not None:
            passthrough(conn, log_ns, raw)
        if id(conn) in joint_ids:
            item = decode(raw, conn.msgtype, log_ns)
        elif id(conn) in imu_ids:
            w = (msg := reader.deserialize(raw, conn.msgtype)).angular_velocity
            cov = tuple(float(c) for c in msg.angular_velocity_covariance)
            # imu_stamp_source receive_time: ordered (and fed) by the log time.
            stamp = log_ns if stream.imu_by_log_time else stamp_to_ns(msg.header.stamp)
            item = ImuSample(stamp, log_ns, w.x, w.y, w.z, cov)
        elif id(conn) in ref_ids:
            stamp, x, y, yaw = reference_pose(reader.deserialize(raw, conn.msgtype))
            item = ReferenceSample(stamp, log_ns, x, y, yaw)
        else:
            continue
        yield from order.push(item)
    yield from order.flush()


def read_joint_states(
    path: str | Path, topic: str = "/joint_states", jump_back_ns: int = 1_000_000_000
) -> Iterator[JointReading]:
    """Open ``path`` and stream its JointState readings in stamp order."""
    with open_bag(path) as reader:
        yield from iter_readings(reader, topic, stream=Stream(jump_back_ns=jump_back_ns))
