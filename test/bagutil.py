"""Shared helpers of the bag tests: an independent MCAP reader and params files."""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from gyrostreams import NAMES, T0, Truth
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore

from diffdrive_odom.tools.bags.bagio import ODOMETRY, TF_MESSAGE
from diffdrive_odom.wire.conversions import yaw_to_quaternion

STORE = get_typestore(Stores.ROS2_JAZZY)
JS, IMU = "sensor_msgs/msg/JointState", "sensor_msgs/msg/Imu"
POSE = "geometry_msgs/msg/PoseStamped"

OPTIODOM_PARAMS = {"wheel_radius": 0.042, "wheel_separation": 0.200}
TB3_PARAMS = {
    "wheel_radius": 0.033,
    "wheel_separation": 0.287,
    "left_wheel_names": ["wheel_left_joint"],
    "right_wheel_names": ["wheel_right_joint"],
}


def mcap_messages(
    bag: Path, topics: Sequence[str] | None = None
) -> Iterator[tuple[str, int, Any]]:
    """(topic, log time, message) decoded by mcap-ros2-support, not by rosbags."""
    files = sorted(bag.glob("*.mcap")) if bag.is_dir() else [bag]
    assert files, f"no .mcap in {bag}"
    for path in files:
        with open(path, "rb") as f:
            reader = make_reader(f, decoder_factories=[DecoderFactory()])
            for _, channel, message, msg in reader.iter_decoded_messages(topics=topics):
                yield channel.topic, message.log_time, msg


def write_params(path: Path, values: dict[str, Any], node: str = "odometry_node") -> Path:
    """A ROS 2 params YAML for ``node`` (the form ``--params-file`` takes)."""
    import yaml

    path.write_text(yaml.safe_dump({node: {"ros__parameters": values}}), encoding="utf-8")
    return path


class OdomMessages:
    """Builds nav_msgs/Odometry and tf2_msgs/TFMessage with rosbags' message classes.

    Test bags written this way are independent of the byte layouts the node and replay
    use (:mod:`diffdrive_odom.wire.odometry`).
    """

    def __init__(self, store: Typestore, odom_frame: str, base_frame: str) -> None:
        t = store.types
        self._t = t
        self.odom_frame = odom_frame
        self.base_frame = base_frame

    def _header(self, ns: int) -> Any:
        t = self._t
        sec, nanosec = divmod(int(ns), 1_000_000_000)
        return t["std_msgs/msg/Header"](
            stamp=t["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec),
            frame_id=self.odom_frame,
        )

    def _quaternion(self, yaw: float) -> Any:
        x, y, z, w = yaw_to_quaternion(yaw)
        return self._t["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w)

    def odometry(
        self,
        ns: int,
        x: float,
        y: float,
        yaw: float,
        *,
        linear: float,
        angular: float,
        pose_covariance: Sequence[float],
        twist_covariance: Sequence[float],
    ) -> Any:
        """Build an Odometry as the node publishes it (header stamp = measurement time)."""
        t = self._t
        vec = t["geometry_msgs/msg/Vector3"]
        pose = t["geometry_msgs/msg/Pose"](
            position=t["geometry_msgs/msg/Point"](x=x, y=y, z=0.0),
            orientation=self._quaternion(yaw),
        )
        twist = t["geometry_msgs/msg/Twist"](
            linear=vec(x=linear, y=0.0, z=0.0), angular=vec(x=0.0, y=0.0, z=angular)
        )
        return t[ODOMETRY](
            header=self._header(ns),
            child_frame_id=self.base_frame,
            pose=t["geometry_msgs/msg/PoseWithCovariance"](
                pose=pose, covariance=np.asarray(pose_covariance, dtype=np.float64)
            ),
            twist=t["geometry_msgs/msg/TwistWithCovariance"](
                twist=twist, covariance=np.asarray(twist_covariance, dtype=np.float64)
            ),
        )

    def tf(self, ns: int, x: float, y: float, yaw: float) -> Any:
        """Build a TFMessage with the single odom -> base transform."""
        t = self._t
        transform = t["geometry_msgs/msg/Transform"](
            translation=t["geometry_msgs/msg/Vector3"](x=x, y=y, z=0.0),
            rotation=self._quaternion(yaw),
        )
        stamped = t["geometry_msgs/msg/TransformStamped"](
            header=self._header(ns), child_frame_id=self.base_frame, transform=transform
        )
        return t[TF_MESSAGE](transforms=[stamped])


def _stamp(ns: int) -> Any:
    sec, nsec = divmod(ns, 10**9)
    return STORE.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec)


def _header(ns: int, frame: str) -> Any:
    return STORE.types["std_msgs/msg/Header"](stamp=_stamp(ns), frame_id=frame)


def joint_state_msg(t: Any, stamp_ns: int, left: float, right: float) -> Any:
    """A two-wheel JointState (positions only) of the typestore types ``t``."""
    sec, nsec = divmod(int(stamp_ns), 10**9)
    return t[JS](header=t["std_msgs/msg/Header"](
                     stamp=t["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec), frame_id=""),
                 name=list(NAMES), position=np.array([left, right]),
                 velocity=np.zeros(0), effort=np.zeros(0))


def write_sensor_bag(path: Path, messages: Iterable[tuple[Any, ...]],
                     imu_hz: float, noise_density: float = 3e-4, truth: Truth | None = None,
                     truth_hz: float = 100.0, imu: bool = True,
                     truth_topic: str = "/ground_truth/pose",
                     static: tuple[str, float, float, float] | None = None) -> None:
    """An MCAP bag of ``gyrostreams`` messages, each logged at its receive time.

    JointStates on /joint_states (positions), Imu on /imu (the yaw rate, its
    angular_velocity_covariance honest: the density squared times the rate; ``imu``
    False: none written). ``truth``: its poses at ``truth_hz`` on ``truth_topic``
    (PoseStamped, stamped and logged at the true time). ``refstreams``' reference poses
    (if any) as PoseStamped on /reference. ``static``: (frame, x, y, yaw), the transform
    base_link -> frame latched on /tf_static before everything else.
    """
    t = STORE.types
    zero3 = t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
    cov = np.zeros(9)
    cov[8] = noise_density ** 2 * imu_hz
    writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
    with writer:
        joints = writer.add_connection("/joint_states", JS, typestore=STORE)
        imus = writer.add_connection("/imu", IMU, typestore=STORE) if imu else None
        if static is not None:
            frame, *pose = static
            latched = writer.add_connection("/tf_static", TF_MESSAGE, typestore=STORE)
            writer.write(latched, T0, bytes(STORE.serialize_cdr(
                OdomMessages(STORE, "base_link", frame).tf(T0, *pose), TF_MESSAGE)))
        if truth is not None:
            _write_truth(writer, truth, truth_hz, truth_topic)
        messages = list(messages)
        ref = (writer.add_connection("/reference", POSE, typestore=STORE)
               if any(m[0] == "r" for m in messages) else None)
        for kind, rx, stamp, a, b, *more in messages:
            if kind == "r" and ref is not None:
                writer.write(ref, rx, bytes(STORE.serialize_cdr(
                    pose_stamped_msg(stamp, a, b, more[0]), POSE)))
            elif kind == "j":
                msg = joint_state_msg(t, stamp, a, b)
                writer.write(joints, rx, bytes(STORE.serialize_cdr(msg, JS)))
            elif imus is not None:
                msg = t[IMU](
                    header=_header(stamp, "base_link"),
                    orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
                    orientation_covariance=np.array([-1.0, *[0.0] * 8]),
                    angular_velocity=t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=a),
                    angular_velocity_covariance=cov, linear_acceleration=zero3,
                    linear_acceleration_covariance=np.zeros(9))
                writer.write(imus, rx, bytes(STORE.serialize_cdr(msg, IMU)))


def _write_truth(writer: Writer, truth: Truth, rate_hz: float, topic: str) -> None:
    """``truth`` sampled at ``rate_hz`` as PoseStamped on ``topic``."""
    conn = writer.add_connection(topic, POSE, typestore=STORE)
    for s in np.arange(0.0, float(truth.t[-1]) + 1e-9, 1.0 / rate_hz):
        x, y, yaw = truth.at(float(s))
        stamp = T0 + round(float(s) * 1e9)
        msg = pose_stamped_msg(stamp, x, y, yaw)
        writer.write(conn, stamp, bytes(STORE.serialize_cdr(msg, POSE)))


def pose_stamped_msg(stamp_ns: int, x: float, y: float, yaw: float) -> Any:
    """A planar pose as rosbags' PoseStamped, frame ``map``."""
    t = STORE.types
    qx, qy, qz, qw = yaw_to_quaternion(yaw)
    return t[POSE](header=_header(stamp_ns, "map"), pose=t["geometry_msgs/msg/Pose"](
        position=t["geometry_msgs/msg/Point"](x=x, y=y, z=0.0),
        orientation=t["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw)))


def mounted_copy(src: Path, dst: Path, x: float, y: float, yaw: float,
                 topic: str = "/ground_truth/pose") -> Path:
    """``src`` with its PoseStamped ``topic`` moved onto a mount: ``R = B M``, M = (x, y, yaw).

    What a reference that far off the axle and that much turned would have recorded of
    the same robot (the point ``p + R(theta) (x, y)``, its heading ``theta + yaw``),
    written here with plain trigonometry, not the package's mount. Other topics as they
    are.
    """
    from rosbags.rosbag2 import Reader

    with Reader(src) as reader, Writer(dst, version=9,
                                       storage_plugin=StoragePlugin.MCAP) as writer:
        out = {c.id: writer.add_connection(c.topic, c.msgtype, typestore=STORE)
               for c in reader.connections}
        for conn, log_ns, raw in reader.messages():
            if conn.topic == topic:
                msg = STORE.deserialize_cdr(raw, conn.msgtype)
                p, q = msg.pose.position, msg.pose.orientation
                theta = 2.0 * np.arctan2(q.z, q.w)
                c, s = np.cos(theta), np.sin(theta)
                msg = pose_stamped_msg(msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec,
                                       float(p.x + c * x - s * y), float(p.y + s * x + c * y),
                                       float(theta + yaw))
                raw = bytes(STORE.serialize_cdr(msg, conn.msgtype))
            writer.write(out[conn.id], log_ns, raw)
    return dst
