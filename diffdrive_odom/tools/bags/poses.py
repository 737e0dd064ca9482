"""A bag's poses as a trajectory: the odometry or the ground truth eval, replay and calibrate judge.

Any pose type (PoseStamped, PoseWithCovarianceStamped, Odometry, TransformStamped, or
/tf's TFMessage for one child frame) becomes a
:class:`~diffdrive_odom.core.evaluation.metrics.Trajectory` by header stamp. Which topic
is the ground truth is decided here once (:func:`reference_topic`): the one asked for,
else :data:`~diffdrive_odom.tools.cmdline.args.DEFAULT_REFERENCE`, else the bag's only
topic named like ground truth; every tool that reads one finds it the same way.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

from diffdrive_odom.core.evaluation.metrics import Trajectory
from diffdrive_odom.tools.bags import bagio
from diffdrive_odom.tools.bags.bagio import TF_MESSAGE
from diffdrive_odom.tools.cmdline.args import DEFAULT_REFERENCE
from diffdrive_odom.wire.conversions import quaternion_to_yaw, reference_pose, stamp_to_ns

POSE_TYPES = (
    "geometry_msgs/msg/PoseStamped",
    "geometry_msgs/msg/PoseWithCovarianceStamped",
    bagio.ODOMETRY,
    "geometry_msgs/msg/TransformStamped",
    TF_MESSAGE,
)


Notify = Callable[[str], None]
# Name parts that mark a topic as ground truth (sim_node and the demo write
# /ground_truth/odom; motion-capture bridges use mocap/vicon/optitrack names).
REFERENCE_HINTS = ("ground_truth", "groundtruth", "mocap", "vicon", "optitrack")


def reference_topic(
    bag: str | Path, requested: str | None, exclude: Iterable[str] = (),
    notify: Notify | None = None, flag: str = "--ground-truth TOPIC",
) -> str:
    """The reference topic to read: ``requested``, else the default, else the one candidate.

    With no topic asked for and no :data:`DEFAULT_REFERENCE` in the bag, a pose-typed
    topic whose name looks like ground truth is taken when it is the only one (and
    ``notify`` is told); otherwise BagError lists what there is. ``flag``: how the
    command running it names another topic (eval's, calibrate's ``--ground-truth``;
    replay's ``--eval TOPIC``), in both.
    """
    if requested is not None:
        return requested
    with bagio.open_bag(bag) as reader:
        posed: list[str] = sorted(
            {str(c.topic) for c in reader.connections if c.msgtype in POSE_TYPES}
            - set(exclude))
    if DEFAULT_REFERENCE in posed:
        return DEFAULT_REFERENCE
    plausible = [t for t in posed if any(h in t.lower() for h in REFERENCE_HINTS)]
    if len(plausible) == 1:
        if notify is not None:
            notify(f"{DEFAULT_REFERENCE} is not in {bag}; using {plausible[0]}, its only "
                   f"ground-truth topic ({flag} to choose another)")
        return plausible[0]
    which = "there are several ground-truth topics" if plausible else (
        "there is no ground-truth topic")
    raise bagio.BagError(
        f"{bag}: {DEFAULT_REFERENCE} is absent and {which}; name one with "
        f"{flag} (pose topics: {', '.join(posed) or 'none'})")


def read_trajectory(
    bag: str | Path, topic: str, child_frame: str | None = None,
    frame_flag: str = "--child-frame", notify: Notify | None = None,
) -> Trajectory:
    """Poses on ``topic`` by header stamp; for /tf, the transforms to ``child_frame``.

    On a TFMessage topic without ``child_frame``, the only child frame is used (and
    ``notify`` told); with several, BagError names them and ``frame_flag``, the
    option that chooses one.
    """
    by_child: dict[str, list[list[float]]] = {}  # stamps [ns], x, y, yaw
    seen: set[str] = set()
    with bagio.open_bag(bag) as reader:
        conns = bagio.connections_for(reader, topic, POSE_TYPES)
        for conn, _, raw in reader.messages(connections=conns):
            msg: Any = reader.deserialize(raw, conn.msgtype)
            items = list(msg.transforms) if conn.msgtype == TF_MESSAGE else [msg]
            for item in items:
                key = ""  # every pose of a topic that is not a TFMessage
                if conn.msgtype in (TF_MESSAGE, "geometry_msgs/msg/TransformStamped"):
                    child = str(item.child_frame_id).lstrip("/")
                    seen.add(child)
                    if child_frame is not None and child != child_frame.lstrip("/"):
                        continue
                    key = child if conn.msgtype == TF_MESSAGE else ""
                    p, q = item.transform.translation, item.transform.rotation
                    pose = (stamp_to_ns(item.header.stamp), float(p.x), float(p.y),
                            quaternion_to_yaw(q))
                else:  # PoseStamped, PoseWithCovarianceStamped, Odometry
                    pose = reference_pose(item)
                for column, value in zip(by_child.setdefault(key, [[], [], [], []]), pose,
                                         strict=True):
                    column.append(value)
    frames = sorted(k for k in by_child if k)
    if child_frame is None and len(frames) > 1:
        raise bagio.BagError(f"{topic}: name the child frame ({frame_flag}); frames: {frames}")
    if child_frame is None and len(frames) == 1 and notify is not None:
        notify(f"{topic}: using child frame '{frames[0]}', the only one ({frame_flag} to "
               "choose)")
    if not by_child:
        if seen:
            raise bagio.BagError(
                f"{topic}: no transform to '{child_frame}' ({frame_flag}); frames: "
                f"{sorted(seen)}")
        raise bagio.BagError(f"{topic}: no poses")
    ((ts, xs, ys, yaws),) = by_child.values()
    return Trajectory.from_arrays(ts, xs, ys, yaws)
