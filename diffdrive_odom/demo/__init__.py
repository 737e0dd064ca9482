"""``diffdrive-odom demo`` (``make demo``): the whole product in one closed loop.

Kept import-light (no rclpy, no matplotlib): the pure parts (:mod:`.settings`,
:mod:`.report`, :mod:`.plot`) import without ROS, and ``diffdrive_odom.demo.X`` for the
few names other code uses is resolved on first use from the submodule that owns it.

- :mod:`.settings`: options, the params file of a run, the squares' paths, the topic table
- :mod:`.report`: recorded series, calibration from the run, the results table (pure)
- :mod:`.plot`: the picture (matplotlib, pure)
- :mod:`.children`: the four nodes as child processes (logs, stop on leaving)
- :mod:`.recorder`: this process's node (records the bag, sends the paths)
- :mod:`.loop`: the run (start, wait until up, drive the squares, evaluate)
- :mod:`.cli`: the command line
"""

from __future__ import annotations

import importlib
from typing import Any

_OWNERS = {
    "BAG_TOPICS": "settings", "DEFAULT_PARAMS": "settings", "DemoError": "settings",
    "DemoOptions": "settings", "DemoResult": "report",
    "run": "loop", "main": "cli",
}

__all__ = sorted(_OWNERS)


def __getattr__(name: str) -> Any:
    """``diffdrive_odom.demo.NAME`` from the submodule that defines it (PEP 562)."""
    owner = _OWNERS.get(name)
    if owner is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{owner}"), name)
