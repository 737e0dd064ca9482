"""The optional dependencies, and the one line a missing one gets.

Pure Python. A plain ``pip install diffdrive_odom`` brings numpy and PyYAML (and, with
ROS from pip or apt, rclpy and the messages): what the nodes import, as package.xml
declares it for rosdep. The bag tools need the ``tools`` extra (rosbags, orjson, scipy,
matplotlib; threadpoolctl, optional) and the odometry node needs tf2_msgs, which is no
PyPI package. The commands import those only where they are used, so ``--help`` always
works; when one is missing at run time, the command says which and how to get it in one
line (exit 2) instead of a traceback. The extras are declared in setup.py; this table says
which extra holds each module, and the line names the extra's libraries as the installed
distribution declares them, for a colcon build, which no ``pip install`` of the
package made.
"""

from __future__ import annotations

import re
import shlex
from importlib import metadata

DISTRIBUTION = "diffdrive_odom"

# Top-level module -> the extra of setup.py that installs it.
EXTRAS: dict[str, str] = {
    "rosbags": "tools",
    "orjson": "tools",
    "scipy": "tools",
    "matplotlib": "tools",
    "threadpoolctl": "tools",  # optional: calibrate's fits run without it
    "pytest": "test",
    "hypothesis": "test",
    "mcap": "test",
    "mcap_ros2": "test",
    "distributed": "fleet",
}

# Top-level module -> how to get it when no extra can (ROS packages not on PyPI).
ROS_PACKAGES: dict[str, str] = {
    "tf2_msgs": ("tf2_msgs is a ROS 2 package, not on PyPI: sudo apt install "
                 "ros-jazzy-tf2-msgs (rosdep does it), or in a venv: "
                 "bash scripts/build_tf2_msgs.sh VENV"),
}

_EXTRA = re.compile(r"""extra\s*==\s*["']([^"']+)["']""")


def extra_requirements(extra: str) -> list[str]:
    """The requirements of ``extra`` as the installed distribution declares them.

    Empty where the package was never installed (a source tree on ``PYTHONPATH``).
    """
    try:
        declared = metadata.requires(DISTRIBUTION) or []
    except metadata.PackageNotFoundError:
        return []
    found = []
    for line in declared:
        spec, _, marker = line.partition(";")
        named = _EXTRA.search(marker)
        if named is not None and named.group(1) == extra:
            found.append(spec.strip())
    return found


def missing_text(module: str | None, who: str) -> str | None:
    """The one line for ``who`` (a command) missing ``module``, or None if not optional.

    ``module``: the name an ImportError carries (``ModuleNotFoundError.name``), dotted
    or not.
    """
    top = (module or "").split(".")[0]
    if top in EXTRAS:
        extra = EXTRAS[top]
        line = f"{who} needs {top}: pip install '{DISTRIBUTION}[{extra}]'"
        libraries = " ".join(shlex.quote(r) for r in extra_requirements(extra))
        return f"{line} (or its libraries alone: pip install {libraries})" if libraries else line
    if top in ROS_PACKAGES:
        return f"{who} needs {top}: {ROS_PACKAGES[top]}"
    return None
