"""A launch argument the package's launch files do not declare, said in one warning line.

``ros2 launch`` takes any ``name:=value`` and sets it as a launch configuration: one no
file declares is silently ignored (``publish_tf:=false``, robot_localization's name, did
nothing). It is not refused, since a launch file that includes another passes its own
arguments on to it, so only the file ``ros2 launch`` itself ran checks what it was
given: the line names each unknown argument with the one it most likely stands for
(:func:`~diffdrive_odom.settings.registry.did_you_mean`). Pure: the launch files call it
from an ``OpaqueFunction`` with ``context.argv`` and log the line.
"""

from __future__ import annotations

import sys
from collections.abc import Iterable, Sequence
from pathlib import Path

from diffdrive_odom.settings.registry import did_you_mean

# What ros2 launch adds to the arguments itself (--launch-prefix, --launch-prefix-filter).
ROS2_LAUNCH_OWN = ("launch-prefix", "launch-prefix-filter")


def unknown_arguments_line(launch_file: str, given: Sequence[str], declared: Iterable[str],
                           command: Sequence[str] | None = None) -> str | None:
    """The warning for ``given`` (``name:=value`` items) none of ``declared`` names, or None.

    None also where ``launch_file`` (a launch file's ``__file__``) is not the file the
    ``ros2 launch`` ``command`` (default: this process's) ran: included, it gets the
    including file's arguments too.
    """
    name = Path(launch_file).name
    words = sys.argv if command is None else command
    if not any(Path(w).name == name for w in words[1:] if ":=" not in w):
        return None
    known = set(declared)
    unknown = [arg.split(":=", 1)[0] for arg in given if ":=" in arg]
    unknown = [u for u in dict.fromkeys(unknown) if u not in known and u not in ROS2_LAUNCH_OWN]
    if not unknown:
        return None
    parts = []
    for arg in unknown:
        hint = did_you_mean(arg, known)
        parts.append(f"{arg}:=" + (f" ({hint})" if hint else ""))
    return (f"{name} has no launch argument " + ", ".join(parts)
            + f"; ignored (ros2 launch diffdrive_odom {name} --show-args lists them)")
