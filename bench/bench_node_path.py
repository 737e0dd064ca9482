"""Per-reading cost of ``odometry_node``'s path before and after issue 23, side by side.

What the node does for each JointState (``ros/odometry_node.py``, ``_on_joint_state``):
decode the message's bytes (the wire layer's ``JointStateDecoder``),
``ReadingPipeline.feed`` with the receive time, the outcome's report check, and for a
published pose ``pipeline_publication``, the propagated covariance written into the
Odometry bytes and the Odometry and /tf messages encoded. rclpy's own part (the
callback, ``publish``) is not timed: it is the same for both trees.

Before: the tree at ``--before`` (default 5a2a093, the last commit before issue 23's
moves: ``core/`` flat, the codecs in ``core/cdr.py``), taken from this clone's history
with ``git archive`` into a temporary directory. After: this working tree. The same
stream (a slow left turn at 1 kHz, the defaults' joints in radians, covariance
propagated; serialised once here by rclpy) is fed to a fresh pipeline in a fresh
interpreter per round, with ``PYTHONPATH`` pointing at one tree; rounds alternate
between the trees, so machine noise hits both alike. Each round's figure is the
worker's CPU time over the stream (``time.process_time``: time other processes take
on a shared machine does not count), the best of :data:`PASSES` passes; the medians
of the rounds are compared, and the median of each round's after/before ratio. Both
trees must end at the same pose, bit for bit (the moves changed no behaviour).

    .venv/bin/python bench/bench_node_path.py [--readings 20000] [--rounds 7] [--quick]

Without git history (an archive, a shallow clone lacking the commit) it says so and
exits 0 without measuring.
"""

from __future__ import annotations

import argparse
import importlib
import io
import json
import math
import os
import pickle
import pkgutil
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
BEFORE = "5a2a093"
RATE_HZ = 1000
LEFT_RAD_S, RIGHT_RAD_S = 10.0, 11.0  # joint speeds: a slow left turn (as bench_core)
T0_NS = 1_700_000_000 * 10**9
LATENCY_NS = 1_000_000  # receive time = stamp + 1 ms: a driver's clock in sync
PARAMS = {"wheel_radius": 0.05, "wheel_separation": 0.3}
WARMUP = 2000
PASSES = 3  # passes over the stream per round, each on a fresh pipeline; the best counts

# Where each name lived before the move and lives after it (first found wins); a
# name moved again later is looked up in the package (see _owner).
OWNERS = {
    "ReadingPipeline": ("diffdrive_odom.core.estimation.pipeline", "diffdrive_odom.core.pipeline"),
    "pipeline_publication": ("diffdrive_odom.core.estimation.publication",
                             "diffdrive_odom.core.publication"),
    "Refusal": ("diffdrive_odom.core.estimation.publication", "diffdrive_odom.core.publication"),
    "JointStateDecoder": ("diffdrive_odom.wire.cdr", "diffdrive_odom.core.cdr"),
    "OdometryLayout": ("diffdrive_odom.wire.cdr", "diffdrive_odom.core.cdr"),
    "TransformLayout": ("diffdrive_odom.wire.cdr", "diffdrive_odom.core.cdr"),
    "odometry_settings": ("diffdrive_odom.settings.odometry",),
}


# --- the worker: one round in one tree -------------------------------------------------


def _owner(name: str) -> Any:
    """``name`` from the module that defines it, in whichever tree is on the path."""
    for module in OWNERS[name]:
        try:
            found = getattr(importlib.import_module(module), name, None)
        except ImportError:
            continue
        if found is not None:
            return found
    import diffdrive_odom

    for info in pkgutil.walk_packages(diffdrive_odom.__path__, "diffdrive_odom."):
        if not info.name.startswith(("diffdrive_odom.core", "diffdrive_odom.wire",
                                     "diffdrive_odom.settings")):
            continue
        found = getattr(importlib.import_module(info.name), name, None)
        if found is not None and getattr(found, "__module__", None) == info.name:
            return found
    raise LookupError(f"{name} is defined nowhere in {diffdrive_odom.__file__}")


def worker(stream_path: str) -> int:
    """Time the node's path over the stream once; print a JSON line with the result."""
    import diffdrive_odom

    raws: list[bytes] = pickle.loads(Path(stream_path).read_bytes())
    ReadingPipeline = _owner("ReadingPipeline")  # noqa: N806
    publication, refusal = _owner("pipeline_publication"), _owner("Refusal")
    decoder_type = _owner("JointStateDecoder")
    odom_type, tf_type = _owner("OdometryLayout"), _owner("TransformLayout")
    settings = _owner("odometry_settings")(dict(PARAMS))

    def run(data: list[bytes]) -> tuple[float, Any, int]:
        pipe = ReadingPipeline(settings)
        decoder = decoder_type()
        odom = odom_type(settings.odom_frame_id, settings.base_frame_id)
        tf = tf_type(settings.odom_frame_id, settings.base_frame_id)
        feed, decode = pipe.feed, decoder.decode
        sent = 0
        t0 = time.process_time()
        for raw in data:
            msg = decode(raw)
            stamp = msg.sec * 1_000_000_000 + msg.nanosec
            outcome = feed(stamp, msg.name, msg.position, msg.velocity,
                           receive_ns=stamp + LATENCY_NS, check_clock=True)
            if outcome.note or outcome.warning or outcome.verdict.warning:
                pass  # the node logs here; a steady drive has nothing to say
            if outcome.publish:
                out = publication(pipe)
                if isinstance(out, refusal):
                    continue
                odom.covariance(out.pose_covariance, out.twist_covariance)
                pose = out.pose
                odom.planar(outcome.stamp_ns, pose.x, pose.y, pose.theta, out.linear,
                            out.angular)
                tf.planar(outcome.stamp_ns, pose.x, pose.y, pose.theta)
                sent += 1
        return time.process_time() - t0, pipe.estimator.pose, sent

    run(raws[:WARMUP])
    runs = [run(raws) for _ in range(PASSES)]
    seconds, pose, sent = min(runs, key=lambda r: r[0])
    print(json.dumps({"us": seconds / len(raws) * 1e6, "sent": sent,
                      "pose": [pose.x, pose.y, pose.theta],
                      "package": str(Path(diffdrive_odom.__file__).resolve().parent)}))
    return 0


# --- the driver: both trees, interleaved -------------------------------------------------


def stream(n: int) -> list[bytes]:
    """``n`` serialised JointStates of the steady drive, as a driver sends them."""
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import JointState

    out = []
    for k in range(n):
        t = k / RATE_HZ
        stamp = T0_NS + k * 10**9 // RATE_HZ
        msg = JointState()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 10**9)
        msg.name = ["left_wheel_joint", "right_wheel_joint"]
        msg.position = [LEFT_RAD_S * t, RIGHT_RAD_S * t]
        msg.velocity = [LEFT_RAD_S, RIGHT_RAD_S]
        out.append(bytes(serialize_message(msg)))
    return out


def old_tree(commit: str, into: Path) -> Path | None:
    """The package at ``commit`` extracted under ``into`` (None: no such history here)."""
    git = ["git", "-C", str(ROOT)]
    try:
        found = subprocess.run([*git, "rev-parse", "--verify", "--quiet", f"{commit}^{{commit}}"],
                               capture_output=True, check=False)
        if found.returncode != 0:
            return None
        tar = subprocess.run([*git, "archive", "--format=tar", commit, "diffdrive_odom"],
                             capture_output=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        return None
    with tarfile.open(fileobj=io.BytesIO(tar)) as archive:
        archive.extractall(into, filter="data")
    return into


def one_round(tree: Path, stream_path: Path) -> dict[str, Any]:
    """One worker run with ``tree`` first on the path."""
    env = {**os.environ, "PYTHONPATH": str(tree), "PYTHONDONTWRITEBYTECODE": "1"}
    done = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--worker",
                           str(stream_path)], env=env, capture_output=True, text=True,
                          check=False, cwd=tempfile.gettempdir())
    if done.returncode != 0:
        raise RuntimeError(f"worker on {tree} failed:\n{done.stderr}")
    result: dict[str, Any] = json.loads(done.stdout.strip().splitlines()[-1])
    if Path(result["package"]) != (tree / "diffdrive_odom").resolve():
        raise RuntimeError(f"worker imported {result['package']}, not the tree {tree}")
    return result


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    ap.add_argument("--readings", type=int, default=20_000, help="readings per round")
    ap.add_argument("--rounds", type=int, default=7, help="rounds per tree (interleaved)")
    ap.add_argument("--before", default=BEFORE, help="the commit before the change")
    ap.add_argument("--quick", action="store_true", help="smoke run: 4000 readings, 2 rounds")
    ap.add_argument("--worker", metavar="STREAM", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        return worker(args.worker)
    n, rounds = (4000, 2) if args.quick else (args.readings, args.rounds)
    with tempfile.TemporaryDirectory(prefix="bench_node_path_") as tmp:
        before = old_tree(args.before, Path(tmp) / "before")
        if before is None:
            print(f"skipped: commit {args.before} is not in this clone's git history "
                  "(an archive or a shallow clone); fetch it to compare before and after")
            return 0
        stream_path = Path(tmp) / "stream.pickle"
        stream_path.write_bytes(pickle.dumps(stream(n)))
        trees = {f"before ({args.before})": before, "after (this tree)": ROOT}
        results: dict[str, list[dict[str, Any]]] = {label: [] for label in trees}
        for _ in range(rounds):
            for label, tree in trees.items():
                results[label].append(one_round(tree, stream_path))
    poses = {json.dumps(r["pose"]) for rs in results.values() for r in rs}
    sent = {r["sent"] for rs in results.values() for r in rs}
    print(f"odometry_node's path per JointState [us/reading, CPU]: decode + feed + "
          f"publication + Odometry and /tf bytes; {n} readings at {RATE_HZ} Hz, {rounds} "
          f"interleaved rounds per tree (best of {PASSES} passes), each in a fresh "
          "interpreter")
    print(f"{'tree':34s}{'median':>10s}{'min':>10s}{'max':>10s}")
    medians = []
    for label, rs in results.items():
        us = [r["us"] for r in rs]
        medians.append(statistics.median(us))
        print(f"{label:34s}{medians[-1]:10.2f}{min(us):10.2f}{max(us):10.2f}")
    paired = statistics.median(a["us"] / b["us"] for b, a in zip(*results.values(), strict=True))
    print(f"{'after / before (medians)':34s}{medians[1] / medians[0]:10.3f}")
    print(f"{'after / before (paired rounds)':34s}{paired:10.3f}")
    same = len(poses) == 1 and sent == {n}
    final = json.loads(poses.pop()) if len(poses) == 1 else None
    print("both trees end at the same pose, bit for bit, every reading published: "
          f"{'yes' if same else 'NO'}"
          + (f" ({', '.join(f'{v:.9g}' for v in final)})" if final else ""))
    return 0 if same and all(math.isfinite(m) for m in medians) else 1


if __name__ == "__main__":
    sys.exit(main())
