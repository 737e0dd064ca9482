"""Helpers for tests that talk to the nodes over real DDS (no mocks).

A test owns a private rclpy Context and an executor; the node under test runs as a
separate process started from the venv's console script, exactly as a user runs it.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import rclpy
from rcl_interfaces.srv import ListParameters
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from diffdrive_odom.tools import process

BIN = Path(sys.executable).parent
ROOT = Path(__file__).resolve().parent.parent
DATA = Path(__file__).resolve().parent / "data"


def executable(name: str) -> str:
    """Path of a console script installed in this venv."""
    path = BIN / name
    if not path.exists():
        raise FileNotFoundError(f"{path} missing: run `make venv` (pip install -e .)")
    return str(path)


@contextmanager
def node_process(
    name: str, args: Sequence[str] = (), env: dict[str, str] | None = None
) -> Iterator[subprocess.Popen[str]]:
    """Run a console script as its own process; stop it with SIGINT at the end."""
    proc = subprocess.Popen(
        [executable(name), *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env={**os.environ, **(env or {})},
    )
    try:
        yield proc
    finally:
        process.stop(proc, timeout=10)


@contextmanager
def ros_test_node(name: str = "test_peer") -> Iterator[tuple[Node, SingleThreadedExecutor]]:
    """A node in a private Context, with its executor; both torn down afterwards."""
    context = Context()
    rclpy.init(context=context)
    node = Node(name, context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    try:
        yield node, executor
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)


def spin_until(
    executor: SingleThreadedExecutor, condition: Callable[[], Any], timeout: float = 10.0
) -> bool:
    """Spin until ``condition()`` is truthy or ``timeout`` seconds pass."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        executor.spin_once(timeout_sec=0.05)
    return bool(condition())


def spin_for(executor: SingleThreadedExecutor, seconds: float) -> None:
    """Spin for a fixed time."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.02)


def call_service(node: Node, executor: SingleThreadedExecutor, srv_type: Any, name: str,
                 request: Any, timeout: float = 20.0) -> Any:
    """The answer to ``request`` on service ``name``, asked again until one comes.

    DDS can report a service before its reply path is matched, and a request sent
    then is never answered; so only for calls without side effects.
    """
    client = node.create_client(srv_type, name)
    try:
        assert spin_until(executor, client.service_is_ready, timeout), f"{name} never came up"
        deadline = time.monotonic() + timeout
        while True:
            future = client.call_async(request)
            if spin_until(executor, future.done, 2.0) or time.monotonic() > deadline:
                break
        assert future.done(), f"{name} never answered"
        return future.result()
    finally:
        node.destroy_client(client)


def handshake(node: Node, executor: SingleThreadedExecutor, target: str,
              timeout: float = 20.0) -> None:
    """Return once the node ``target`` has matched every endpoint ``node`` made so far.

    Discovery is asymmetric: our subscription can see a publisher of ``target`` while
    that publisher does not yet see us, and what it sends meanwhile is lost to us (a
    first odom lost so, its reading's repeats are dropped as repeats: the test
    waits forever). ``target`` answering a service client made after our other
    endpoints proves it has matched them too: each side announces its readers, and
    its writers, in order on one reliable discovery stream, and the client's reply
    reader and request writer come last on theirs.
    """
    call_service(node, executor, ListParameters, f"{target}/list_parameters",
                 ListParameters.Request(depth=1), timeout)


def publisher_node(node: Node, executor: SingleThreadedExecutor, topic: str,
                   timeout: float = 20.0) -> str:
    """The fully qualified name of the (first) node publishing ``topic``.

    The graph can list an endpoint before the name of its node has arrived (rmw
    sends names on their own topic): wait for the name.
    """
    names: list[str] = []

    def known() -> bool:
        names[:] = [f"{i.node_namespace.rstrip('/')}/{i.node_name}"
                    for i in node.get_publishers_info_by_topic(topic)
                    if "_UNKNOWN_" not in i.node_name + i.node_namespace]
        return bool(names)

    assert spin_until(executor, known, timeout), f"no named publisher of {topic}"
    return names[0]


def wait_matched(node: Node, executor: SingleThreadedExecutor, pub: Any, sub: Any,
                 timeout: float = 20.0) -> bool:
    """Wait until a node matches ``pub`` and publishes ``sub``'s topic, both ways.

    Both our views first (cheap), then :func:`handshake` with that node for its own.
    """
    if not (spin_until(executor, lambda: pub.get_subscription_count() > 0, timeout)
            and spin_until(executor, lambda: sub.get_publisher_count() > 0, timeout)):
        return False
    handshake(node, executor, publisher_node(node, executor, sub.topic_name, timeout),
              timeout)
    return True


def wait_for_subscriber(
    executor: SingleThreadedExecutor, publisher: Any, timeout: float = 15.0
) -> bool:
    """Wait until DDS discovery has matched ``publisher`` with a subscriber."""
    return spin_until(executor, lambda: publisher.get_subscription_count() > 0, timeout)


def assert_refuses_to_start(executable_name: str, cases: dict[str, list[str]]) -> None:
    """Each case (parameter name -> ``-p`` arguments) must stop the node at start with
    a non-zero exit and exactly one output line naming that parameter."""
    for name, params in cases.items():
        with node_process(executable_name, ["--ros-args", *params]) as proc:
            code = proc.wait(timeout=20)
            out = proc.stdout.read() if proc.stdout else ""
        assert code != 0, f"{name}: node started with a bad value"
        lines = [ln for ln in out.splitlines() if ln.strip()]
        assert len(lines) == 1 and f"'{name}'" in lines[0], out
