"""Ctrl-C, SIGTERM and SIGHUP for the demo: a KeyboardInterrupt, raised only where it is safe.

Python raises KeyboardInterrupt wherever the main thread is when SIGINT arrives. Inside
rclpy's deserialization (a C extension, run by the executor for every recorded message)
pybind turns it into a TypeError with a traceback, and the demo would fail instead of
stopping cleanly. Inside ``subprocess.Popen.poll`` (the loop checks its children between
spins) it can land between taking the Popen's waitpid lock and the ``try`` that releases
it: the lock stays held, and stopping that child later waits for it forever (the demo did
not end within 30 s of Ctrl-C under load). So while the children run (:func:`deferred`
around the loop) a signal only marks itself pending and is raised as KeyboardInterrupt
at the loop's safe point (:func:`check`) or when the outermost deferral is left; anywhere
else it is raised at once.
"""

from __future__ import annotations

import signal
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType
from typing import Any

from diffdrive_odom.ros.lifetime import stop_signals

_state = {"deferring": False, "pending": False}


def _on_signal(signum: int, frame: FrameType | None) -> None:
    if _state["deferring"]:
        _state["pending"] = True
        return
    raise KeyboardInterrupt


@contextmanager
def handled() -> Iterator[None]:
    """The stop signals raise KeyboardInterrupt (deferred inside :func:`deferred`) while inside."""
    previous: dict[int, Any] = {s: signal.signal(s, _on_signal) for s in stop_signals()}
    _state["pending"] = False
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


@contextmanager
def deferred() -> Iterator[None]:
    """Hold a signal that arrives inside until :func:`check` or until the block is left."""
    outer = _state["deferring"]
    _state["deferring"] = True
    try:
        yield
    finally:
        _state["deferring"] = outer
        if not outer:
            check()


def check() -> None:
    """Raise the KeyboardInterrupt of a signal held by :func:`deferred`, if one came."""
    if _state["pending"]:
        _state["pending"] = False
        raise KeyboardInterrupt
