"""Ctrl-C and SIGTERM for the demo: a KeyboardInterrupt, but never inside rclpy's C code.

Python raises KeyboardInterrupt wherever the main thread is when SIGINT arrives. Inside
rclpy's deserialization (a C extension, run by the executor for every recorded message)
pybind turns it into a TypeError with a traceback, and the demo would fail instead of
stopping cleanly. So while the recorder spins, a signal only marks itself pending and is
raised as KeyboardInterrupt when the spin returns; anywhere else it is raised at once.
"""

from __future__ import annotations

import signal
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType
from typing import Any

_state = {"deferring": False, "pending": False}


def _on_signal(signum: int, frame: FrameType | None) -> None:
    if _state["deferring"]:
        _state["pending"] = True
        return
    raise KeyboardInterrupt


@contextmanager
def handled() -> Iterator[None]:
    """SIGINT and SIGTERM raise KeyboardInterrupt (deferred out of spins) while inside."""
    previous: dict[int, Any] = {
        s: signal.signal(s, _on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    _state["pending"] = False
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


@contextmanager
def deferred() -> Iterator[None]:
    """Hold a signal that arrives inside (an executor's spin) until the block is left."""
    outer = _state["deferring"]
    _state["deferring"] = True
    try:
        yield
    finally:
        _state["deferring"] = outer
        if not outer and _state["pending"]:
            _state["pending"] = False
            raise KeyboardInterrupt
