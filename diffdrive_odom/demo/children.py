"""The demo's nodes as child processes, each logging to a file, all stopped on leaving.

Each is told this process's pid (:func:`diffdrive_odom.ros.lifetime.child_env`) and
stops by itself once this process has ended, however it ended: SIGKILL runs no
``__exit__``, and the nodes used to keep running under init.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType

from diffdrive_odom.ros import lifetime
from diffdrive_odom.tools.cmdline import process

from .settings import DemoError


@dataclass
class Child:
    """A node started as its own process, its output going to a log file."""

    name: str
    proc: subprocess.Popen[bytes]
    log: Path

    def tail(self, lines: int = 12) -> str:
        """Last lines of its output (for error messages)."""
        try:
            text = self.log.read_text(encoding="utf-8", errors="replace")
        except OSError:
            return ""
        return "\n".join(f"  [{self.name}] {line}" for line in text.splitlines()[-lines:])


def _executable(name: str) -> str:
    path = Path(sys.executable).parent / name
    found = str(path) if path.exists() else shutil.which(name)
    if found is None:
        raise DemoError(f"{name} not found next to {sys.executable} or on PATH (make venv)")
    return found


class Children:
    """The nodes as child processes; leaving the ``with`` block stops every one started.

    SIGINT first (the nodes exit cleanly on it), then SIGKILL whatever is left after
    ``grace`` seconds (:func:`diffdrive_odom.tools.cmdline.process.stop_all`).
    """

    def __init__(self, env: Mapping[str, str], logs: Path, grace: float = 5.0) -> None:
        self.env, self.logs, self.grace = lifetime.child_env(env), logs, grace
        self.started: list[Child] = []

    def start(self, name: str, args: Sequence[str]) -> Child:
        """Start a console script with ``--ros-args``."""
        exe = _executable(name)
        log = self.logs / f"{name}.log"
        with open(log, "wb") as out:
            proc = subprocess.Popen([exe, "--ros-args", *args], stdout=out,
                                    stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                    env=self.env)
        child = Child(name, proc, log)
        self.started.append(child)
        return child

    def check(self, what: str) -> None:
        """Raise DemoError if a child has exited."""
        for c in self.started:
            if c.proc.poll() is not None:
                raise DemoError(f"{c.name} exited with {c.proc.returncode} while {what}:\n"
                                f"{c.tail()}")

    def tails(self, lines: int = 5) -> str:
        """Each child's last log lines."""
        return "\n".join(c.tail(lines) for c in self.started)

    def __enter__(self) -> Children:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        process.stop_all((c.proc for c in self.started), self.grace)
