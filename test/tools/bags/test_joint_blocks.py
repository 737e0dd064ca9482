"""Runs of alike JointState messages read as blocks give exactly the one-by-one readings.

- cdr.JointBlockDecoder against rosbags' own deserialisation (the bytes oracle), on
  streams whose layout changes (names, frame_id, array lengths), with padding bytes
  scribbled as Fast CDR leaves them, big-endian and cut-off messages among them.
- reorder.Reorder with blocks against the plain heap rule written out here: any mix of
  blocks and single readings, out-of-order stamps and jumps back, comes out in the
  order the heap gives one reading at a time.
- Real bag files: iter_joint_blocks opened equals iter_readings, and replay writes
  the same bytes either way; the progress line counts a block's readings.
- The CSV's float text reads back to the same double with repr's number of digits; the
  output file's background writer raises a failed write (a real /dev/full); a real
  SIGTERM mid-replay leaves no output behind.
"""

from __future__ import annotations

import heapq
import itertools
import math
import os
import re
import signal
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from diffdrive_odom.core.bulk.readings import JointBlock, JointReading
from diffdrive_odom.ros.lifetime import stop_signals
from diffdrive_odom.settings.odometry import odometry_settings
from diffdrive_odom.tools.bags import bagblocks, bagio, bagreadings, bagwriter, bulkmcap, reorder
from diffdrive_odom.tools.cli import main as cli
from diffdrive_odom.tools.cmdline import progress
from diffdrive_odom.tools.replaying import csvout, sinks
from diffdrive_odom.tools.replaying.readings import replay_readings
from diffdrive_odom.wire.jointstate import JointBlockDecoder

from bagutil import OPTIODOM_PARAMS, write_params
from rosutil import DATA

STORE = get_typestore(Stores.ROS2_JAZZY)
JS = "sensor_msgs/msg/JointState"
CASES = settings(derandomize=True, deadline=None, database=None, max_examples=200)


def _message(stamp_ns: int, names: list[str], position: list[float], velocity: list[float],
             frame: str = "") -> Any:
    t = STORE.types
    sec, nsec = divmod(stamp_ns, 10**9)
    return t[JS](header=t["std_msgs/msg/Header"](
        stamp=t["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec), frame_id=frame),
        name=names, position=np.array(position, dtype=np.float64),
        velocity=np.array(velocity, dtype=np.float64), effort=np.zeros(0))


def _scribble(raw: bytes, rng: np.random.Generator) -> bytes:
    """The message with its alignment padding bytes random, as Fast CDR may leave them."""
    buf = bytearray(raw)
    off = 4 + 8
    off += 4 + int.from_bytes(buf[off:off + 4], "little")
    pads = []
    while (off - 4) % 4:
        pads.append(off)
        off += 1
    count = int.from_bytes(buf[off:off + 4], "little")
    off += 4
    for _ in range(count):
        while (off - 4) % 4:
            pads.append(off)
            off += 1
        off += 4 + int.from_bytes(buf[off:off + 4], "little")
    for _ in range(3):
        while (off - 4) % 4:
            pads.append(off)
            off += 1
        count = int.from_bytes(buf[off:off + 4], "little")
        off += 4
        while count and (off - 4) % 8:
            pads.append(off)
            off += 1
        off += 8 * count
    for k in pads:
        buf[k] = int(rng.integers(0, 256))
    return bytes(buf)


KINDS = ("plain", "plain", "plain", "names", "frame", "velocity", "short", "big_endian",
         "cut", "nan")


@CASES
@given(seed=st.integers(0, 2**32 - 1),
       runs=st.lists(st.tuples(st.sampled_from(KINDS), st.integers(1, 40)), min_size=1,
                     max_size=8),
       min_run=st.sampled_from((1, 1, 4, 16)))
def test_block_decoder_gives_what_rosbags_deserialises(
        seed: int, runs: list[tuple[str, int]], min_run: int) -> None:
    rng = np.random.default_rng(seed)
    raws: list[bytes] = []
    for kind, length in runs:
        names = ["left_wheel_joint", "right_wheel_joint"]
        frame = ""
        for _ in range(length):
            stamp = int(rng.integers(-2**31, 2**31)) * 10**9 + int(rng.integers(0, 10**9))
            pos = rng.normal(0, 100, 2).tolist()
            vel: list[float] = []
            if kind == "names":
                names = ["a", "bcd", "efghi"][: 1 + length % 3]
                pos = rng.normal(0, 1, len(names)).tolist()
            elif kind == "frame":
                frame = "base_link" if length % 2 else "odom"
            elif kind == "velocity":
                vel = rng.normal(0, 1, 2).tolist()
            elif kind == "short":
                pos = []
            elif kind == "nan":
                pos[0] = math.nan
            raw = bytes(STORE.serialize_cdr(_message(stamp, names, pos, vel, frame), JS,
                                            little_endian=kind != "big_endian"))
            if kind == "cut":
                raw = raw[: len(raw) - 3]
            raws.append(_scribble(raw, rng) if kind not in ("big_endian", "cut") else raw)
    decoder = JointBlockDecoder()
    start = 0
    while start < len(raws):
        n, arrays = decoder.decode(raws, start, min_run)
        assert 1 <= n <= len(raws) - start
        if arrays is None:  # left to the one-by-one decoder: min_run of them
            assert n == min(min_run, len(raws) - start)
            raw = raws[start]
            if min_run == 1:
                assert raw[:2] != b"\x00\x01" or len(raw) % 4, "a whole LE message has a layout"
        else:
            for k in range(n):
                msg = STORE.deserialize_cdr(raws[start + k], JS)
                assert arrays.stamp_ns[k] == msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
                assert list(arrays.name) == list(msg.name)
                np.testing.assert_array_equal(arrays.position[k], msg.position)
                np.testing.assert_array_equal(arrays.velocity[k], msg.velocity)
        start += n


def test_block_decoder_takes_a_long_clean_run_at_once() -> None:
    raws = [bytes(STORE.serialize_cdr(_message(10**9 + k * 10**7, ["l", "r"], [k, -k], []),
                                      JS)) for k in range(500)]
    n, arrays = JointBlockDecoder().decode(raws)
    assert n == 500 and arrays is not None
    assert arrays.position[499].tolist() == [499.0, -499.0]


@pytest.mark.parametrize("names", [["arm"], ["left_wheel_joinX", "right_wheel_joinX"]],
                         ids=["other length", "same length"])
def test_alternating_layouts_cost_one_check_per_min_run(names: list[str]) -> None:
    """Two drivers on one topic, interleaved (another length, or the same length with
    other names): no block, and one call per 64 messages, not one per message."""
    wheels = ["left_wheel_joint", "right_wheel_joint"]
    raws = [bytes(STORE.serialize_cdr(_message(10**9 + k * 10**7, wheels if k % 2 else names,
                                               [0.1 * k] * 2, []), JS)) for k in range(1000)]
    decoder, start, calls = JointBlockDecoder(), 0, 0
    while start < len(raws):
        n, arrays = decoder.decode(raws, start, min_run=64)
        assert arrays is None
        start += n
        calls += 1
    assert calls == math.ceil(1000 / 64)


def _heap_order(items: list[tuple[int, int]], window: int, jump: int) -> list[int]:
    """The reordering one reading at a time (a heap of ``window``; a jump back flushes)."""
    heap: list[tuple[int, int]] = []
    out: list[int] = []
    newest: int | None = None
    for stamp, ident in items:
        if newest is not None and stamp < newest - jump:
            out.extend(heapq.heappop(heap)[1] for _ in range(len(heap)))
            newest = None
        newest = stamp if newest is None else max(newest, stamp)
        heapq.heappush(heap, (stamp, ident))
        if len(heap) > window:
            out.append(heapq.heappop(heap)[1])
    out.extend(heapq.heappop(heap)[1] for _ in range(len(heap)))
    return out


def _reading(stamp: int, ident: int) -> JointReading:
    return JointReading(stamp, ident, ("l", "r"), (float(ident), 0.0), ())


def _block(part: list[tuple[int, int]]) -> JointBlock:
    return JointBlock(np.array([s for s, _ in part], dtype=np.int64),
                      np.array([i for _, i in part], dtype=np.int64), ("l", "r"),
                      np.array([[float(i), 0.0] for _, i in part]), np.zeros((len(part), 0)))


@CASES
@given(steps=st.lists(st.one_of(st.integers(-30, 30), st.just(-10_000)), min_size=1,
                      max_size=400),
       cuts=st.lists(st.integers(1, 120), min_size=1, max_size=30),
       as_block=st.lists(st.booleans(), min_size=1, max_size=30),
       window=st.sampled_from((1, 4, 16)))
def test_reorder_with_blocks_is_the_heap_one_by_one(
        steps: list[int], cuts: list[int], as_block: list[bool], window: int) -> None:
    stamps = list(itertools.accumulate([100_000, *steps]))
    items = list(zip(stamps, range(len(stamps)), strict=True))
    expected = _heap_order(items, window, jump=1000)
    order = reorder.Reorder(window, 1000)
    got: list[int] = []
    blocks = 0

    def take(out: Any) -> None:
        nonlocal blocks
        for item in out:
            if isinstance(item, JointBlock):
                blocks += 1
                got.extend(item.log_ns.tolist())
            else:
                got.append(item.log_ns)

    at = 0
    for k in itertools.count():
        if at >= len(items):
            break
        part = items[at:at + cuts[k % len(cuts)]]
        at += len(part)
        if as_block[k % len(as_block)]:
            take(order.push_block(_block(part)))
        else:
            for stamp, ident in part:
                take(order.push(_reading(stamp, ident)))
    take(order.flush())
    assert got == expected


def test_sorted_blocks_pass_whole() -> None:
    order = reorder.Reorder(64, 10**9)
    first = _block([(1000 + k, k) for k in range(100)])
    second = _block([(2000 + k, 100 + k) for k in range(100)])
    assert list(order.push_block(first)) == []
    assert list(order.push_block(second)) == [first]
    assert list(order.flush()) == [second]


def _messy_bag(path: Path) -> None:
    """A JointState bag (rosbags' writer) with everything that breaks a run."""
    rng = np.random.default_rng(5)
    writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
    with writer:
        conn = writer.add_connection("/joint_states", JS, typestore=STORE)
        stamp, angle = 10**18, np.zeros(2)
        for k in range(6000):
            stamp += 10_000_000
            angle += rng.uniform(0.0, 0.05, 2)
            names = ["left_wheel_joint", "right_wheel_joint"]
            shown, log = stamp, stamp + 1_000_000
            if 1500 <= k < 1510:
                shown -= 35_000_000  # late by a few readings: reordered
            if k == 3000:
                stamp -= 5 * 10**9  # the driver's clock jumps back: a new run
            if 4000 <= k < 4300:
                names = ["caster", *names]  # another layout for a while
            position = angle.tolist() if len(names) == 2 else [0.0, *angle.tolist()]
            msg = _message(shown, names, position, [], "base" if k % 1000 == 7 else "")
            raw = _scribble(bytes(STORE.serialize_cdr(msg, JS)), rng)
            writer.write(conn, log, raw)


@pytest.fixture(scope="module")
def messy(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("blocks") / "messy"
    _messy_bag(path)
    return path


BAGS = ["messy", DATA / "optiodom" / "square_231220200029_run-01",
        DATA / "turtlebot3_sim" / "turtlebot3.bag"]


def _fields(r: JointReading) -> tuple[Any, ...]:
    """A reading's values (a ROS 1 bag's readings hold numpy arrays)."""
    return (r.stamp_ns, r.log_ns, tuple(r.names), tuple(map(float, r.position)),
            tuple(map(float, r.velocity)))


@pytest.mark.parametrize("bag", BAGS, ids=lambda v: getattr(v, "name", str(v)))
def test_blocks_opened_are_the_readings(bag: Any, messy: Path) -> None:
    path = messy if bag == "messy" else bag
    one = list(bagreadings.read_joint_states(path))
    items = list(bagblocks.read_joint_blocks(path))
    opened = [r for item in items for r in (item if isinstance(item, JointBlock) else [item])]
    assert list(map(_fields, opened)) == list(map(_fields, one))
    in_blocks = sum(len(i) for i in items if isinstance(i, JointBlock))
    if path.suffix == ".bag":  # ROS 1: rosbags decodes it, one by one
        assert in_blocks == 0
    else:  # a clean run nearly all in blocks; each break costs a window one by one
        assert in_blocks > (0.7 if bag == "messy" else 0.9) * len(one), (in_blocks, len(one))


def test_replay_writes_the_same_from_blocks(tmp_path: Path, messy: Path) -> None:
    """Stamps, statuses, poses and /tf the same to the bit; the covariances to the fast
    lane's bound (1e-9 of the largest entry), as stretches start at other readings."""
    cfg = odometry_settings({"wheel_radius": 0.05, "wheel_separation": 0.3})
    tables, bags = [], []
    for name, source in (("one", bagreadings.read_joint_states(messy)),
                         ("blocks", bagblocks.read_joint_blocks(messy))):
        (tmp_path / name).mkdir()
        out = tmp_path / name / "out"
        with bagwriter.BagWriter(out) as w, csvout.CsvWriter(out.with_suffix(".csv")) as t:
            w.add_topic("/odom", bagio.ODOMETRY)
            w.add_topic("/tf", bagio.TF_MESSAGE)
            stats = replay_readings(source, cfg, sinks.OutputSink(cfg, w, t))
        assert stats.reasons["stale_stamp"] > 0 and stats.published > 5000  # the clock's jump
        tables.append([line.split(",") for line in
                       out.with_suffix(".csv").read_text().splitlines()])
        with bagio.open_bag(out) as reader:
            bags.append([(c.topic, t, raw if c.topic == "/tf" else
                          reader.deserialize(raw, c.msgtype))
                         for c, t, raw in reader.messages()])
    assert len(tables[0]) == len(tables[1]) > 5000 and tables[0][0] == tables[1][0]
    for a, b in zip(tables[0][1:], tables[1][1:], strict=True):
        assert a[:8] == b[:8]
        for u, v in zip(a[8:], b[8:], strict=True):
            assert abs(float(u) - float(v)) <= 1e-9 * abs(float(u)), (u, v)
    assert len(bags[0]) == len(bags[1])
    for (topic, t, a), (topic_b, t_b, b) in zip(*bags, strict=True):
        assert (topic, t) == (topic_b, t_b)
        if topic == "/tf":
            assert a == b
            continue
        assert (a.header.stamp.sec, a.header.stamp.nanosec) == (b.header.stamp.sec,
                                                                 b.header.stamp.nanosec)
        qa, qb = a.pose.pose.orientation, b.pose.pose.orientation
        assert (qa.x, qa.y, qa.z, qa.w) == (qb.x, qb.y, qb.z, qb.w)
        for pa, pb in ((a.pose.pose.position, b.pose.pose.position),
                       (a.twist.twist.linear, b.twist.twist.linear),
                       (a.twist.twist.angular, b.twist.twist.angular)):
            assert (pa.x, pa.y, pa.z) == (pb.x, pb.y, pb.z)
        for ca, cb in ((a.pose.covariance, b.pose.covariance),
                       (a.twist.covariance, b.twist.covariance)):
            assert np.all(np.abs(ca - cb) <= 1e-9 * np.abs(ca).max())


def test_progress_counts_the_readings_of_blocks(
        tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    bag = DATA / "optiodom" / "square_231220200029_run-01"
    params = write_params(tmp_path / "p.yaml", OPTIODOM_PARAMS)
    assert cli(["replay", str(bag), "--params-file", str(params), "--progress",
                "--csv", str(tmp_path / "o.csv")]) == 0
    assert "1.39k/1.39k readings (100 %)" in capfd.readouterr().err


def _digits(text: str) -> str:
    """The significant digits of a decimal number's text."""
    mantissa = re.split("[eE]", text)[0].lstrip("-").replace(".", "")
    return mantissa.strip("0")


@CASES
@given(values=st.lists(st.floats(allow_nan=False, allow_infinity=False), min_size=8,
                       max_size=8))
def test_csv_numbers_read_back_exactly_with_the_fewest_digits(values: list[float]) -> None:
    (text,) = csvout.float_texts(np.array([values]))
    cells = text.split(",")
    assert len(cells) == 8
    for cell, value in zip(cells, values, strict=True):
        assert float(cell) == value and math.copysign(1, float(cell)) == math.copysign(1, value)
        assert _digits(cell) == _digits(repr(value)), (cell, repr(value))


def test_csv_non_finite_falls_back_to_repr() -> None:
    assert csvout.float_texts(np.array([[1.5, math.inf, -math.nan]]))[0].split(",")[:2] == [
        "1.5", "inf"]


def test_background_file_raises_a_failed_write() -> None:
    out = bulkmcap.BackgroundFile(open("/dev/full", "wb"))  # noqa: SIM115 - closed by it
    out.write(b"x" * (1 << 20))  # queued: the failure comes back by a later call
    with pytest.raises(OSError, match="No space left"):
        try:
            for _ in range(64):
                out.write(b"y" * (1 << 20))
        finally:
            out.close()
    assert out.tell() >= 1 << 20


@pytest.mark.parametrize("signum", [signal.SIGTERM, pytest.param(
    signal.SIGHUP, marks=pytest.mark.skipif(
        signal.SIGHUP not in stop_signals(), reason="SIGHUP ignored (nohup): not a stop"))])
def test_sigterm_ends_a_replay_as_ctrl_c_with_no_output_left(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capfd: pytest.CaptureFixture[str], signum: int) -> None:
    """A real SIGTERM (or SIGHUP: the terminal closed) to this process mid-replay (sent
    once the first block has gone through): exit 130, the interrupted line, no output
    and no staged file left, and the signal's handler as it was before."""
    bag = DATA / "optiodom" / "square_231220200029_run-01"
    params = write_params(tmp_path / "p.yaml", OPTIODOM_PARAMS)
    wrapped = progress.progress

    def then_terminate(items: Any, *args: Any, **kwargs: Any) -> Any:
        for k, item in enumerate(wrapped(items, *args, **kwargs)):
            if k == 1:
                os.kill(os.getpid(), signum)
            yield item

    monkeypatch.setattr(progress, "progress", then_terminate)
    before = signal.getsignal(signum)
    out = tmp_path / "out"
    assert cli(["replay", str(bag), "--params-file", str(params), "--progress", "-o", str(out),
                "--csv", str(tmp_path / "out.csv")]) == 130
    assert "interrupted; no output written" in capfd.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p.yaml"]
    assert signal.getsignal(signum) is before
