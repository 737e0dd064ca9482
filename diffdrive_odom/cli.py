"""``diffdrive-odom``: one entry point for the tools, each in its own module.

Subcommands are imported only when used, so ``diffdrive-odom eval`` does not pay
for rclpy and ``diffdrive-odom play`` does not pay for matplotlib.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Sequence

COMMANDS: dict[str, tuple[str, str]] = {
    "demo": ("diffdrive_odom.demo", "closed-loop demo: sim + cmd_vel + odometry, table, plot, bag"),
    "play": ("diffdrive_odom.play", "publish a bag's messages over DDS with /clock (no rosbag2)"),
    "replay": ("diffdrive_odom.replay", "run the estimator over a bag offline; write bag/CSV"),
    "eval": ("diffdrive_odom.evaluate", "compare odometry with ground truth in a bag"),
}


def main(argv: Sequence[str] | None = None) -> int:
    """Dispatch to ``<module>.main(argv)``."""
    args = list(sys.argv[1:] if argv is None else argv)
    if not args or args[0] in ("-h", "--help") or args[0] not in COMMANDS:
        print("usage: diffdrive-odom {" + ",".join(COMMANDS) + "} ...\n")
        for name, (_, text) in COMMANDS.items():
            print(f"  {name:8s} {text}")
        return 0 if args and args[0] in ("-h", "--help") else 2
    module = importlib.import_module(COMMANDS[args[0]][0])
    return int(module.main(args[1:]) or 0)


if __name__ == "__main__":
    sys.exit(main())
