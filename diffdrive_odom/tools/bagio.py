"""Bag input/output for the offline tools (no rclpy): read JointState, write odometry.

Reading goes through rosbags' ``AnyReader``, so rosbag2 (sqlite3 or mcap) and ROS 1
bags look the same; a ROS 2 Jazzy typestore is the default for bags that carry no
message definitions, and ROS 1 messages are converted to ROS 2 CDR where they have to
leave the bag (``--keep-input``, ``play``): same field names, minus ``Header.seq``.

Readings come out in *header stamp* order, because the estimator works on
measurement time and a recorder logs in arrival order; a small heap reorders them
while streaming, so memory stays constant whatever the bag's length.

Output bags are written with rosbags' own message classes (not rclpy's serializer,
which pads some messages in a way strict readers reject), as rosbag2 with mcap
storage by default or sqlite3 on request; ``ros2 bag play`` and independent readers
(mcap-ros2-support) read them.

CSV columns (one row per published odometry, see :data:`CSV_COLUMNS`):

==============  =============================================================
``stamp_ns``    measurement time: the JointState header stamp [ns], an integer
``time``        the same in seconds, written exactly: ``sec.nanosec`` with nine
                decimals (``1600000000.100000001``), never a rounded float
``x``, ``y``    position of the base frame in the odom frame [m]
``yaw``         heading in (-pi, pi] [rad]
``linear``      forward speed along base x [m/s] (rolling mean as the node)
``angular``     yaw rate [rad/s] (rolling mean as the node)
``status``      estimator verdict: reference / updated / time_reset
``var_x``,      diagonal of the published pose covariance: variance of x, y
``var_y``,      [m^2] and yaw [rad^2] (the full 6x6 matrix is in the output bag)
``var_yaw``
==============  =============================================================
"""

from __future__ import annotations

import csv
import functools
import heapq
import itertools
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import IO, Any

import numpy as np
import numpy.typing as npt
from rosbags.convert.converter import is_same_wireformat, migrate_bytes
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.interfaces import Connection
from rosbags.rosbag2 import StoragePlugin
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore

try:  # the CSV's numbers from C (float_texts); repr where it is not installed
    import orjson as _orjson
except ImportError:  # pragma: no cover - an install without the tools extra's orjson
    _orjson = None  # type: ignore[assignment]

from diffdrive_odom.core.bulk.readings import JointBlock
from diffdrive_odom.core.bulk.readings import JointReading as JointReading
from diffdrive_odom.tools import bulkmcap, recovery
from diffdrive_odom.tools.outputs import STORAGES as STORAGES
from diffdrive_odom.wire.cdr import JointBlockDecoder, JointStateDecoder
from diffdrive_odom.wire.conversions import split_ns, stamp_to_ns

JOINT_STATE = "sensor_msgs/msg/JointState"
IMU = "sensor_msgs/msg/Imu"
ODOMETRY = "nav_msgs/msg/Odometry"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
CSV_COLUMNS = ("stamp_ns", "time", "x", "y", "yaw", "linear", "angular", "status",
               "var_x", "var_y", "var_yaw")
# Readings displaced further than this many messages from stamp order still come out,
# in arrival order (the estimator then drops the late one, as the node would).
REORDER_WINDOW = 64


class BagError(RuntimeError):
    """A bag that cannot be used as asked (missing topic, wrong type, bad path)."""


@functools.cache
def typestore() -> Typestore:
    """Return the ROS 2 Jazzy typestore (JointState, Odometry, TFMessage, Clock, ...).

    Shared and never modified: building it (and its serializers) costs ~0.3 s.
    """
    return get_typestore(Stores.ROS2_JAZZY)


# What rosbags raises for a path that is not a bag (or a damaged one).
_NOT_A_BAG = (AnyReaderError, OSError, KeyError, ValueError)


class _Reader(AnyReader):
    """AnyReader whose open() reports a file that is not a bag as one BagError."""

    def open(self) -> None:
        try:
            super().open()
        except _NOT_A_BAG as err:
            raise BagError(f"{self.paths[0]}: not a readable bag ({err})") from err


class _Recovered(_Reader, recovery.RecoveredReader):
    """A recording cut short (no metadata.yaml, torn, malformed): :mod:`.recovery`."""


def open_bag(path: str | Path) -> AnyReader:
    """Return an unopened reader for a rosbag2 dir / ``.mcap`` / ``.db3`` or ROS 1 ``.bag``.

    Use as a context manager. A single rosbag2 storage file is accepted for
    convenience: its directory is opened when it holds the metadata. Anything that is
    not a bag raises :class:`BagError` naming the path, here or on opening.
    """
    p = Path(path)
    if not p.exists():
        raise BagError(f"{p}: no such bag")
    if p.is_file() and p.suffix in (".mcap", ".db3") and (p.parent / "metadata.yaml").exists():
        p = p.parent
    try:
        if recovery.needs_recovery(p):
            return _Recovered(p, default_typestore=typestore())
        return _Reader([p], default_typestore=typestore())
    except _NOT_A_BAG as err:
        raise BagError(f"{p}: not a readable bag ({err})") from err


def connections_for(
    reader: AnyReader, topic: str, msgtypes: Iterable[str] = ()
) -> list[Connection]:
    """Return the connections on ``topic``; BagError naming what exists if none fit."""
    wanted = set(msgtypes)
    found = [c for c in reader.connections if c.topic == topic]
    if not found:
        have = ", ".join(sorted({c.topic for c in reader.connections})) or "none"
        raise BagError(f"topic {topic} is not in the bag (topics: {have})")
    if wanted:
        typed = [c for c in found if c.msgtype in wanted]
        if not typed:
            raise BagError(
                f"topic {topic} has type {found[0].msgtype}, expected one of {sorted(wanted)}"
            )
        found = typed
    return found


@dataclass(frozen=True)
class ImuSample:
    """One Imu message's angular velocity (its own frame) and stamps (``use_imu``)."""

    stamp_ns: int
    log_ns: int
    wx: float
    wy: float
    wz: float


def _reading(msg: Any, log_ns: int) -> JointReading:
    return JointReading(
        stamp_to_ns(msg.header.stamp), log_ns, msg.name, msg.position, msg.velocity
    )


class _JointStates:
    """A bag's JointState bytes -> readings.

    The node's own CDR decoder for rosbag2 data (rosbags' full deserialisation is
    several times slower); rosbags' for ROS 1 bags and whatever that decoder leaves.
    """

    def __init__(self, reader: AnyReader) -> None:
        self._reader = reader
        self._decoder = JointStateDecoder() if reader.is2 else None

    def __call__(self, raw: bytes, msgtype: str, log_ns: int) -> JointReading:
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


def iter_joint_states(
    reader: AnyReader,
    topic: str = "/joint_states",
    passthrough: Passthrough | None = None,
    window: int = REORDER_WINDOW,
    jump_back_ns: int = 1_000_000_000,
) -> Iterator[JointReading]:
    """JointState readings of an open reader, in header stamp order, streaming."""
    for item in iter_sensor_readings(reader, topic, None, passthrough, window, jump_back_ns):
        assert isinstance(item, JointReading)  # no IMU topic asked for
        yield item


def iter_sensor_readings(
    reader: AnyReader,
    topic: str = "/joint_states",
    imu_topic: str | None = None,
    passthrough: Passthrough | None = None,
    window: int = REORDER_WINDOW,
    jump_back_ns: int = 1_000_000_000,
) -> Iterator[JointReading | ImuSample]:
    """JointState readings (and Imu samples of ``imu_topic``) by header stamp, streaming.

    Both go through one reordering by stamp (:class:`_Reorder`), so a wheel reading
    comes after the gyro samples up to its stamp. With ``passthrough``, every message
    of the bag is also handed to it raw, in log time order (``replay --keep-input``).
    """
    joints = connections_for(reader, topic, (JOINT_STATE,))
    imus = [] if imu_topic is None else connections_for(reader, imu_topic, (IMU,))
    conns = reader.connections if passthrough is not None else joints + imus
    joint_ids, imu_ids = {id(c) for c in joints}, {id(c) for c in imus}
    decode = _JointStates(reader)
    order = _Reorder(window, jump_back_ns)
    for conn, log_ns, raw in reader.messages(connections=conns):
        item: JointReading | ImuSample
        if passthrough is not None:
            passthrough(conn, log_ns, raw)
        if id(conn) in joint_ids:
            item = decode(raw, conn.msgtype, log_ns)
        elif id(conn) in imu_ids:
            w = (msg := reader.deserialize(raw, conn.msgtype)).angular_velocity
            item = ImuSample(stamp_to_ns(msg.header.stamp), log_ns, w.x, w.y, w.z)
        else:
            continue
        yield from order.push(item)
    yield from order.flush()


def iter_joint_blocks(
    reader: AnyReader,
    topic: str = "/joint_states",
    window: int = REORDER_WINDOW,
    jump_back_ns: int = 1_000_000_000,
) -> Iterator[JointReading | JointBlock]:
    """:func:`iter_joint_states`, with runs of alike messages as :class:`JointBlock`s.

    The same readings in the same order (opening the blocks gives exactly what
    :func:`iter_joint_states` yields); a run of messages of one byte layout in stamp
    order is decoded at once by :class:`~diffdrive_odom.wire.cdr.JointBlockDecoder`.
    ROS 1 bags, whose bytes that decoder does not read, come one by one.
    """
    if not reader.is2:
        yield from iter_joint_states(reader, topic, None, window, jump_back_ns)
        return
    joints = connections_for(reader, topic, (JOINT_STATE,))
    decode, blocks = _JointStates(reader), JointBlockDecoder()
    order = _Reorder(window, jump_back_ns)
    raws: list[bytes] = []
    logs: list[int] = []
    for _, log_ns, raw in reader.messages(connections=joints):  # all of type JOINT_STATE
        raws.append(raw)
        logs.append(log_ns)
        if len(raws) == GROUP:
            yield from _group(raws, logs, decode, blocks, order)
            raws, logs = [], []
    yield from _group(raws, logs, decode, blocks, order)
    yield from order.flush()


GROUP = 1024  # messages decoded into blocks at a time (memory stays flat)


def _group(raws: list[bytes], logs: list[int], decode: _JointStates,
           blocks: JointBlockDecoder, order: _Reorder) -> Iterator[JointReading | JointBlock]:
    """One group of raw messages into the reordering: blocks where they are alike."""
    i = 0
    while i < len(raws):
        n, arrays = blocks.decode(raws, i, min_run=order.window)
        if arrays is None:  # a run too short for a block (push_block's rule), or no layout
            for k in range(i, i + n):
                yield from order.push(decode(raws[k], JOINT_STATE, logs[k]))
        else:
            yield from order.push_block(JointBlock(
                arrays.stamp_ns, np.array(logs[i:i + n], dtype=np.int64), arrays.name,
                arrays.position, arrays.velocity))
        i += n


class _Reorder:
    """Items in header stamp order: the one rule, for single items and for blocks.

    A heap of ``window`` items: an item displaced further than that from stamp order
    comes out in arrival order (the estimator then drops the late one, as the node
    would). A stamp more than ``jump_back_ns`` behind the newest seen is a new run (a
    looped play, a restarted simulation): everything before it comes out first, so two
    runs are never merged.

    A block (:meth:`push_block`) whose stamps are in order and start at or after every
    stamp seen is held whole instead of going through the heap item by item: the heap
    would have let out everything queued before it, then all of it but its last
    ``window`` items, in this same order. When a single item follows, exactly that
    happens (:meth:`_release`); when another such block follows, the held one goes out.
    """

    def __init__(self, window: int, jump_back_ns: int) -> None:
        self.window, self._jump = window, jump_back_ns
        self._heap: list[tuple[int, int, Any]] = []
        self._order = itertools.count()
        self._newest: int | None = None
        self._held: JointBlock | None = None

    def push(self, item: JointReading | ImuSample) -> Iterator[Any]:
        """Queue one item; whatever the heap lets out."""
        yield from self._release()
        if self._newest is not None and item.stamp_ns < self._newest - self._jump:
            yield from self.flush()
        self._newest = item.stamp_ns if self._newest is None else max(self._newest, item.stamp_ns)
        heapq.heappush(self._heap, (item.stamp_ns, next(self._order), item))
        if len(self._heap) > self.window:
            yield heapq.heappop(self._heap)[2]

    def push_block(self, block: JointBlock) -> Iterator[Any]:
        """Queue a block of readings; whatever comes out (blocks and single readings)."""
        stamps = block.stamp_ns
        if (len(block) < max(self.window, 1) or (np.diff(stamps) < 0).any()
                or (self._newest is not None and int(stamps[0]) < self._newest)):
            for reading in block:
                yield from self.push(reading)
            return
        if self._held is not None:
            yield self._held
        while self._heap:
            yield heapq.heappop(self._heap)[2]
        self._held, self._newest = block, int(stamps[-1])

    def _release(self) -> Iterator[Any]:
        """The held block as the heap would have it: all but its last ``window`` out."""
        held, self._held = self._held, None
        if held is None:
            return
        cut = len(held) - self.window
        if cut > 0:
            yield held[:cut]
        for reading in held[max(cut, 0):]:
            heapq.heappush(self._heap, (reading.stamp_ns, next(self._order), reading))

    def flush(self) -> Iterator[Any]:
        """Everything queued, in order; the next item starts a new run."""
        if self._held is not None:
            yield self._held
            self._held = None
        while self._heap:
            yield heapq.heappop(self._heap)[2]
        self._newest = None


def read_joint_states(
    path: str | Path, topic: str = "/joint_states", jump_back_ns: int = 1_000_000_000
) -> Iterator[JointReading]:
    """Open ``path`` and stream its JointState readings in stamp order."""
    with open_bag(path) as reader:
        yield from iter_joint_states(reader, topic, jump_back_ns=jump_back_ns)


def read_joint_blocks(
    path: str | Path, topic: str = "/joint_states", jump_back_ns: int = 1_000_000_000
) -> Iterator[JointReading | JointBlock]:
    """:func:`read_joint_states`, runs of alike messages as blocks (:func:`iter_joint_blocks`)."""
    with open_bag(path) as reader:
        yield from iter_joint_blocks(reader, topic, jump_back_ns=jump_back_ns)


def count_messages(reader: AnyReader, topic: str) -> int:
    """Messages on ``topic`` according to the bag's index (no decoding)."""
    return sum(c.msgcount for c in reader.connections if c.topic == topic)


# --- ROS 1 -> ROS 2 -------------------------------------------------------------------


class CdrConverter:
    """Raw bytes of any connection of a bag -> ROS 2 CDR with a Jazzy type name.

    rosbag2 data passes through untouched. ROS 1 data is re-encoded; types whose
    fields differ from Jazzy's (only ``Header.seq`` for the common messages) are
    migrated field by field, as ``rosbags-convert`` does. Types Jazzy lacks are
    registered from the bag's own definitions.
    """

    def __init__(self, reader: AnyReader) -> None:
        self._reader = reader
        self.typestore = get_typestore(Stores.ROS2_JAZZY)  # its own: types get added
        self._funcs: dict[str, Callable[[bytes], bytes]] = {}
        self._cache: dict[str, object] = {}

    def __call__(self, conn: Connection, raw: bytes) -> bytes:
        """CDR bytes of one message of ``conn``."""
        func = self._funcs.get(conn.msgtype)
        if func is None:
            func = self._funcs[conn.msgtype] = self._make(conn.msgtype)
        return func(raw)

    def _make(self, msgtype: str) -> Callable[[bytes], bytes]:
        src = self._reader.typestore
        if self._reader.is2:
            if msgtype not in self.typestore.fielddefs:
                self.typestore.register({msgtype: src.fielddefs[msgtype]})
            return bytes
        if msgtype not in self.typestore.fielddefs:
            missing = {
                k: v
                for k, v in src.fielddefs.items()
                if k not in self.typestore.fielddefs and k != "std_msgs/msg/Header"
            }
            self.typestore.register(missing)
        if is_same_wireformat(src, self.typestore, msgtype, msgtype):
            to_cdr = functools.partial(self.typestore.ros1_to_cdr, typename=msgtype)
            return lambda raw: bytes(to_cdr(raw))
        migrate = functools.partial(
            migrate_bytes, src, self.typestore, msgtype, msgtype, self._cache,
            src_is2=False, dst_is2=True,
        )
        return lambda raw: bytes(migrate(raw))


# --- writing ---------------------------------------------------------------------------


class BagWriter:
    """A rosbag2 being written: topics by name, messages as objects or CDR bytes.

    Refuses an existing output path (rosbag2 does too) rather than mixing two runs.
    """

    def __init__(self, path: str | Path, storage: str = "mcap") -> None:
        if storage not in STORAGES:
            raise BagError(f"storage must be one of {STORAGES}, got {storage!r}")
        self.path = Path(path)
        if self.path.exists():
            raise BagError(f"{self.path} exists: remove it or choose another output")
        plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        self._writer = bulkmcap.FastWriter(self.path, version=9, storage_plugin=plugin)
        self.typestore = typestore()
        self._conns: dict[str, tuple[Connection, str]] = {}
        self.count = 0

    def __enter__(self) -> BagWriter:
        self._writer.open()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self._writer.close()

    def add_topic(self, topic: str, msgtype: str, store: Typestore | None = None) -> None:
        """Register ``topic`` once; a second type on the same topic is an error."""
        known = self._conns.get(topic)
        if known is not None:
            if known[1] != msgtype:
                raise BagError(f"topic {topic} would carry both {known[1]} and {msgtype}")
            return
        conn = self._writer.add_connection(topic, msgtype, typestore=store or self.typestore)
        self._conns[topic] = (conn, msgtype)

    def has_topic(self, topic: str) -> bool:
        """Tell whether ``topic`` is registered."""
        return topic in self._conns

    def write(self, topic: str, log_ns: int, msg: Any) -> None:
        """Serialize a rosbags message object (Jazzy types) onto ``topic``."""
        conn, msgtype = self._conns[topic]
        self._writer.write(conn, log_ns, self.typestore.serialize_cdr(msg, msgtype))
        self.count += 1

    def write_cdr(self, topic: str, log_ns: int, data: bytes) -> None:
        """Write already-serialized CDR bytes onto ``topic``."""
        self._writer.write(self._conns[topic][0], log_ns, data)
        self.count += 1

    def write_rows(self, topics: Sequence[str], log_ns: npt.NDArray[np.int64],
                   payloads: Sequence[npt.NDArray[np.uint8]]) -> None:
        """Per row ``k``: ``payloads[j][k]`` (CDR bytes) onto ``topics[j]`` at ``log_ns[k]``.

        The same bag as :meth:`write_cdr` once per message, in that order; MCAP in bulk
        (:mod:`diffdrive_odom.tools.bulkmcap`), sqlite3 one by one.
        """
        conns = [self._conns[t][0] for t in topics]
        if bulkmcap.supported(self._writer):
            bulkmcap.write_rows(self._writer, conns, log_ns, payloads)
        else:
            for k, stamp in enumerate(log_ns.tolist()):
                for conn, data in zip(conns, payloads, strict=True):
                    self._writer.write(conn, stamp, data[k].tobytes())
        self.count += len(log_ns) * len(topics)


class CsvWriter:
    """Odometry rows with the documented :data:`CSV_COLUMNS` (full float precision)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._file: IO[str] | None = None
        self._csv: Any = None

    def __enter__(self) -> CsvWriter:
        self._file = open(self.path, "w", newline="", encoding="utf-8")
        self._csv = csv.writer(self._file)
        self._csv.writerow(CSV_COLUMNS)
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if self._file is not None:
            self._file.close()

    def row(
        self, ns: int, x: float, y: float, yaw: float, *, linear: float, angular: float,
        status: str, pose_covariance: Sequence[float] = (),
    ) -> None:
        """One published pose; floats as :func:`float_texts` writes them (lossless).

        The stamp is an integer, so it is written as integers too: a float in seconds
        has only ~0.2 us resolution at today's epoch (``1600000000.1000001``).
        ``pose_covariance`` is the message's 6x6 row-major matrix; its x, y and yaw
        variances fill the last three columns (left empty without one).
        """
        (motion,) = float_texts(np.array([[x, y, yaw, linear, angular]], dtype=np.float64))
        variances = (float_texts(np.array([[pose_covariance[i] for i in (0, 7, 35)]],
                                          dtype=np.float64))[0].split(",")
                     if pose_covariance else ["", "", ""])
        self._csv.writerow((ns, seconds_text(ns), *motion.split(","), status, *variances))

    def rows(self, ns: Sequence[int], columns: npt.NDArray[np.float64], status: str) -> None:
        """Many rows at once, the text :meth:`row` writes.

        ``columns`` (n, 8) holds x, y, yaw, linear, angular and the x, y, yaw
        variances; ``status`` is a plain word (csv quotes nothing of such a row).
        """
        assert self._file is not None
        if not len(ns):
            return
        assert status.isidentifier(), status
        motion, variances = float_texts(columns[:, :5]), float_texts(columns[:, 5:])
        lines = (f"{n},{n // 1_000_000_000}.{n % 1_000_000_000:09d},{m},{status},{v}\r\n"
                 for n, m, v in zip(ns, motion, variances, strict=True))
        self._file.write("".join(lines))


def float_texts(values: npt.NDArray[np.float64]) -> list[str]:
    """Each row of a 2-D array as its numbers' shortest round-trip texts, comma-separated.

    Why: Python's ``repr`` costs about 0.5 us a number, more than the odometry of a
    reading; orjson (where installed) writes the same shortest digits from C, as
    ``0.00001`` and ``-2.5e-7`` where ``repr`` writes ``1e-05`` and ``-2.5e-07``.
    Either reads back to the very same double. A non-finite number (which publication
    never lets out) falls back to ``repr`` for the whole array.
    """
    if _orjson is not None and bool(np.isfinite(values).all()):
        text: str = _orjson.dumps(np.ascontiguousarray(values, dtype=np.float64),
                                  option=_orjson.OPT_SERIALIZE_NUMPY).decode()
        return text[2:-2].split("],[")
    return [",".join(map(repr, row)) for row in values.tolist()]


def seconds_text(ns: int) -> str:
    """Exact decimal seconds of an integer nanosecond stamp: ``sec.nanosec`` (9 places)."""
    sec, nanosec = split_ns(ns)
    return f"{sec}.{nanosec:09d}"
