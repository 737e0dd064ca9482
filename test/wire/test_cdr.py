"""The node's CDR decoder and layouts against rclpy's own serialisation (the oracle).

Bytes are compared through rclpy: what we decode must equal what rclpy serialised, and
what we encode must deserialise (with rclpy) to the message rclpy would have sent, at
the same length. Byte-for-byte equality is not the test: Fast CDR leaves its alignment
padding uninitialised, so rclpy's own bytes differ from run to run there.
"""

from __future__ import annotations

import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from nav_msgs.msg import Odometry
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import JointState
from tf2_msgs.msg import TFMessage

from diffdrive_odom.tools.bags import bagio, cdrconvert
from diffdrive_odom.wire.jointstate import JointStateDecoder
from diffdrive_odom.wire.odometry import OdometryLayout, TransformLayout

from rosutil import DATA

CASES = settings(derandomize=True, deadline=None, database=None, max_examples=400)

# Every length mod 4 and 8, non-ASCII included; no NUL (rclpy cuts a string there) and
# no lone surrogate (not UTF-8).
texts = st.text(st.characters(exclude_categories=["Cs"], exclude_characters="\x00"),
                max_size=13)
doubles = st.floats(allow_nan=True, allow_infinity=True)
finite = st.floats(allow_nan=False, allow_infinity=False)
arrays = st.lists(doubles, max_size=6)
sec32 = st.integers(-(2**31), 2**31 - 1)
nsec32 = st.integers(0, 2**32 - 1)


def _same(a: tuple[float, ...], b: list[float]) -> bool:
    """Equal as IEEE bit patterns (NaN == NaN)."""
    return struct.pack(f"<{len(a)}d", *a) == struct.pack(f"<{len(b)}d", *b)


def joint_state(sec: int, nsec: int, frame: str, names: list[str], pos: list[float],
                vel: list[float], eff: list[float]) -> JointState:
    msg = JointState(name=names, position=pos, velocity=vel, effort=eff)
    msg.header.frame_id = frame
    msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nsec
    return msg


@CASES
@given(st.lists(st.tuples(sec32, nsec32, texts, st.lists(texts, max_size=4), arrays, arrays,
                          arrays), min_size=1, max_size=4))
def test_decoder_reads_what_rclpy_wrote(messages: list[tuple]) -> None:  # type: ignore[type-arg]
    """Several messages through one decoder: its name cache never carries one message's
    names into the next."""
    decoder = JointStateDecoder()
    for sec, nsec, frame, names, pos, vel, eff in messages * 2:
        got = decoder.decode(serialize_message(joint_state(sec, nsec, frame, names, pos, vel,
                                                           eff)))
        assert got is not None
        assert (got.sec, got.nanosec, got.name) == (sec, nsec, tuple(names))
        assert _same(got.position, pos) and _same(got.velocity, vel)


def test_every_cut_short_message_is_refused_not_misread() -> None:
    raw = serialize_message(joint_state(7, 8, "odd", ["left_wheel_joint", "r"], [1.0, 2.0],
                                        [3.0], [4.0, 5.0]))
    decoder = JointStateDecoder()
    assert decoder.decode(raw) is not None
    for n in range(len(raw)):
        with pytest.raises(ValueError):
            if decoder.decode(raw[:n]) is None:  # no encapsulation header left
                raise ValueError
    # Garbage after the message (a sender's own padding) is not ours to judge.
    assert decoder.decode(raw + b"\x00" * 4) is not None


@pytest.mark.parametrize("where", ["names", "position"])
def test_a_corrupt_count_is_refused_at_once(where: str) -> None:
    msg = joint_state(1, 2, "", ["a", "b"], [1.0, 2.0], [], [])
    raw = bytearray(serialize_message(msg))
    # Header: 4 encapsulation + 8 stamp + 4 length + 1 NUL of an empty frame_id, padded to 20.
    at = 20 if where == "names" else 20 + 4 + (4 + 2) + 2 + (4 + 2) + 2  # names, padded
    assert struct.unpack_from("<I", raw, at)[0] == 2
    struct.pack_into("<I", raw, at, 0xFFFFFFFF)
    with pytest.raises(ValueError, match="announced"):
        JointStateDecoder().decode(bytes(raw))


def test_another_encapsulation_is_left_to_the_fallback() -> None:
    raw = serialize_message(joint_state(1, 2, "", ["a"], [1.0], [], []))
    assert JointStateDecoder().decode(b"\x00\x00" + raw[2:]) is None  # big-endian CDR
    assert JointStateDecoder().decode(b"") is None


def expected_odometry(frame: str, child: str, sec: int, nsec: int, v: list[float],
                      pose_cov: list[float], twist_cov: list[float]) -> Odometry:
    odom = Odometry()
    odom.header.frame_id, odom.child_frame_id = frame, child
    odom.header.stamp.sec, odom.header.stamp.nanosec = sec, nsec
    p = odom.pose.pose
    p.position.x, p.position.y, p.orientation.z, p.orientation.w = v[:4]
    odom.twist.twist.linear.x, odom.twist.twist.angular.z = v[4:]
    odom.pose.covariance, odom.twist.covariance = pose_cov, twist_cov
    return odom


@CASES
@given(texts, texts, sec32, nsec32, st.lists(finite, min_size=6, max_size=6),
       st.lists(finite, min_size=36, max_size=36), st.lists(finite, min_size=36, max_size=36))
def test_odometry_layout_is_what_rclpy_reads(frame: str, child: str, sec: int, nsec: int,
                                             v: list[float], pose_cov: list[float],
                                             twist_cov: list[float]) -> None:
    layout = OdometryLayout(frame, child)
    layout.encode(1, 1, 9.0, 9.0, 9.0, 9.0, 9.0, 9.0)  # values of an earlier message
    layout.covariance(pose_cov, twist_cov)
    raw = layout.encode(sec, nsec, *v)
    want = expected_odometry(frame, child, sec, nsec, v, pose_cov, twist_cov)
    assert deserialize_message(raw, Odometry) == want
    assert len(raw) == len(serialize_message(want))


def test_odometry_layout_keeps_its_covariance_until_told() -> None:
    layout = OdometryLayout("odom", "base_link")
    cov = [float(i) for i in range(36)]
    layout.covariance(cov, cov[::-1])
    for _ in range(2):
        got = deserialize_message(layout.encode(3, 4, 1.0, 2.0, 0.0, 1.0, 0.5, 0.1), Odometry)
        assert list(got.pose.covariance) == cov and list(got.twist.covariance) == cov[::-1]
        assert got.pose.pose.position.z == 0.0 and got.pose.pose.orientation.x == 0.0


@CASES
@given(texts, texts, sec32, nsec32, st.lists(finite, min_size=4, max_size=4))
def test_transform_layout_is_what_rclpy_reads(frame: str, child: str, sec: int, nsec: int,
                                              v: list[float]) -> None:
    raw = TransformLayout(frame, child).encode(sec, nsec, *v)
    got = deserialize_message(raw, TFMessage)
    assert len(got.transforms) == 1
    t = got.transforms[0]
    assert (t.header.frame_id, t.child_frame_id) == (frame, child)
    assert (t.header.stamp.sec, t.header.stamp.nanosec) == (sec, nsec)
    tr, rot = t.transform.translation, t.transform.rotation
    assert [tr.x, tr.y, tr.z, rot.x, rot.y, rot.z, rot.w] == [v[0], v[1], 0.0, 0.0, 0.0, v[2],
                                                              v[3]]
    assert len(raw) == len(serialize_message(got))


@pytest.mark.parametrize("bag", ["optiodom/square_231220200029_run-01",
                                 "optiodom/square_231220200029_run-04",
                                 "turtlebot3_sim/turtlebot3.bag"])
def test_decoder_agrees_with_rosbags_on_every_reading_of_the_data(bag: str) -> None:
    """Real recordings: every JointState as rosbags decodes it. The ROS 1 bag's
    messages are first turned into ROS 2 CDR by rosbags, as ``replay --keep-input``
    does."""
    decoder = JointStateDecoder()
    count = 0
    with bagio.open_bag(DATA / bag) as reader:
        convert = cdrconvert.CdrConverter(reader)
        for conn, _, raw in reader.messages(connections=bagio.connections_for(reader,
                                                                              "/joint_states")):
            want = reader.deserialize(raw, conn.msgtype)
            got = decoder.decode(convert(conn, raw))
            assert got is not None
            assert (got.sec, got.nanosec) == (want.header.stamp.sec, want.header.stamp.nanosec)
            assert got.name == tuple(want.name)
            assert _same(got.position, list(want.position))
            assert _same(got.velocity, list(want.velocity))
            count += 1
    assert count > 1000
