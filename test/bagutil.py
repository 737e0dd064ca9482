"""Shared helpers of the bag tests: an independent MCAP reader and params files."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

OPTIODOM_PARAMS = {"wheel_radius": 0.042, "wheel_separation": 0.200}
TB3_PARAMS = {
    "wheel_radius": 0.033,
    "wheel_separation": 0.287,
    "left_wheel_names": ["wheel_left_joint"],
    "right_wheel_names": ["wheel_right_joint"],
}


def mcap_messages(
    bag: Path, topics: Sequence[str] | None = None
) -> Iterator[tuple[str, int, Any]]:
    """(topic, log time, message) decoded by mcap-ros2-support, not by rosbags."""
    files = sorted(bag.glob("*.mcap")) if bag.is_dir() else [bag]
    assert files, f"no .mcap in {bag}"
    for path in files:
        with open(path, "rb") as f:
            reader = make_reader(f, decoder_factories=[DecoderFactory()])
            for _, channel, message, msg in reader.iter_decoded_messages(topics=topics):
                yield channel.topic, message.log_time, msg


def write_params(path: Path, values: dict[str, Any], node: str = "odometry_node") -> Path:
    """A ROS 2 params YAML for ``node`` (the form ``--params-file`` takes)."""
    import yaml

    path.write_text(yaml.safe_dump({node: {"ros__parameters": values}}), encoding="utf-8")
    return path
