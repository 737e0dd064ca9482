"""Stopping child processes the one way (SIGINT, wait, then SIGKILL); pure stdlib, no rclpy.

The nodes exit cleanly on SIGINT (as on Ctrl-C), so that comes first; whatever is still
running after the grace period is killed, and every process is reaped. The demo, the
tests and the benches all stop their children with this.
"""

from __future__ import annotations

import signal
import subprocess
import time
from collections.abc import Iterable
from typing import Any


def stop_all(procs: Iterable[subprocess.Popen[Any]], timeout: float) -> None:
    """SIGINT every running process, give them ``timeout`` seconds in all, kill the rest.

    The grace period is shared (every process got its signal at once), so stopping
    many children takes no longer than stopping one.
    """
    procs = list(procs)
    for proc in procs:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
    deadline = time.monotonic() + timeout
    for proc in procs:
        try:
            proc.wait(timeout=max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def stop(proc: subprocess.Popen[Any], timeout: float) -> None:
    """SIGINT ``proc`` if it runs, wait up to ``timeout`` seconds, then SIGKILL it."""
    stop_all((proc,), timeout)
