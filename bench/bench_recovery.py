"""A torn recording against the intact one: reading its messages, and its JointStates.

    .venv/bin/python bench/bench_recovery.py [--mb 100] [--repeat 3] [--quick]

One MCAP recording of JointStates at 100 Hz (rosbag2 as rosbags writes it, about
``--mb`` MB), and the same file torn mid-record in its last chunk (that chunk's tail,
the summary and the footer gone) in a folder without ``metadata.yaml``: what a
recorder killed near the end leaves. Each is opened with ``bagio.open_bag`` (rosbags for the intact
one, :mod:`diffdrive_odom.tools.bags.recovery` for the torn one) and read:

- ``messages``: every message's raw bytes (open, scan, yield), nothing decoded;
- ``joint blocks``: the JointState readings replay works on (``read_joint_blocks``).

Runs are interleaved (intact, torn, intact, ...) so both see the same machine; the
median of ``--repeat`` runs is printed, and the ratio (the issue's goal: within 2x).
"""

from __future__ import annotations

import argparse
import io
import shutil
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from contextlib import redirect_stderr
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from diffdrive_odom.core.bulk.readings import JointBlock  # noqa: E402
from diffdrive_odom.tools.bags import bagblocks, bagio, bagwriter  # noqa: E402


def _write(path: Path, n: int) -> bytes:
    """n JointStates through the bulk writer: one message's CDR, stamps and angles set.

    Returns the last message's bytes (where the tear goes is found by them).
    """
    t = bagio.typestore().types
    probe = t[bagio.JOINT_STATE](
        header=t["std_msgs/msg/Header"](stamp=t["builtin_interfaces/msg/Time"](
            sec=0x5EC5EC5E, nanosec=0x0AC0AC0A), frame_id="base"),
        name=["left_wheel_joint", "right_wheel_joint"],
        position=np.array([1234.5678, 8765.4321]), velocity=np.array([0.25, 0.5]),
        effort=np.zeros(0))
    raw = np.frombuffer(bagio.typestore().serialize_cdr(probe, bagio.JOINT_STATE), np.uint8)
    body = raw.tobytes()
    at_sec = body.index((0x5EC5EC5E).to_bytes(4, "little"))
    at_pos = body.index(np.array([1234.5678]).tobytes())
    logs = 1_700_000_000 * 10**9 + np.arange(n, dtype=np.int64) * 10_000_000
    rows = np.tile(raw, (n, 1))
    rows[:, at_sec:at_sec + 4] = (logs // 10**9).astype("<u4").view(np.uint8).reshape(n, 4)
    rows[:, at_sec + 4:at_sec + 8] = (logs % 10**9).astype("<u4").view(np.uint8).reshape(n, 4)
    rng = np.random.default_rng(1)
    wheels = np.cumsum(0.05 + 0.02 * rng.standard_normal((n, 2)), axis=0)
    rows[:, at_pos:at_pos + 16] = wheels.astype("<f8").view(np.uint8).reshape(n, 16)
    with bagwriter.BagWriter(path) as w:
        w.add_topic("/joint_states", bagio.JOINT_STATE)
        w.write_rows(["/joint_states"], logs, [rows])
    return bytes(rows[-1].tobytes())


def _messages(bag: Path) -> int:
    with redirect_stderr(io.StringIO()), bagio.open_bag(bag) as reader:
        return sum(len(raw) > 0 for _, _, raw in reader.messages())


def _blocks(bag: Path) -> int:
    with redirect_stderr(io.StringIO()):
        return sum(len(item) if isinstance(item, JointBlock) else 1
                   for item in bagblocks.read_joint_blocks(bag))


def _time(func: Callable[[Path], int], bag: Path) -> tuple[float, int]:
    t0 = time.perf_counter()
    count = func(bag)
    return time.perf_counter() - t0, count


def main() -> int:
    """Write the two recordings, time them interleaved, print the table."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--mb", type=float, default=100.0, help="size of the recording [MB]")
    ap.add_argument("--repeat", type=int, default=3, help="runs of each (median)")
    ap.add_argument("--quick", action="store_true", help="5 MB, 3 runs (the test's)")
    args = ap.parse_args()
    if args.quick:
        args.mb, args.repeat = 5.0, 3
    with tempfile.TemporaryDirectory() as tmp:
        intact = Path(tmp) / "intact"
        n = int(args.mb * 1e6 / 176)  # bytes a message takes in the file, about
        last = _write(intact, n)
        (mcap,) = intact.glob("*.mcap")
        torn = Path(tmp) / "torn"
        torn.mkdir()
        data = mcap.read_bytes()
        # 10 kB before the last message's end: mid-record in the last chunk
        (torn / "torn_0.mcap").write_bytes(data[:data.rfind(last) - 10_000])
        del data
        size = mcap.stat().st_size / 1e6
        print(f"recording: {size:.1f} MB, {n} JointStates; torn copy cut in its last "
              f"chunk, no metadata.yaml; median of {args.repeat}, interleaved")
        print(f"{'read':14s} {'intact [s]':>11s} {'torn [s]':>9s} {'ratio':>6s} "
              f"{'intact msgs':>12s} {'torn msgs':>10s}")
        for name, func in (("messages", _messages), ("joint blocks", _blocks)):
            runs: dict[str, list[float]] = {"intact": [], "torn": []}
            counts = {}
            for _ in range(args.repeat):
                for label, bag in (("intact", intact), ("torn", torn)):
                    seconds, counts[label] = _time(func, bag)
                    runs[label].append(seconds)
            a, b = (statistics.median(runs[k]) for k in ("intact", "torn"))
            print(f"{name:14s} {a:11.3f} {b:9.3f} {b / a:6.2f} {counts['intact']:12d} "
                  f"{counts['torn']:10d}")
        shutil.rmtree(intact)
    return 0


if __name__ == "__main__":
    sys.exit(main())
