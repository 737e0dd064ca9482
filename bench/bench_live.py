"""Live throughput of ``odometry_node`` next to a bare rclpy relay, over real DDS.

    .venv/bin/python bench/bench_live.py [--quick] [--rates 100,250,...] [--seconds 3]
                                         [--profile single|events]

Three processes per trial: a publisher (JointState at a fixed rate, header stamp =
send time), the system under test, and a subscriber (counts Odometry, latency from
the header stamp to its receive time). Systems under test, all started once and fed
in turn at every rate (interleaved, so machine noise hits all of them alike):

- node:  the real console script ``.venv/bin/odometry_node``,
- relay: a bare rclpy node in this file, JointState in, nav_msgs/Odometry out with
  the same header and no math, on the node's QoS (ros.qos.SENSOR_IN_QOS /
  RELIABLE_OUT_QOS),

each with rclpy's EventsExecutor (the default) and the SingleThreadedExecutor
(``DIFFDRIVE_ODOM_EXECUTOR=single``), both built by ros.runtime.make_executor.
Rates rise until every system lost over 1 % of them. CPU per message is the user + system
time of the system's process (/proc/<pid>/stat) while a trial ran, over messages
sent. ``--profile`` runs the node in this process under cProfile at 1 kHz instead and
prints where its time goes.
"""

from __future__ import annotations

import argparse
import cProfile
import itertools
import json
import math
import os
import pstats
import select
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass
from pathlib import Path

import rclpy
from nav_msgs.msg import Odometry
from rclpy.node import Node
from sensor_msgs.msg import JointState

from diffdrive_odom.ros.qos import RELIABLE_OUT_QOS, SENSOR_IN_QOS
from diffdrive_odom.ros.runtime import EXECUTOR_ENV, EXECUTOR_KINDS, make_executor
from diffdrive_odom.tools.cmdline import process
from diffdrive_odom.wire.conversions import ns_to_stamp, stamp_to_ns

BIN = Path(sys.executable).parent
NODE_PARAMS = ["-p", "wheel_radius:=0.05", "-p", "wheel_separation:=0.3"]
WHEEL_SPEEDS = (4.0, 6.0)  # rad/s of the published joints: well under max_wheel_speed
IDLE_END_S = 0.5  # the subscriber stops this long after the last message
CLK_TCK = os.sysconf("SC_CLK_TCK")
RATES = (100, 250, 500, 1000, 2000, 3000)
KINDS = EXECUTOR_KINDS


# --- the three roles (child processes) -----------------------------------------------

def role_relay(in_topic: str, out_topic: str, kind: str) -> int:
    """JointState -> Odometry with the same header: the rclpy floor the node stands on."""
    rclpy.init()
    executor, spin = make_executor(kind)
    node = Node("bench_relay")
    pub = node.create_publisher(Odometry, out_topic, RELIABLE_OUT_QOS)

    def relay(msg: JointState) -> None:
        out = Odometry()
        out.header = msg.header
        out.child_frame_id = "base_link"
        pub.publish(out)

    node.create_subscription(JointState, in_topic, relay, SENSOR_IN_QOS)
    executor.add_node(node)
    try:
        spin(lambda: False)
    except (KeyboardInterrupt, rclpy.executors.ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


def _wait(cond: Callable[[], bool], timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(0.02)
    return False


def role_pub(topic: str, rate: float, count: int, base_ns: int) -> int:
    """Waits for the system's subscription; on ``warm`` publishes at 20 Hz until ``go``
    (DDS matching finishes on both sides), then publishes ``count`` at ``rate``.

    Joint positions are speed x (stamp - base), one base for the whole run, so the
    node sees one steady motion across trials and warm-up (never a jump it would
    re-anchor on).
    """
    rclpy.init()
    node = Node("bench_pub")
    pub = node.create_publisher(JointState, topic, SENSOR_IN_QOS)
    if not _wait(lambda: pub.get_subscription_count() > 0, 30.0):
        print("no subscriber", flush=True)
        return 1
    print("ready", flush=True)
    msg = JointState()
    msg.name = ["left_wheel_joint", "right_wheel_joint"]

    def send() -> int:
        ns = time.time_ns()
        msg.header.stamp = ns_to_stamp(ns, msg.header.stamp)
        t = (ns - base_ns) / 1e9
        msg.position = [WHEEL_SPEEDS[0] * t, WHEEL_SPEEDS[1] * t]
        pub.publish(msg)
        return ns

    sys.stdin.readline()  # "warm"
    while not select.select([sys.stdin], [], [], 0.05)[0]:
        send()
    sys.stdin.readline()  # "go"
    period = 1e9 / rate
    t0 = time.monotonic_ns()
    start_ns = 0
    for k in range(count):
        due = t0 + k * period
        while (now := time.monotonic_ns()) < due:
            if due - now > 200_000:
                time.sleep((due - now - 100_000) / 1e9)
        ns = send()
        start_ns = start_ns or ns
    elapsed = (time.monotonic_ns() - t0) / 1e9
    print(json.dumps({"sent": count, "elapsed": elapsed, "start_ns": start_ns}), flush=True)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


def role_sub(topic: str, idle_end: float = IDLE_END_S, longest: float = 120.0) -> int:
    """Prints ``warm`` at the first Odometry, then, once messages stop for a while,
    one JSON line of every message's stamp and stamp-to-receive latency."""
    rclpy.init()
    executor, _ = make_executor("events")
    node = Node("bench_sub")
    stamps: list[int] = []
    latencies: list[int] = []
    last = [0.0]

    def on_odom(msg: Odometry) -> None:
        stamp = stamp_to_ns(msg.header.stamp)
        latencies.append(time.time_ns() - stamp)
        stamps.append(stamp)
        last[0] = time.monotonic()
        if len(stamps) == 1:
            print("warm", flush=True)

    sub = node.create_subscription(Odometry, topic, on_odom, RELIABLE_OUT_QOS)
    executor.add_node(node)
    if not _wait(lambda: sub.get_publisher_count() > 0, 30.0):
        print("no publisher", flush=True)
        return 1
    print("ready", flush=True)
    deadline = time.monotonic() + longest
    while time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)
        if stamps and time.monotonic() - last[0] > idle_end:
            break
    print(json.dumps({"stamps": stamps, "latencies": latencies}), flush=True)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


# --- the orchestrator ------------------------------------------------------------------

@dataclass(frozen=True)
class System:
    label: str
    pid: int
    in_topic: str
    out_topic: str


@dataclass(frozen=True)
class Trial:
    rate: int
    sent: int
    achieved_hz: float
    received: int
    p50_ms: float
    p99_ms: float
    cpu_us_per_msg: float
    # The longest run of lost messages (stamp gap between two received ones) and the
    # longest pause in arrivals, with when it began (s after the first measured one).
    max_lost_gap_ms: float = 0.0
    max_pause_ms: float = 0.0
    pause_at_s: float = 0.0

    @property
    def lossless(self) -> bool:
        return self.received == self.sent

    @property
    def saturated(self) -> bool:
        return self.received < 0.99 * self.sent


def cpu_seconds(pid: int) -> float:
    """utime + stime of a process (fields 14 and 15 of /proc/<pid>/stat)."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLK_TCK


def _child(args: list[str], env: dict[str, str] | None = None) -> subprocess.Popen[str]:
    return subprocess.Popen(args, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, text=True,
                            env={**os.environ, **(env or {})})


def _line(proc: subprocess.Popen[str], timeout: float) -> str:
    assert proc.stdout is not None
    ready, _, _ = select.select([proc.stdout], [], [], timeout)
    if not ready:
        raise TimeoutError(f"no answer from {proc.args!r}")
    return proc.stdout.readline().strip()


def _me(*args: str) -> list[str]:
    return [sys.executable, str(Path(__file__).resolve()), *args]


def trial(system: System, rate: int, seconds: float, base_ns: int,
          idle_end: float = IDLE_END_S) -> Trial:
    """One publisher -> system -> subscriber run; CPU of the system over the run.

    Warm-up messages flow until the subscriber has heard one, so DDS matching is done
    before the measured messages (stamped from ``start_ns`` on) are sent.
    """
    count = max(1, round(rate * seconds))
    sub = _child(_me("--role", "sub", "--topic", system.out_topic,
                     "--idle-end", str(idle_end), "--longest", str(seconds + 60.0)))
    pub = _child(_me("--role", "pub", "--topic", system.in_topic, "--rate", str(rate),
                     "--count", str(count), "--base-ns", str(base_ns)))
    try:
        for role, proc in (("subscriber", sub), ("publisher", pub)):
            answer = _line(proc, 60.0)
            if answer != "ready":
                raise RuntimeError(f"{system.label}: {role} said {answer!r}")
        _say(pub, "warm")
        if (answer := _line(sub, 60.0)) != "warm":
            raise RuntimeError(f"{system.label}: subscriber said {answer!r}")
        time.sleep(0.3)
        cpu0 = cpu_seconds(system.pid)
        _say(pub, "go")
        sent = json.loads(_line(pub, 60.0 + 2 * seconds))
        got = json.loads(_line(sub, 60.0))
        cpu1 = cpu_seconds(system.pid)
    finally:
        process.stop(pub, timeout=10)
        process.stop(sub, timeout=10)
    measured = [(stamp, ns) for stamp, ns in zip(got["stamps"], got["latencies"], strict=True)
                if stamp >= sent["start_ns"]]
    lat = sorted(ns for _, ns in measured)
    n = len(lat)
    achieved = (sent["sent"] - 1) / sent["elapsed"] if sent["elapsed"] > 0 else float(rate)
    lost_gap = max((b[0] - a[0] for a, b in itertools.pairwise(measured)), default=0)
    arrivals = [stamp + ns for stamp, ns in measured]
    pause, at = max(((b - a, a) for a, b in itertools.pairwise(arrivals)), default=(0, 0))
    return Trial(rate, sent["sent"], achieved, n,
                 lat[n // 2] / 1e6 if n else math.nan,
                 lat[min(n - 1, int(0.99 * n))] / 1e6 if n else math.nan,
                 (cpu1 - cpu0) / sent["sent"] * 1e6,
                 lost_gap / 1e6, pause / 1e6, (at - arrivals[0]) / 1e9 if arrivals else 0.0)


def _say(proc: subprocess.Popen[str], word: str) -> None:
    assert proc.stdin is not None
    proc.stdin.write(word + "\n")
    proc.stdin.flush()


@contextmanager
def systems(kinds: tuple[str, ...],
            whats: tuple[str, ...] = ("node", "relay")) -> Iterator[list[System]]:
    """Start the node and the relay once per executor kind; stop them at the end."""
    prefix = f"/bench_live_{os.getpid()}"
    with ExitStack() as stack:
        started: list[System] = []
        for kind in kinds:
            for what in whats:
                base = f"{prefix}/{what}_{kind}"
                in_topic, out_topic = f"{base}/joint_states", f"{base}/odom"
                if what == "node":
                    args = [str(BIN / "odometry_node"), "--ros-args", *NODE_PARAMS,
                            "-r", f"joint_states:={in_topic}", "-r", f"odom:={out_topic}",
                            "-r", f"__node:=bench_odometry_{kind}"]
                else:
                    args = _me("--role", "relay", "--executor", kind,
                               "--topic", in_topic, "--out", out_topic)
                proc = _child(args, {EXECUTOR_ENV: kind})
                stack.callback(process.stop, proc, timeout=10)
                started.append(System(f"{what} {kind}", proc.pid, in_topic, out_topic))
        yield started


def run_bench(rates: tuple[int, ...], seconds: float, kinds: tuple[str, ...]) -> None:
    base_ns = time.time_ns()
    results: dict[str, list[Trial]] = {}
    with systems(kinds) as syss:
        results = {s.label: [] for s in syss}
        live = list(syss)
        for i, rate in enumerate(rates):
            if not live:
                break
            # Rotate the order each rate so no system always runs first.
            order = live[i % len(live):] + live[:i % len(live)]
            for s in order:
                results[s.label].append(trial(s, rate, seconds, base_ns))
            # A system climbs until it loses over 1 %: on a loaded machine a stray drop
            # at a low rate says nothing about its capacity.
            live = [s for s in live if not results[s.label][-1].saturated]
    print_table(results, seconds)


def print_table(results: dict[str, list[Trial]], seconds: float) -> None:
    print(f"Live: publisher -> system -> subscriber, {seconds:g} s per rate, interleaved")
    head = (f"{'system':14s} {'rate Hz':>7s} {'sent/s':>8s} {'lost':>6s} {'p50 ms':>7s}"
            f" {'p99 ms':>7s} {'CPU us/msg':>10s}")
    print(head)
    print("-" * len(head))
    for label, trials in results.items():
        for t in trials:
            lost = t.sent - t.received
            print(f"{label:14s} {t.rate:7d} {t.achieved_hz:8.0f} {lost:6d} {t.p50_ms:7.2f}"
                  f" {t.p99_ms:7.2f} {t.cpu_us_per_msg:10.0f}")
    print()
    print(f"{'system':14s} {'highest loss-free Hz':>20s} {'first > 1 % lost Hz':>20s}")
    for label, trials in results.items():
        ok = max((t.rate for t in trials if t.lossless), default=0)
        worst = next((str(t.rate) for t in trials if t.saturated), "-")
        print(f"{label:14s} {ok:20d} {worst:>20s}")
    print()
    print("Ratios node / relay at each rate both ran (same executor):")
    print(f"{'executor':9s} {'rate Hz':>7s} {'p50':>6s} {'p99':>6s} {'CPU/msg':>8s}")
    for kind in KINDS:
        node, relay = results.get(f"node {kind}"), results.get(f"relay {kind}")
        if not node or not relay:
            continue
        for a, b in zip(node, relay, strict=False):
            print(f"{kind:9s} {a.rate:7d} {a.p50_ms / b.p50_ms:6.2f} {a.p99_ms / b.p99_ms:6.2f}"
                  f" {_ratio(a.cpu_us_per_msg, b.cpu_us_per_msg):>8s}")
    node, relay = results.get("node events"), results.get("relay single")
    if node and relay:
        print("\nThe goal: the node on its default executor (events) / the relay on rclpy's"
              " default (single):")
        for a, b in zip(node, relay, strict=False):
            print(f"  {a.rate:5d} Hz: CPU/msg {_ratio(a.cpu_us_per_msg, b.cpu_us_per_msg)}, "
                  f"p50 {a.p50_ms / b.p50_ms:.2f}")
    if all(f"node {k}" in results for k in KINDS):
        print("\nRatios events / single executor (node):")
        for a, b in zip(results["node events"], results["node single"], strict=False):
            print(f"  {a.rate:5d} Hz: CPU/msg {_ratio(a.cpu_us_per_msg, b.cpu_us_per_msg)}, "
                  f"p50 {a.p50_ms / b.p50_ms:.2f}")


def _ratio(a: float, b: float) -> str:
    return f"{a / b:.2f}" if b > 0 else "n/a"


def profile(kind: str, rate: int, seconds: float, top: int) -> None:
    """The node in this process under cProfile while a publisher feeds it at ``rate``."""
    from diffdrive_odom.ros.odometry_node import OdometryNode

    prefix = f"/bench_live_{os.getpid()}/profile"
    rclpy.init(args=["bench", "--ros-args", *NODE_PARAMS,
                     "-r", f"joint_states:={prefix}/joint_states", "-r", f"odom:={prefix}/odom"])
    executor, _ = make_executor(kind)
    node = OdometryNode()
    executor.add_node(node)
    system = System(f"node {kind} (in process)", os.getpid(),
                    f"{prefix}/joint_states", f"{prefix}/odom")
    out: list[Trial] = []
    worker = threading.Thread(
        target=lambda: out.append(trial(system, rate, seconds, time.time_ns())))
    prof = cProfile.Profile()
    worker.start()
    prof.enable()
    while worker.is_alive():
        executor.spin_once(timeout_sec=0.05)
    prof.disable()
    worker.join()
    node.destroy_node()
    rclpy.try_shutdown()
    if out:
        t = out[0]
        print(f"profile: {t.sent} messages at {rate} Hz, {t.received} received, "
              f"{t.cpu_us_per_msg:.0f} us CPU/msg (this process, profiler included)")
    # Wall time: rclpy's wait() is mostly idle blocking, not CPU.
    stats = pstats.Stats(prof)
    stats.sort_stats("tottime").print_stats(top)
    stats.sort_stats("cumulative").print_stats(r"diffdrive_odom|executors\.py", top)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--role", choices=("bench", "relay", "pub", "sub"), default="bench")
    ap.add_argument("--topic", default="joint_states")
    ap.add_argument("--out", default="odom")
    ap.add_argument("--executor", choices=KINDS, default="single")
    ap.add_argument("--rate", type=float, default=100.0)
    ap.add_argument("--count", type=int, default=100)
    ap.add_argument("--base-ns", type=int, default=0)
    ap.add_argument("--idle-end", type=float, default=IDLE_END_S,
                    help="(sub role) stop this long after the last message")
    ap.add_argument("--longest", type=float, default=120.0,
                    help="(sub role) stop listening after this many seconds in any case")
    ap.add_argument("--quick", action="store_true", help="100 Hz only, short trials (smoke test)")
    ap.add_argument("--rates", help="comma-separated rates in Hz")
    ap.add_argument("--seconds", type=float, help="per rate (default 3, --quick 0.5)")
    ap.add_argument("--profile", choices=KINDS, help="profile the node in process instead")
    args = ap.parse_args(argv)
    if args.role == "relay":
        return role_relay(args.topic, args.out, args.executor)
    if args.role == "pub":
        return role_pub(args.topic, args.rate, args.count, args.base_ns)
    if args.role == "sub":
        return role_sub(args.topic, args.idle_end, args.longest)
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    rates = (tuple(int(r) for r in args.rates.split(",")) if args.rates
             else (100,) if args.quick else RATES)
    seconds = args.seconds if args.seconds is not None else 0.5 if args.quick else 3.0
    if args.profile:
        profile(args.profile, rates[-1] if args.rates else 1000, seconds, 25)
        return 0
    run_bench(rates, seconds, KINDS)
    return 0


if __name__ == "__main__":
    sys.exit(main())
