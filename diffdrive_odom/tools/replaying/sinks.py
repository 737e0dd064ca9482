"""Where replay's published poses go: the output bag (odom, /tf), the CSV table, ``--eval``.

Kept apart from the engine (:mod:`diffdrive_odom.tools.replay`), which only decides
what is published; the bytes are the node's own layouts, so the bag holds what the
node would have sent.
"""

from __future__ import annotations

from array import array
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from diffdrive_odom.core.bulk.fastlane import Stretch
from diffdrive_odom.core.estimation.config import OdometrySettings
from diffdrive_odom.core.estimation.wheels.timeline import Status
from diffdrive_odom.core.evaluation.metrics import Trajectory
from diffdrive_odom.core.geometry.integration import Pose2D
from diffdrive_odom.core.uncertainty.propagation import (
    ZERO3,
    pose_message_covariance,
    twist_message_covariance,
)
from diffdrive_odom.wire.odometry import BulkOdometry, BulkTransform, planar_fields

if TYPE_CHECKING:  # the bag library only where a bag is read or written (``tools`` extra)
    from rosbags.highlevel import AnyReader
    from rosbags.interfaces import Connection

    from diffdrive_odom.tools.bags import bagreadings, bagwriter
    from diffdrive_odom.tools.replaying import csvout


@dataclass
class Published:
    """One pose the node would publish."""

    stamp_ns: int
    log_ns: int
    pose: Pose2D
    linear: float
    angular: float
    status: Status
    pose_covariance: Sequence[float]  # 6x6 row-major, as the node publishes it
    twist_covariance: Sequence[float]


class PoseLog:
    """Poses by stamp kept compactly (32 bytes each).

    Replay's published ones for ``--eval``; the demo's odometry and ground truth as received.
    """

    def __init__(self) -> None:
        self.stamp_ns = array("q")
        self.xyz = array("d")

    def add(self, stamp_ns: int, x: float, y: float, yaw: float) -> None:
        """Keep one planar pose."""
        self.stamp_ns.append(stamp_ns)
        self.xyz.extend((x, y, yaw))

    def trajectory(self) -> Trajectory:
        """The poses kept, as eval's trajectory (sorted, unwrapped)."""
        return Trajectory.from_arrays(
            np.frombuffer(self.stamp_ns, dtype=np.int64),
            *np.frombuffer(self.xyz, dtype=np.float64).reshape(-1, 3).T,
        )


def keep_input(
    reader: AnyReader, writer: bagwriter.BagWriter, odom_topic: str
) -> bagreadings.Passthrough:
    """Copy every input message (converted to CDR) into the output bag as it streams by."""
    from diffdrive_odom.tools.bags import bagio, cdrconvert

    convert = cdrconvert.CdrConverter(reader)
    for conn in reader.connections:
        if conn.topic == odom_topic:
            raise bagio.BagError(
                f"--keep-input: the input bag already has {conn.topic}; choose another "
                "--odom-topic for the replayed odometry")
    registered: set[str] = set()

    def passthrough(conn: Connection, log_ns: int, raw: bytes) -> None:
        data = convert(conn, raw)
        if conn.topic not in registered:
            writer.add_topic(conn.topic, conn.msgtype, convert.typestore)
            registered.add(conn.topic)
        writer.write_cdr(conn.topic, log_ns, data)

    return passthrough


class OutputSink:
    """Where each published pose goes: output bag, CSV table, ``--eval`` trajectory.

    Called with one :class:`Published`; :meth:`stretch` takes a whole stretch of the
    fast lane at once (the same bytes and text, built with numpy: writing one message
    at a time cost more than the odometry). The bag's topics are registered by the caller.
    """

    def __init__(self, settings: OdometrySettings, writer: bagwriter.BagWriter | None,
                 csv_out: csvout.CsvWriter | None, traj: PoseLog | None = None, *,
                 odom_topic: str = "/odom", tf_topic: str = "/tf") -> None:
        # The node's own byte layouts: the bag holds what the node would have published.
        self.odom = BulkOdometry(settings.odom_frame_id, settings.base_frame_id)
        self.transform = BulkTransform(settings.odom_frame_id, settings.base_frame_id)
        self.tf = settings.enable_odom_tf
        self.writer, self.csv_out, self.traj = writer, csv_out, traj
        self.odom_topic, self.tf_topic = odom_topic, tf_topic

    def __call__(self, p: Published) -> None:
        """One pose."""
        x, y, yaw = p.pose.x, p.pose.y, p.pose.theta
        if self.writer is not None:
            self.odom.covariance(p.pose_covariance, p.twist_covariance)
            self.writer.write_cdr(self.odom_topic, p.log_ns, self.odom.planar(
                p.stamp_ns, x, y, yaw, p.linear, p.angular))
            if self.tf:
                self.writer.write_cdr(self.tf_topic, p.log_ns,
                                      self.transform.planar(p.stamp_ns, x, y, yaw))
        if self.csv_out is not None:
            self.csv_out.row(p.stamp_ns, x, y, yaw, linear=p.linear, angular=p.angular,
                             status=p.status.value, pose_covariance=p.pose_covariance)
        if self.traj is not None:
            self.traj.add(p.stamp_ns, x, y, yaw)

    def stretch(self, st: Stretch) -> None:
        """Every pose of a fast-lane stretch (all ``updated``), as :meth:`__call__` one by one."""
        n = len(st.stamp_ns)
        if n == 0:
            return
        pcov, tcov = _covariances(st, n)
        if self.writer is not None:
            topics = [self.odom_topic]
            fields = planar_fields(st.stamp_ns, st.pose[:, 2].tolist())
            payloads = [self.odom.rows(fields, st.pose, st.twist, pcov, tcov)]
            if self.tf:
                topics.append(self.tf_topic)
                payloads.append(self.transform.rows(fields, st.pose))
            self.writer.write_rows(topics, np.asarray(st.log_ns, dtype=np.int64), payloads)
            # the layout keeps the last covariance, as the one-by-one path leaves it
            self.odom.covariance(pcov[-1].tolist(), tcov[-1].tolist())
        if self.csv_out is not None:
            self.csv_out.rows(st.stamp_ns, np.column_stack(
                (st.pose, st.twist, pcov[:, (0, 7, 35)])), Status.UPDATED.value)
        if self.traj is not None:
            self.traj.stamp_ns.extend(st.stamp_ns)
            self.traj.xyz.extend(st.pose.ravel().tolist())


# Entries of the 6x6 message matrices taken from the stretch's packed 3x3 / 2x2 ones
# (uncertainty.pose_message_covariance / twist_message_covariance, the one definition).
_POSE_AT = ((0, 0), (1, 1), (5, 2), (6, 1), (7, 3), (11, 4), (30, 2), (31, 4), (35, 5))
_TWIST_AT = ((0, 0), (5, 1), (30, 1), (35, 2))


def _covariances(st: Stretch, n: int) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """(n, 36) pose and twist message covariances of a stretch's published poses."""
    static_pose, static_twist = st.static
    if st.pose_covariance is None or st.twist_covariance is None:
        return (np.tile(np.asarray(static_pose, dtype=np.float64), (n, 1)),
                np.tile(np.asarray(static_twist, dtype=np.float64), (n, 1)))
    pose = np.tile(np.asarray(pose_message_covariance(ZERO3), dtype=np.float64), (n, 1))
    twist = np.tile(np.asarray(twist_message_covariance(((0.0, 0.0), (0.0, 0.0))),
                               dtype=np.float64), (n, 1))
    # Added to the floor the zero matrices' messages hold, as the scalar form adds them.
    for at, src in _POSE_AT:
        pose[:, at] += st.pose_covariance[:, src]
    for at, src in _TWIST_AT:
        twist[:, at] += st.twist_covariance[:, src]
    return pose, twist
