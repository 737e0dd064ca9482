"""When a process of the package stops: a stop signal, or the end of the process that started it.

The stop signals (:func:`stop_signals`) are SIGINT (Ctrl-C), SIGTERM and SIGHUP (the
terminal or ssh session closed), except SIGHUP where it is ignored from the start:
``nohup`` asked the process to outlive its terminal.

A parent ended by SIGKILL, or by a signal it does not handle, runs no cleanup: its
children are handed to init and keep running (the demo's four nodes went on publishing
in their domain at about one core). So a parent names itself in the child's
environment (:func:`child_env`) or a pool's initializer names it, and the child watches
that process from a daemon thread (:func:`watch`): once it has ended, the child stops
itself the way a stop signal would, and ends outright if that stop has not finished
after a grace period.

Watched through a pid file descriptor (``pidfd_open``, Linux 5.3), which becomes
readable when the process ends, whichever of its threads started the child, with
nothing polled. ``prctl(PR_SET_PDEATHSIG)`` fires when the *thread* that forked the
child ends (a pool's worker thread, a launch service run in a thread) and only sends a
signal. A parent that ended before the child looked is seen too: its pid is gone, or is
no longer among the child's ancestors (the child was handed to init or a subreaper).
Elsewhere (no pidfd) the pid is polled every :data:`POLL_S`.
"""

from __future__ import annotations

import os
import select
import signal
import threading
import time
from collections.abc import Callable, Mapping

PARENT_ENV = "DIFFDRIVE_ODOM_PARENT_PID"
POLL_S = 0.5  # only without pidfd_open
EXIT_ORPHANED = 1  # the exit status when the stop did not finish within the grace period


def stop_signals() -> tuple[signal.Signals, ...]:
    """The signals this process takes as a request to stop (see the module's docstring)."""
    ignored = signal.getsignal(signal.SIGHUP) == signal.SIG_IGN
    return (signal.SIGINT, signal.SIGTERM) + (() if ignored else (signal.SIGHUP,))


def child_env(env: Mapping[str, str]) -> dict[str, str]:
    """``env`` for a child that must end with this process (it calls :func:`watch`)."""
    return {**env, PARENT_ENV: str(os.getpid())}


def named_parent() -> int | None:
    """The pid :data:`PARENT_ENV` names (taken out of the environment), or None.

    Taken out so that what the child starts in turn does not watch this parent too.
    ValueError (saying so) when it is not a process id.
    """
    text = os.environ.pop(PARENT_ENV, None)
    if text is None or not text.strip():
        return None
    try:
        pid = int(text)
    except ValueError:
        pid = 0
    if pid <= 0:
        raise ValueError(f"{PARENT_ENV}={text!r} is not a process id")
    return pid


def watch(pid: int, on_end: Callable[[], None], grace: float) -> threading.Thread:
    """Call ``on_end`` (from a daemon thread) once process ``pid`` has ended.

    At once if ``pid`` has ended already; ``os._exit`` if this process still runs
    ``grace`` seconds after the call.
    """
    def run() -> None:
        _wait_for_end(pid)
        try:
            on_end()
        finally:  # whatever on_end met (its output's reader was the parent: EPIPE)
            time.sleep(grace)
            os._exit(EXIT_ORPHANED)

    thread = threading.Thread(target=run, name=f"watch parent {pid}", daemon=True)
    thread.start()
    return thread


def _wait_for_end(pid: int) -> None:
    """Return once ``pid`` has ended (at once if it has or if it is not an ancestor)."""
    try:
        fd = os.pidfd_open(pid)
    except ProcessLookupError:
        return
    except (AttributeError, OSError):  # no pidfd here (an old kernel, not Linux)
        while is_ancestor(pid) and pid_exists(pid):
            time.sleep(POLL_S)
        return
    try:
        # Checked after the open: an ancestor now is the process the descriptor holds
        # (a pid taken over by a new process after the open cannot be an ancestor).
        if is_ancestor(pid):
            poller = select.poll()
            poller.register(fd, select.POLLIN)
            while not poller.poll():
                pass
    finally:
        os.close(fd)


def pid_exists(pid: int) -> bool:
    """Whether process ``pid`` exists (someone else's counts)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def is_ancestor(pid: int) -> bool:
    """Whether ``pid`` is this process's parent or one of its ancestors.

    Ancestors too: a node started through a wrapper (``ros2 launch``'s launch-prefix:
    gdb, valgrind) has launch as its grandparent. Without /proc only the parent counts.
    """
    p = os.getppid()
    seen = 0
    while p > 1 and seen < 64:
        if p == pid:
            return True
        p = _parent_of(p)
        seen += 1
    return False


def _parent_of(pid: int) -> int:
    """The parent pid of ``pid`` from /proc (0 if unknown)."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            # "pid (comm) state ppid ...": comm may hold spaces and parentheses.
            return int(f.read().rsplit(b")", 1)[1].split()[1])
    except (OSError, IndexError, ValueError):
        return 0
