"""Lines a command says once, however often the thing they report is met again.

``replay --eval`` opens its bag three times (the ground-truth topic, the ground truth,
the readings): a recording cut short printed its ``[recovery]`` line each time. A line
is said when it is first met in a command; :func:`new_command` (``diffdrive-odom``'s
dispatch) starts again, so a test running several commands in one process sees each
command's own.
"""

from __future__ import annotations

_SAID: set[str] = set()


def first_time(line: str) -> bool:
    """Tell whether ``line`` is new in this command (and remember it)."""
    if line in _SAID:
        return False
    _SAID.add(line)
    return True


def new_command() -> None:
    """Forget what was said: a new command says its own lines."""
    _SAID.clear()
