"""Bag I/O: reading JointState from rosbag2 and ROS 1 bags, writing odometry bags and CSV.

Every read is checked against an independent reader (mcap-ros2-support for MCAP, rclpy's
own CDR deserializer for converted ROS 1 data) and every write is read back.
"""

from __future__ import annotations

import csv
import itertools
import math
import random
from decimal import Decimal
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rclpy.serialization import deserialize_message
from rosbags.highlevel import AnyReader
from sensor_msgs.msg import JointState

from diffdrive_odom.tools.bags import bagio, bagreadings, bagwriter, cdrconvert
from diffdrive_odom.tools.cmdline.outputs import STORAGES
from diffdrive_odom.tools.replaying import csvout
from diffdrive_odom.wire.conversions import quaternion_to_yaw
from diffdrive_odom.wire.odometry import OdometryLayout, TransformLayout

from bagutil import mcap_messages
from rosutil import DATA

RUN04 = DATA / "optiodom" / "square_231220200029_run-04"
TB3 = DATA / "turtlebot3_sim" / "turtlebot3.bag"


def _ns(t: Any) -> int:
    return int(t.sec) * 10**9 + int(t.nanosec)


def test_optiodom_readings_equal_an_independent_mcap_reader() -> None:
    readings = list(bagreadings.read_joint_states(RUN04))
    independent = [m for _, _, m in mcap_messages(RUN04, ["/joint_states"])]
    assert len(readings) == len(independent) == 1385  # metadata.yaml's count
    independent.sort(key=lambda m: _ns(m.header.stamp))
    for r, m in zip(readings, independent, strict=True):
        assert r.stamp_ns == _ns(m.header.stamp)
        assert list(r.names) == list(m.name) == ["left_wheel_joint", "right_wheel_joint"]
        assert list(r.position) == list(m.position)
        assert list(r.velocity) == list(m.velocity)
    stamps = [r.stamp_ns for r in readings]
    assert all(b > a for a, b in itertools.pairwise(stamps))
    assert stamps[0] == 1_600_000_000 * 10**9  # the data README: 1.6e9 s + run time


def test_ros1_bag_reads_with_its_quirks() -> None:
    readings = list(bagreadings.read_joint_states(TB3))
    assert len(readings) == 2741
    first = readings[0]
    # Data README: right wheel listed first, non-zero first positions, sim time from 112 s.
    assert list(first.names) == ["wheel_right_joint", "wheel_left_joint"]
    assert first.position[0] == pytest.approx(-4.23, abs=0.01)
    assert first.position[1] == pytest.approx(9.01, abs=0.01)
    assert 112 * 10**9 <= first.stamp_ns < 113 * 10**9
    stamps = [r.stamp_ns for r in readings]
    assert all(b >= a for a, b in itertools.pairwise(stamps))


def test_ros1_messages_convert_to_cdr_that_rclpy_decodes() -> None:
    """Converted bytes decode with rclpy's own deserializer to the ROS 1 values."""
    checked = 0
    with bagio.open_bag(TB3) as reader:
        convert = cdrconvert.CdrConverter(reader)
        conns = [c for c in reader.connections if c.topic == "/joint_states"]
        for conn, _, raw in reader.messages(connections=conns):
            ros1 = reader.deserialize(raw, conn.msgtype)
            msg = deserialize_message(convert(conn, raw), JointState)
            assert _ns(msg.header.stamp) == _ns(ros1.header.stamp)  # type: ignore[attr-defined]
            assert list(msg.name) == list(ros1.name)  # type: ignore[attr-defined]
            assert list(msg.position) == list(ros1.position)  # type: ignore[attr-defined]
            checked += 1
            if checked == 50:
                break
    assert checked == 50


def _joint_state(store: Any, ns: int, pos: tuple[float, float]) -> Any:
    t = store.types
    sec, nsec = divmod(ns, 10**9)
    return t[bagio.JOINT_STATE](
        header=t["std_msgs/msg/Header"](
            stamp=t["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec), frame_id=""),
        name=["left_wheel_joint", "right_wheel_joint"],
        position=np.array(pos, dtype=np.float64),
        velocity=np.zeros(0), effort=np.zeros(0),
    )


@pytest.mark.parametrize("storage", STORAGES)
def test_readings_come_out_in_stamp_order_when_logged_out_of_order(
    tmp_path: Path, storage: str
) -> None:
    rng = random.Random(5)
    stamps = [10**9 + k * 10**7 for k in range(500)]
    logged = stamps[:]
    for i in range(0, len(logged) - 8, 8):  # each block of 8 arrives shuffled
        block = logged[i:i + 8]
        rng.shuffle(block)
        logged[i:i + 8] = block
    bag = tmp_path / "shuffled"
    with bagwriter.BagWriter(bag, storage) as w:
        w.add_topic("/joint_states", bagio.JOINT_STATE)
        for k, ns in enumerate(logged):
            w.write("/joint_states", 2 * 10**9 + k, _joint_state(w.typestore, ns, (ns, -ns)))
    readings = list(bagreadings.read_joint_states(bag))
    assert [r.stamp_ns for r in readings] == stamps
    assert all(r.position[0] == r.stamp_ns for r in readings)


@pytest.mark.parametrize("storage", STORAGES)
def test_odometry_and_tf_round_trip(tmp_path: Path, storage: str) -> None:
    """The node's byte layouts, as replay writes them, read back by rosbags and (MCAP)
    by mcap-ros2-support."""
    bag = tmp_path / "odom"
    store = bagio.typestore()
    odom, transform = OdometryLayout("odom", "base_link"), TransformLayout("odom", "base_link")
    pose_cov = [float(i) for i in range(36)]
    twist_cov = [0.5 * i for i in range(36)]
    poses = [(10**9 * 1_700_000_000 + 123 + k * 50_000_000, 0.1 * k, -0.2 * k,
              math.remainder(0.7 * k, 2 * math.pi), 0.3, -0.4) for k in range(20)]
    with bagwriter.BagWriter(bag, storage) as w:
        w.add_topic("/odom", bagio.ODOMETRY)
        w.add_topic("/tf", bagio.TF_MESSAGE)
        for ns, x, y, yaw, v, om in poses:
            odom.covariance(pose_cov, twist_cov)
            w.write_cdr("/odom", ns, odom.planar(ns, x, y, yaw, v, om))
            w.write_cdr("/tf", ns, transform.planar(ns, x, y, yaw))
    with AnyReader([bag], default_typestore=store) as reader:
        odoms = [reader.deserialize(raw, c.msgtype)
                 for c, _, raw in reader.messages() if c.topic == "/odom"]
        tfs = [reader.deserialize(raw, c.msgtype)
               for c, _, raw in reader.messages() if c.topic == "/tf"]
    assert len(odoms) == len(tfs) == len(poses)
    for o, tf, (ns, x, y, yaw, v, om) in zip(odoms, tfs, poses, strict=True):
        assert _ns(o.header.stamp) == ns and o.header.frame_id == "odom"  # type: ignore[attr-defined]
        assert o.child_frame_id == "base_link"  # type: ignore[attr-defined]
        p = o.pose.pose  # type: ignore[attr-defined]
        assert (p.position.x, p.position.y) == (x, y)
        assert 2 * math.atan2(p.orientation.z, p.orientation.w) == pytest.approx(yaw, abs=1e-12)
        assert list(o.pose.covariance) == pose_cov  # type: ignore[attr-defined]
        assert list(o.twist.covariance) == twist_cov  # type: ignore[attr-defined]
        assert o.twist.twist.linear.x == v and o.twist.twist.angular.z == om  # type: ignore[attr-defined]
        t = tf.transforms[0]  # type: ignore[attr-defined]
        assert t.child_frame_id == "base_link" and t.header.frame_id == "odom"
        assert (t.transform.translation.x, t.transform.translation.y) == (x, y)
    if storage == "mcap":  # an independent reader
        got = [(t, m) for t, _, m in mcap_messages(bag)]
        indep_odom = [m for t, m in got if t == "/odom"]
        indep_tf = [m for t, m in got if t == "/tf"]
        assert len(indep_odom) == len(indep_tf) == len(poses)
        for o, tfm, (ns, x, y, yaw, _, _) in zip(indep_odom, indep_tf, poses, strict=True):
            assert _ns(o.header.stamp) == ns
            assert (o.pose.pose.position.x, o.pose.pose.position.y) == (x, y)
            assert list(o.pose.covariance) == pose_cov
            assert tfm.transforms[0].transform.translation.x == x
            assert quaternion_to_yaw(o.pose.pose.orientation) == pytest.approx(yaw, abs=1e-12)


def test_csv_header_is_the_documented_one_and_values_round_trip(tmp_path: Path) -> None:
    path = tmp_path / "o.csv"
    rows = [(1_600_000_000_050_000_001, 1 / 3, -2 / 7, math.pi, 0.1, -1e-17, "updated")]
    with csvout.CsvWriter(path) as out:
        for ns, x, y, yaw, v, w, status in rows:
            out.row(ns, x, y, yaw, linear=v, angular=w, status=status)
    with open(path, newline="", encoding="utf-8") as f:
        got = list(csv.reader(f))
    assert tuple(got[0]) == csvout.CSV_COLUMNS
    assert all(f"``{c}``" in (csvout.__doc__ or "") for c in csvout.CSV_COLUMNS)
    ns, x, y, yaw, v, w, status = rows[0]
    back = got[1]
    assert int(back[0]) == ns and back[1] == "1600000000.050000001"
    assert [float(c) for c in back[2:7]] == [x, y, yaw, v, w] and back[7] == status


def test_csv_stamps_round_trip_exactly(tmp_path: Path) -> None:
    """1600000000.100000001 s: a float in seconds cannot hold it (0.24 us spacing there)."""
    ns = 1_600_000_000 * 10**9 + 100_000_001
    assert float(ns * 1e-9) != Decimal("1600000000.100000001")  # why floats will not do
    path = tmp_path / "o.csv"
    with csvout.CsvWriter(path) as out:
        out.row(ns, 0.0, 0.0, 0.0, linear=0.0, angular=0.0, status="updated")
    with open(path, newline="", encoding="utf-8") as f:
        row = dict(zip(csvout.CSV_COLUMNS, list(csv.reader(f))[1], strict=True))
    assert int(row["stamp_ns"]) == ns
    assert row["time"] == "1600000000.100000001"
    assert Decimal(row["time"]) * 10**9 == ns


def test_unusable_bags_raise_one_clear_error(tmp_path: Path) -> None:
    with pytest.raises(bagio.BagError, match="no such bag"):
        bagio.open_bag(tmp_path / "missing")
    (tmp_path / "empty_dir").mkdir()
    (tmp_path / "notes.txt").write_text("not a bag\n")
    (tmp_path / "fake.bag").write_text("not a bag either\n")
    for name, what in (("empty_dir", "no metadata.yaml and no .mcap or .db3 file"),
                       ("notes.txt", "not a readable bag"),
                       ("fake.bag", "not a ROS 1 bag")):
        with (pytest.raises(bagio.BagError, match=f"{name}: {what}.*; give a rosbag2 folder, "
                            r"an \.mcap or \.db3 file, or a ROS 1 \.bag$"),
              bagio.open_bag(tmp_path / name)):
            pass
    with pytest.raises(bagio.BagError, match=r"/ground_truth/pose"):
        list(bagreadings.read_joint_states(RUN04, "/wheels"))
    with bagio.open_bag(RUN04) as reader, pytest.raises(bagio.BagError, match="has type"):
        bagio.connections_for(reader, "/firmware/odom", [bagio.JOINT_STATE])
    (tmp_path / "exists").mkdir()
    with pytest.raises(bagio.BagError, match="exists"):
        bagwriter.BagWriter(tmp_path / "exists")
