"""A /diagnostics listener for the DDS tests: the node under test runs as its own process.

A peer node subscribes ``/diagnostics`` as diagnostic_aggregator does and keeps every
status with its array's stamp and the time it arrived.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from rosutil import node_process, ros_test_node, spin_until


@dataclass
class Status:
    """One received status, its array's stamp [s] and the receipt time (monotonic)."""

    level: int
    name: str
    hardware_id: str
    message: str
    values: dict[str, str]
    stamp_s: float
    received: float


@dataclass
class Peer:
    node: Node
    executor: SingleThreadedExecutor
    statuses: list[Status] = field(default_factory=list)
    arrays: list[int] = field(default_factory=list)  # status count of each array
    cursor: int = 0  # statuses before this one were looked at by wait_for

    def wait_for(self, check: Callable[[Status], bool], timeout: float = 15.0) -> Status:
        """The first status from now on (not seen by an earlier wait) that passes ``check``."""
        found: list[Status] = []

        def seen() -> bool:
            while not found and self.cursor < len(self.statuses):
                s = self.statuses[self.cursor]
                self.cursor += 1
                if check(s):
                    found.append(s)
            return bool(found)

        assert spin_until(self.executor, seen, timeout), "no such status arrived"
        return found[0]


@contextmanager
def diagnosed(executable: str, args: list[str]) -> Iterator[Peer]:
    """Run ``executable`` with ``--ros-args args`` and listen to /diagnostics."""
    with node_process(executable, ["--ros-args", *args]) as proc, \
            ros_test_node() as (node, executor):
        peer = Peer(node, executor)

        def on_array(msg: Any) -> None:
            peer.arrays.append(len(msg.status))
            stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
            for s in msg.status:
                peer.statuses.append(Status(
                    s.level[0], s.name, s.hardware_id, s.message,
                    {kv.key: kv.value for kv in s.values}, stamp, time.monotonic()))

        node.create_subscription(DiagnosticArray, "/diagnostics", on_array, 10)
        yield peer
        assert proc.poll() is None, f"{executable} died"


def assert_finite(s: Status) -> None:
    """Every value is a finite number or a word ("never", "commanding", ...)."""
    for key, value in s.values.items():
        assert "nan" not in value.lower() and "inf" not in value.lower(), (key, value)
        try:
            number = float(value)
        except ValueError:
            continue
        assert math.isfinite(number), (key, value)
