"""Test-session setup: every run gets its own DDS domain, on loopback only."""

from __future__ import annotations

import os
import random

# Before anything imports rclpy or starts a node: child processes inherit these.
if "ROS_DOMAIN_ID" not in os.environ or os.environ.get("DIFFDRIVE_ODOM_FRESH_DOMAIN", "1") == "1":
    os.environ["ROS_DOMAIN_ID"] = str(random.Random(os.getpid() ^ id(os)).randint(1, 100))
    os.environ["DIFFDRIVE_ODOM_FRESH_DOMAIN"] = "0"
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.pop("ROS_LOCALHOST_ONLY", None)
os.environ.setdefault("RCUTILS_COLORIZED_OUTPUT", "0")
