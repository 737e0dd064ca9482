"""The optional dependencies, and the one line a missing one gets.

Pure Python. A plain ``pip install diffdrive_odom`` brings numpy (and, with ROS from
pip or apt, rclpy and the messages); the bag tools need the ``tools`` extra
(rosbags, scipy, matplotlib) and the odometry node needs tf2_msgs, which is no PyPI
package. The commands import those only where they are used, so ``--help`` always
works; when one is missing at run time, the command says which and how to get it in
one line (exit 2) instead of a traceback. The extras are declared in setup.py; this
table says which extra holds each module.
"""

from __future__ import annotations

DISTRIBUTION = "diffdrive_odom"

# Top-level module -> the extra of setup.py that installs it.
EXTRAS: dict[str, str] = {
    "rosbags": "tools",
    "scipy": "tools",
    "matplotlib": "tools",
    "pytest": "test",
    "hypothesis": "test",
}

# Top-level module -> how to get it when no extra can (ROS packages not on PyPI).
ROS_PACKAGES: dict[str, str] = {
    "tf2_msgs": ("tf2_msgs is a ROS 2 package, not on PyPI: sudo apt install "
                 "ros-jazzy-tf2-msgs (rosdep does it), or in a venv: "
                 "bash scripts/build_tf2_msgs.sh VENV"),
}


def missing_text(module: str | None, who: str) -> str | None:
    """The one line for ``who`` (a command) missing ``module``, or None if not optional.

    ``module``: the name an ImportError carries (``ModuleNotFoundError.name``), dotted
    or not.
    """
    top = (module or "").split(".")[0]
    if top in EXTRAS:
        return f"{who} needs {top}: pip install '{DISTRIBUTION}[{EXTRAS[top]}]'"
    if top in ROS_PACKAGES:
        return f"{who} needs {top}: {ROS_PACKAGES[top]}"
    return None
