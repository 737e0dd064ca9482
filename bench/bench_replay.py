"""Replay speed next to the speed of merely reading / decoding the same bag, and the
vectorised path next to the step-by-step estimator, in one run.

    .venv/bin/python bench/bench_replay.py [--long 40000]

Rows per bag (readings/s, higher is better; ratios against "rosbags decode"):
  read only        iterate the bag's raw JointState records (no deserialization)
  rosbags decode   every JointState deserialised by rosbags (the baseline)
  decode only      JointState -> readings in stamp order, as replay reads them (runs
                   of alike rosbag2 messages as blocks by numpy, else the node's CDR
                   decoder; rosbags' for ROS 1)
  replay           decode + the node's reading pipeline (fast lane), nothing written
  replay -> bag    decode + pipeline + Odometry and /tf into an MCAP bag + CSV
and, on the decoded readings held in memory:
  step-by-step     the pipeline fed one reading at a time (the node's path)
  fast lane        the same through core.bulk.fastlane (rule-free stretches in bulk)
  vectorised       wheel_steps (decode once) + integrate_steps (numpy)
  integrate only   integrate_steps alone: calibration's inner loop
Memory: peak traced allocation of streaming replay -> bag on a synthetic bag and on
one four times longer.

``--before COMMIT``: only replay in memory (the fast lane and step by step, a weaving
robot at 100 Hz, and the same with every other reading repeating the counts before it
as a Kobuki's driver does), this tree against the tree at COMMIT (``git archive``), each
round in fresh interpreters, rounds interleaved; the median of the rounds' ratios.

Sizes (issue 19): synthetic bags of 1e4, 1e5 and 1e6 readings (``--sizes``), side by
side: rosbags' decode-only, replay -> bag and replay -> CSV through the fast lane
(:mod:`diffdrive_odom.core.bulk.fastlane`), replay -> bag one reading at a time (up to
``--slow-max`` readings), and the peak traced allocation of replay -> bag.

Writers (issue 39, ``--writers N``): replay's rows (an Odometry and a /tf message a
reading) into MCAP by the bulk path, which leans on rosbags' writer internals
(:mod:`diffdrive_odom.tools.bags.rosbagsinternals`), and by the two public writers, one
message at a time: rosbags' ``Writer.write`` and the mcap library's
``Writer.add_message``; timed round by round, side by side.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
import tracemalloc
from collections.abc import Callable
from functools import partial
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
if "--lane-worker" not in sys.argv:  # a worker times the tree PYTHONPATH names
    sys.path.insert(0, str(ROOT))

from diffdrive_odom.core.bulk import batch  # noqa: E402
from diffdrive_odom.core.bulk.readings import count  # noqa: E402
from diffdrive_odom.core.estimation.config import OdometrySettings  # noqa: E402
from diffdrive_odom.settings.odometry import odometry_settings  # noqa: E402
from diffdrive_odom.tools.bags import bagblocks, bagio, bagreadings, bagwriter  # noqa: E402
from diffdrive_odom.tools.replaying import csvout, sinks  # noqa: E402
from diffdrive_odom.tools.replaying.readings import replay_readings  # noqa: E402

DATA = ROOT / "test" / "data"


def _best(fn: Callable[[], object], repeat: int = 3,
          setup: Callable[[], object] | None = None) -> float:
    """Fastest of ``repeat`` runs of ``fn`` (``setup`` before each, not timed)."""
    best = float("inf")
    for _ in range(repeat):
        if setup is not None:
            setup()
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def _clear(out: Path) -> None:
    """Remove an earlier output (its deletion is not the replay's time)."""
    shutil.rmtree(out, ignore_errors=True)
    out.with_suffix(".csv").unlink(missing_ok=True)


def _synthetic(path: Path, n: int, storage: str = "mcap") -> None:
    """A JointState bag of a robot weaving at 100 Hz (random-ish wheel speeds)."""
    rng = np.random.default_rng(1)
    left = np.cumsum(0.05 + 0.02 * rng.standard_normal(n))
    right = np.cumsum(0.05 + 0.02 * rng.standard_normal(n))
    with bagwriter.BagWriter(path, storage) as w:
        w.add_topic("/joint_states", bagio.JOINT_STATE)
        t = w.typestore.types
        for k in range(n):
            ns = 10**9 + k * 10**7
            sec, nsec = divmod(ns, 10**9)
            w.write("/joint_states", ns, t[bagio.JOINT_STATE](
                header=t["std_msgs/msg/Header"](
                    stamp=t["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec), frame_id=""),
                name=["left_wheel_joint", "right_wheel_joint"],
                position=np.array([left[k], right[k]]), velocity=np.zeros(0),
                effort=np.zeros(0)))


def _read_only(bag: Path) -> int:
    with bagio.open_bag(bag) as reader:
        conns = bagio.connections_for(reader, "/joint_states")
        return sum(1 for _ in reader.messages(connections=conns))


def _rosbags_decode(bag: Path) -> int:
    """The baseline: every JointState deserialised by rosbags, nothing else."""
    with bagio.open_bag(bag) as reader:
        conns = bagio.connections_for(reader, "/joint_states")
        return sum(1 for conn, _, raw in reader.messages(connections=conns)
                   if reader.deserialize(raw, conn.msgtype) is not None)


def _replay_to_bag(bag: Path, settings: OdometrySettings, out: Path) -> None:
    """What ``diffdrive-odom replay BAG -o OUT --csv OUT.csv`` does, minus argument parsing."""
    shutil.rmtree(out, ignore_errors=True)
    with bagwriter.BagWriter(out) as w, csvout.CsvWriter(out.with_suffix(".csv")) as table:
        w.add_topic("/odom", bagio.ODOMETRY)
        w.add_topic("/tf", bagio.TF_MESSAGE)
        replay_readings(bagblocks.read_joint_blocks(bag), settings,
                               sinks.OutputSink(settings, w, table))


def _replay_to(bag: Path, settings: OdometrySettings, out: Path, *, to_bag: bool,
               fast: bool = True) -> None:
    """``replay BAG -o OUT`` (``to_bag``) or ``replay BAG --csv OUT.csv``, one output."""
    _clear(out)
    if to_bag:
        with bagwriter.BagWriter(out) as w:
            w.add_topic("/odom", bagio.ODOMETRY)
            w.add_topic("/tf", bagio.TF_MESSAGE)
            replay_readings(bagblocks.read_joint_blocks(bag), settings,
                                   sinks.OutputSink(settings, w, None), fast=fast)
    else:
        with csvout.CsvWriter(out.with_suffix(".csv")) as table:
            replay_readings(bagblocks.read_joint_blocks(bag), settings,
                                   sinks.OutputSink(settings, None, table), fast=fast)


def bench_sizes(tmp: Path, sizes: list[int], slow_max: int, settings: OdometrySettings) -> None:
    """Replay -> bag / CSV against rosbags' decode-only, by bag size, memory beside."""
    print("\nreplay by bag size (synthetic rosbag2 mcap; readings/s, ratio to rosbags "
          "decode-only; peak = traced allocation of replay -> bag)")
    print(f"  {'readings':>9s} {'rosbags decode':>15s} {'-> bag (lane)':>21s} "
          f"{'-> CSV (lane)':>21s} {'-> bag (1 by 1)':>21s} {'peak MB':>8s}")
    for n in sizes:
        bag = tmp / f"sizes{n}"
        _synthetic(bag, n)
        repeat = 5 if n <= 10_000 else 3 if n <= 100_000 else 1
        out = tmp / f"sizes_out{n}"
        # side by side: each round times the three once, so a noisy spell hits them all
        best = [float("inf")] * 3
        runs: list[Callable[[], object]] = [
            partial(_rosbags_decode, bag), partial(_replay_to, bag, settings, out, to_bag=True),
            partial(_replay_to, bag, settings, out, to_bag=False)]
        for _ in range(repeat):
            for k, run in enumerate(runs):
                best[k] = min(best[k], _best(run, 1, partial(_clear, out)))
        decode, cols = best[0], best[1:]
        slow = (_best(partial(_replay_to, bag, settings, out, to_bag=True, fast=False), 1,
                      partial(_clear, out))
                if n <= slow_max else None)
        tracemalloc.start()
        _replay_to(bag, settings, out, to_bag=True)
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        cells = [f"{n / s:11,.0f} ({decode / s:4.2f}x)" for s in cols]
        cells.append(f"{n / slow:11,.0f} ({decode / slow:4.2f}x)" if slow else f"{'-':>21s}")
        print(f"  {n:9d} {n / decode:15,.0f} " + " ".join(f"{c:>21s}" for c in cells)
              + f" {peak / 1e6:8.2f}")
        shutil.rmtree(bag, ignore_errors=True)
        shutil.rmtree(out, ignore_errors=True)


def bench_writers(tmp: Path, n: int, rounds: int = 3) -> None:
    """``n`` rows of replay's two messages through each MCAP writer (us a message)."""
    from mcap.writer import CompressionType
    from mcap.writer import Writer as McapWriter
    from rosbags.rosbag2 import StoragePlugin, Writer

    from diffdrive_odom.wire.odometry import OdometryLayout, TransformLayout

    odom = np.frombuffer(OdometryLayout("odom", "base_link").planar(
        10**9, 1.0, 2.0, 0.3, 0.1, 0.2), dtype=np.uint8)
    tf = np.frombuffer(TransformLayout("odom", "base_link").planar(10**9, 1.0, 2.0, 0.3),
                       dtype=np.uint8)
    rows = [np.tile(odom, (n, 1)), np.tile(tf, (n, 1))]
    log = 10**18 + np.arange(n, dtype=np.int64) * 10_000_000
    out = tmp / "writers"

    def bulk() -> None:
        with bagwriter.BagWriter(out) as w:
            w.add_topic("/odom", bagio.ODOMETRY)
            w.add_topic("/tf", bagio.TF_MESSAGE)
            w.write_rows(["/odom", "/tf"], log, rows)

    def rosbags_one_by_one() -> None:
        store = bagio.typestore()
        with Writer(out, version=9, storage_plugin=StoragePlugin.MCAP) as w:
            conns = [w.add_connection("/odom", bagio.ODOMETRY, typestore=store),
                     w.add_connection("/tf", bagio.TF_MESSAGE, typestore=store)]
            for k, stamp in enumerate(log.tolist()):
                for conn, data in zip(conns, rows, strict=True):
                    w.write(conn, stamp, data[k].tobytes())

    def mcap_one_by_one() -> None:
        out.mkdir()
        with (out / "writers.mcap").open("wb") as f:
            w = McapWriter(f, compression=CompressionType.NONE)
            w.start("ros2", "bench")
            channels = [w.register_channel(topic, "cdr", w.register_schema(kind, "ros2msg", b""))
                        for topic, kind in (("/odom", bagio.ODOMETRY), ("/tf", bagio.TF_MESSAGE))]
            for k, stamp in enumerate(log.tolist()):
                for channel, data in zip(channels, rows, strict=True):
                    w.add_message(channel, stamp, data[k].tobytes(), stamp)
            w.finish()

    cases: dict[str, Callable[[], None]] = {
        "bulk (rosbags internals)": bulk, "rosbags Writer.write": rosbags_one_by_one,
        "mcap Writer.add_message": mcap_one_by_one}
    best = dict.fromkeys(cases, float("inf"))
    for k in range(rounds):  # side by side: each round times each, in a rotated order
        names = list(cases)
        for name in names[k % len(names):] + names[:k % len(names)]:
            best[name] = min(best[name], _best(cases[name], 1,
                                               partial(shutil.rmtree, out, True)))
    shutil.rmtree(out, ignore_errors=True)
    print(f"\nMCAP writers: {n} rows of Odometry ({odom.size} B) and /tf ({tf.size} B), "
          f"best of {rounds} rounds side by side")
    print(f"  {'writer':28s} {'us/message':>11s} {'vs bulk':>8s}")
    for name, seconds in best.items():
        print(f"  {name:28s} {seconds * 1e6 / (2 * n):11.2f} "
              f"{seconds / best['bulk (rosbags internals)']:7.2f}x")


def bench_bag(name: str, bag: Path, settings: OdometrySettings, tmp: Path) -> None:
    readings = list(bagreadings.read_joint_states(bag))
    n = len(readings)
    rows: list[tuple[str, float]] = []
    rows.append(("read only", _best(lambda: _read_only(bag))))
    decode = _best(lambda: _rosbags_decode(bag))
    rows.append(("rosbags decode", decode))
    rows.append(("decode only", _best(lambda: sum(map(count, bagblocks.read_joint_blocks(bag))))))
    rows.append(("replay", _best(
        lambda: replay_readings(bagblocks.read_joint_blocks(bag), settings))))
    rows.append(("replay -> bag + csv", _best(
        lambda: _replay_to_bag(bag, settings, tmp / f"{name}_out"), repeat=2)))
    step = _best(lambda: replay_readings(readings, settings, fast=False))
    rows.append(("step-by-step (in memory)", step))
    rows.append(("fast lane (in memory)", _best(
        lambda: replay_readings(readings, settings))))
    rows.append(("vectorised (in memory)", _best(lambda: batch.integrate_steps(
        batch.wheel_steps(readings, settings), settings.geometry))))
    steps = batch.wheel_steps(readings, settings)
    integrate = _best(lambda: batch.integrate_steps(steps, settings.geometry), repeat=20)
    rows.append(("integrate only (numpy)", integrate))
    # Agreement of the two paths (the test asserts < 1e-9 m).
    end_step = replay_readings(readings, settings, fast=False).final_pose
    end_vec = batch.final_pose(steps, settings.geometry)
    gap = float(np.hypot(end_step.x - end_vec.x, end_step.y - end_vec.y))
    print(f"\n{name}: {n} readings ({bag.name})")
    print(f"  {'path':28s} {'readings/s':>14s} {'vs rosbags':>10s} {'vs step':>9s}")
    for label, seconds in rows:
        print(f"  {label:28s} {n / seconds:14,.0f} {decode / seconds:10.2f}x "
              f"{step / seconds:8.2f}x")
    print(f"  final pose, step-by-step vs vectorised: {gap:.1e} m")


def bench_memory(tmp: Path, n: int, settings: OdometrySettings) -> None:
    print(f"\nmemory (streaming replay -> MCAP bag, peak traced allocation), {n} readings base:")
    for k in (n, 4 * n):
        bag = tmp / f"synthetic{k}"
        if not bag.exists():
            _synthetic(bag, k)
        tracemalloc.start()
        t0 = time.perf_counter()
        _replay_to_bag(bag, settings, tmp / f"mem_out{k}")
        seconds = time.perf_counter() - t0
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        print(f"  {k:8d} readings: peak {peak / 1e6:6.2f} MB  "
              f"({k / seconds:,.0f} readings/s under tracemalloc)")


def _weave(n: int, repeats: bool) -> list[tuple[int, list[float]]]:
    """A robot weaving at 100 Hz (as :func:`_synthetic`): stamps and positions in memory.

    ``repeats``: every other reading repeats the counts before it, as a Kobuki's driver
    republishes its counters (each step that moves then judged over two periods).
    """
    rng = np.random.default_rng(1)
    left = np.cumsum(0.05 + 0.02 * rng.standard_normal(n))
    right = np.cumsum(0.05 + 0.02 * rng.standard_normal(n))
    k = np.arange(n) // 2 * 2 if repeats else np.arange(n)
    return [(10**9 + i * 10**7, [float(left[j]), float(right[j])]) for i, j in enumerate(k)]


def lane_worker(stream_path: str) -> int:
    """Time the fast lane and the step-by-step path over a stream once; a JSON line."""
    import diffdrive_odom
    from diffdrive_odom.core.bulk.readings import JointReading

    rows = json.loads(Path(stream_path).read_text())
    names = ("left_wheel_joint", "right_wheel_joint")
    readings = [JointReading(t, t, names, tuple(p), ()) for t, p in rows]
    settings = odometry_settings({"wheel_radius": 0.05, "wheel_separation": 0.3})
    out = {}
    for label, fast in (("fast lane", True), ("step-by-step", False)):
        best, pose = math.inf, None
        for _ in range(3):
            t0 = time.process_time()
            stats = replay_readings(readings, settings, fast=fast)
            best = min(best, time.process_time() - t0)
            pose = stats.final_pose
        assert pose is not None
        out[label] = {"us": best / len(readings) * 1e6, "pose": [pose.x, pose.y, pose.theta]}
    out["package"] = str(Path(diffdrive_odom.__file__).resolve().parent)  # type: ignore[assignment]
    print(json.dumps(out))
    return 0


def bench_before(commit: str, n: int, rounds: int) -> int:
    """This tree's replay against the tree at ``commit``, in fresh interpreters, rounds
    interleaved (a noisy spell hits both alike): the median of each round's ratio."""
    from bench_node_path import old_tree

    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        before = old_tree(commit, tmp / "before")
        if before is None:
            print(f"no commit {commit} in this clone's history: nothing measured")
            return 0
        print(f"\nreplay in memory, this tree against {commit} ({n} readings, {rounds} "
              "interleaved rounds; us per reading, CPU time, best of 3 a round)")
        for name, repeats in (("weave", False), ("weave, driver repeats", True)):
            path = tmp / "stream.json"
            path.write_text(json.dumps(_weave(n, repeats)))
            times: dict[str, dict[str, list[float]]] = {"before": {}, "after": {}}
            for _ in range(rounds):
                for tree, label in ((before, "before"), (ROOT, "after")):
                    env = {**os.environ, "PYTHONPATH": str(tree),
                           "PYTHONDONTWRITEBYTECODE": "1"}
                    done = subprocess.run(
                        [sys.executable, str(Path(__file__).resolve()), "--lane-worker",
                         str(path)], env=env, capture_output=True, text=True, check=True,
                        cwd=tempfile.gettempdir())
                    got = json.loads(done.stdout.strip().splitlines()[-1])
                    assert Path(got["package"]) == (tree / "diffdrive_odom").resolve(), got
                    for path_name in ("fast lane", "step-by-step"):
                        times[label].setdefault(path_name, []).append(got[path_name]["us"])
            for path_name in ("fast lane", "step-by-step"):
                b, a = times["before"][path_name], times["after"][path_name]
                ratios = sorted(x / y for x, y in zip(a, b, strict=True))
                print(f"  {name:22s} {path_name:13s} before {statistics.median(b):7.2f} us, "
                      f"after {statistics.median(a):7.2f} us: after/before median "
                      f"{statistics.median(ratios):.3f} (range {ratios[0]:.3f}-{ratios[-1]:.3f})")
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    ap.add_argument("--long", type=int, default=20_000,
                    help="readings of the synthetic bag (the memory check uses 4x too)")
    ap.add_argument("--sizes", type=int, nargs="*", default=[10_000, 100_000, 1_000_000],
                    help="synthetic bag sizes for the by-size table (none: skip it)")
    ap.add_argument("--slow-max", type=int, default=100_000,
                    help="largest bag also replayed one reading at a time")
    ap.add_argument("--only-sizes", action="store_true", help="only the by-size table")
    ap.add_argument("--before", metavar="COMMIT",
                    help="only: replay in memory, this tree against the tree at COMMIT")
    ap.add_argument("--rounds", type=int, default=7, help="with --before: interleaved rounds")
    ap.add_argument("--lane-worker", metavar="STREAM", help=argparse.SUPPRESS)
    ap.add_argument("--writers", type=int, default=100_000, metavar="N",
                    help="rows for the MCAP writers' table (0: skip it)")
    ap.add_argument("--only-writers", action="store_true", help="only the writers' table")
    args = ap.parse_args()
    if args.lane_worker:
        return lane_worker(args.lane_worker)
    if args.before:
        return bench_before(args.before, args.long, args.rounds)
    optiodom = odometry_settings({"wheel_radius": 0.042, "wheel_separation": 0.2})
    tb3 = odometry_settings({"wheel_radius": 0.033, "wheel_separation": 0.287,
                             "left_wheel_names": ["wheel_left_joint"],
                             "right_wheel_names": ["wheel_right_joint"]})
    synth = odometry_settings({"wheel_radius": 0.05, "wheel_separation": 0.3})
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        if args.writers:
            bench_writers(tmp, args.writers)
        if args.only_writers:
            return 0
        if args.sizes:
            bench_sizes(tmp, args.sizes, args.slow_max, synth)
        if args.only_sizes:
            return 0
        long_bag = tmp / f"synthetic{args.long}"
        _synthetic(long_bag, args.long)
        bench_bag("OptiOdom run-04 (rosbag2 mcap)",
                  DATA / "optiodom" / "square_231220200029_run-04", optiodom, tmp)
        bench_bag("TurtleBot3 (ROS 1 bag)", DATA / "turtlebot3_sim" / "turtlebot3.bag", tb3, tmp)
        bench_bag("synthetic (rosbag2 mcap)", long_bag, synth, tmp)
        bench_memory(tmp, args.long // 4, synth)
    return 0


if __name__ == "__main__":
    sys.exit(main())
