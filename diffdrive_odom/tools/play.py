"""``diffdrive-odom play``: publish a bag's messages over DDS with their timing and /clock.

The fallback for machines without rosbag2 (pip-only installs, CI); on a robot
``ros2 bag play --clock`` is the tool. Messages go out as the recorded CDR bytes
(``publisher.publish(bytes)``: no decode/encode, so what the node receives is
byte for byte what was recorded); ROS 1 bags are converted to ROS 2 CDR first.
Messages are released at their recorded log time, scaled by ``--rate``; ``--clock``
publishes ``/clock`` with the bag time so nodes with ``use_sim_time`` follow the bag.
With ``--loop`` the bag starts over and time jumps back, as with ``ros2 bag play
--loop``: the odometry node restarts at the origin (and says so).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from diffdrive_odom.ros.messages import message_class
from diffdrive_odom.tools.cli import command_parser
from diffdrive_odom.wire.conversions import split_ns

if TYPE_CHECKING:  # the bag library only past the parsing (``tools`` extra)
    from rosbags.interfaces import Connection

    from diffdrive_odom.tools.bags import cdrconvert

CLOCK_QOS_DEPTH = 1


def _message_class(msgtype: str) -> Any:
    """Return the rclpy message class for ``pkg/msg/Type`` (None if not installed here)."""
    try:
        return message_class(msgtype)
    except (ImportError, AttributeError):
        return None


def _parser() -> argparse.ArgumentParser:
    ap = command_parser("play", "Publish a bag's messages with their recorded timing (and "
                        "/clock). The fallback where `ros2 bag play` is not installed.")
    ap.add_argument("bag", help="rosbag2 directory (mcap/sqlite3) or ROS 1 .bag")
    ap.add_argument("-r", "--rate", type=float, default=1.0, help="speed factor (> 0)")
    ap.add_argument("-l", "--loop", action="store_true",
                    help="start over at the end (default: play once)")
    ap.add_argument("--topics", nargs="+", default=None, metavar="TOPIC",
                    help="only these topics (default: every topic of the bag)")
    ap.add_argument("--clock", nargs="?", type=float, const=100.0, default=None,
                    metavar="HZ", help="publish /clock at HZ wall-clock rate (default: no /clock; "
                    "HZ defaults to 100)")
    ap.add_argument("--start-offset", type=float, default=0.0, metavar="S",
                    help="skip this many seconds of the bag")
    ap.add_argument("--duration", type=float, default=None, metavar="S",
                    help="play only this many seconds of the bag after the offset "
                    "(default: to the end)")
    ap.add_argument("--delay", type=float, default=0.0, metavar="S",
                    help="wait this long before playing")
    ap.add_argument("--wait-for", nargs="+", default=(), metavar="TOPIC",
                    help="before playing, wait until these topics have a subscriber "
                    "(default: start at once)")
    ap.add_argument("--remap", nargs="+", default=(), metavar="FROM:=TO",
                    help="publish topic FROM as TO (default: recorded names)")
    return ap


def main(argv: Sequence[str]) -> int:
    """``diffdrive-odom play``; Ctrl-C stops it and exits 0."""
    args = _parser().parse_args(list(argv))
    if not args.rate > 0.0 or (args.clock is not None and not args.clock > 0.0):
        print("[play] --rate and --clock must be > 0", file=sys.stderr)
        return 2
    remap: dict[str, str] = {}
    for item in args.remap:
        src, sep, dst = item.partition(":=")
        if not sep or not src or not dst:
            print(f"[play] --remap expects FROM:=TO, got {item!r}", file=sys.stderr)
            return 2
        remap[src] = dst
    from diffdrive_odom.tools.bags import bagio

    try:
        reader = bagio.open_bag(args.bag)
        reader.open()
    except bagio.BagError as err:  # open_bag turns rosbags' own errors into this one
        print(f"[play] {err}", file=sys.stderr)
        return 2
    try:
        return _play(reader, args, remap)
    finally:
        reader.close()


def _play(reader: Any, args: argparse.Namespace, remap: dict[str, str]) -> int:
    import rclpy
    from rclpy.duration import Duration
    from rclpy.executors import ExternalShutdownException
    from rosgraph_msgs.msg import Clock

    from diffdrive_odom.ros import qos as ros_qos
    from diffdrive_odom.ros.runtime import shutdown_after_stop
    from diffdrive_odom.tools.bags import bagio, cdrconvert

    conns: list[Connection] = [
        c for c in reader.connections if args.topics is None or c.topic in args.topics
    ]
    if args.topics is not None:
        missing = sorted(set(args.topics) - {c.topic for c in conns})
        if missing:
            print(f"[play] not in the bag: {', '.join(missing)}", file=sys.stderr)
            return 2
    rclpy.init(args=["--ros-args"])
    node = rclpy.create_node("diffdrive_odom_player")
    log = node.get_logger()
    convert = cdrconvert.CdrConverter(reader)
    topics: dict[int, Any] = {}  # the publishers, by connection and by name
    by_name: dict[str, Any] = {}
    try:
        for conn in conns:
            cls = _message_class(conn.msgtype)
            if cls is None:
                log.warning(f"{conn.topic}: type {conn.msgtype} not installed here, skipped")
                continue
            name = remap.get(conn.topic, conn.topic)
            if name not in by_name:
                qos = ros_qos.qos(100, reliable=True, latched=name == "/tf_static")
                by_name[name] = node.create_publisher(cls, name, qos)
            topics[id(conn)] = by_name[name]
        if not topics:
            print("[play] nothing to play", file=sys.stderr)
            return 2
        clock_pub = (
            node.create_publisher(Clock, "/clock", CLOCK_QOS_DEPTH)
            if args.clock is not None else None
        )
        _wait_for_subscribers(node, by_name, args.wait_for)
        if args.delay > 0:
            time.sleep(args.delay)
        start_ns = reader.start_time + int(args.start_offset * 1e9)
        stop_ns = (start_ns + int(args.duration * 1e9) if args.duration is not None
                   else reader.end_time + 1)
        log.info(f"playing {args.bag}: {len(by_name)} topics, rate {args.rate:g}"
                 + (", looping" if args.loop else "") + (", /clock" if clock_pub else ""))
        sent = 0
        while True:
            sent += _play_once(reader, conns=conns, topics=topics, convert=convert,
                               clock_pub=clock_pub, clock_cls=Clock, start_ns=start_ns,
                               stop_ns=stop_ns, args=args)
            if not args.loop or not rclpy.ok():
                break
        tail = [*by_name.values()] + ([clock_pub] if clock_pub else [])
        for pub in tail:  # let reliable readers get the last messages before exiting
            pub.wait_for_all_acked(Duration(seconds=1.0))
        log.info(f"done: {sent} messages")
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except bagio.BagError as err:  # damaged part way: what was played went out
        print(f"[play] {err}", file=sys.stderr)
        return 2
    except Exception:
        # A stop signal's handler shuts the context down under a publish or a wait for
        # acks (rclpy then raises from them): that is the stop, not a failure of play's.
        if rclpy.ok():
            raise
    finally:
        node.destroy_node()
        shutdown_after_stop()  # Ctrl-C: rclpy's handler may be shutting down as well
    return 0


def _wait_for_subscribers(node: Any, by_name: dict[str, Any], wanted: Sequence[str]) -> None:
    """Block until each wanted topic's publisher is matched (so no reading is lost)."""
    for name in wanted:
        publisher = by_name.get(name)
        if publisher is None:
            node.get_logger().warning(f"--wait-for {name}: not a played topic")
            continue
        deadline = time.monotonic() + 60.0
        while publisher.get_subscription_count() == 0:
            if time.monotonic() > deadline:
                node.get_logger().warning(f"--wait-for {name}: no subscriber after 60 s")
                break
            time.sleep(0.02)


def _play_once(
    reader: Any,
    *,
    conns: list[Connection],
    topics: dict[int, Any],
    convert: cdrconvert.CdrConverter,
    clock_pub: Any,
    clock_cls: Any,
    start_ns: int,
    stop_ns: int,
    args: argparse.Namespace,
) -> int:
    """One pass over the bag, paced by wall time; returns messages sent."""
    rate = float(args.rate)
    clock_period = 1.0 / args.clock if args.clock else 0.0
    wall0 = time.monotonic()
    next_clock = wall0
    sent = 0

    end_ns = min(stop_ns, reader.end_time - 1)  # rosbags' end_time is exclusive
    last_ns = start_ns

    def bag_now() -> int:
        return start_ns + int((time.monotonic() - wall0) * rate * 1e9)

    def publish_clock(ns: int) -> None:
        msg = clock_cls()
        msg.clock.sec, msg.clock.nanosec = split_ns(min(max(ns, start_ns), end_ns))
        clock_pub.publish(msg)

    if clock_pub is not None:
        publish_clock(start_ns)
    for conn, log_ns, raw in reader.messages(connections=conns, start=start_ns, stop=stop_ns):
        publisher = topics.get(id(conn))
        if publisher is None:
            continue
        due = wall0 + (log_ns - start_ns) * 1e-9 / rate
        while True:
            now = time.monotonic()
            if clock_pub is not None and now >= next_clock:
                publish_clock(bag_now())
                next_clock += clock_period * max(1, int((now - next_clock) / clock_period) + 1)
            if now >= due:
                break
            wake = due if clock_pub is None else min(due, next_clock)
            time.sleep(max(0.0, wake - now))
        publisher.publish(convert(conn, bytes(raw)))
        last_ns = log_ns
        sent += 1
    if clock_pub is not None:  # the pass ends at its last message's time
        publish_clock(last_ns)
    return sent


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
