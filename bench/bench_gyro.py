"""Gyrodometry (issue 18): wheels only vs gyro-aided on a slip scenario, and the CPU cost.

    .venv/bin/python bench/bench_gyro.py [--quick]

Scenario: a 2 m square driven three times (0.3 m/s straights, turns in place at
0.5 rad/s) after standing 5 s; wheels read at 50 Hz, a gyro at 200 Hz with a bias of
0.004 rad/s (not given: the start value is 0 +- 0.005) and white noise of 3e-4
rad/s/sqrt(Hz). Four times per run one wheel (chosen at random) spins 8 rad/s more
than it rolls for 0.4 s on a straight: slip the wheels cannot see. The truth is the
commanded motion itself (constant twists: exact arcs), not any estimator's step.
Everything goes through the node's :class:`ReadingPipeline` (Borenstein and Feng,
"Gyrodometry: A New Method for Combining Data from Gyros and Odometry in Mobile
Robots", ICRA 1996, for the rule).

Modes: wheels only; the IMU's yaw replacing the wheels' (what turtlebot3_node's
``use_imu`` does; here ``slip_threshold_sigmas`` tiny: every step takes the gyro);
gyrodometry without and with the distance from the other wheel (the default).

The simulated TurtleBot3 bag of test/data (fuse tutorials): final error of both modes
against Gazebo's own /odom (``--plot PNG``: the figure in doc/images/gyrodometry.png).

CPU: microseconds per message through the pipeline at 1 kHz JointState alone and
with a 1 kHz Imu beside it (the core's cost); ``--live``: the real ``odometry_node``
over DDS at the same rates, its process's CPU per JointState.
"""

from __future__ import annotations

import argparse
import math
import random
import statistics
import time
from dataclasses import dataclass

from diffdrive_odom.core.estimation.pipeline import ReadingPipeline
from diffdrive_odom.settings.odometry import odometry_settings

R, B = 0.033, 0.16
NAMES = ("left_wheel_joint", "right_wheel_joint")
T0 = 1_000_000_000_000
BIAS, DENSITY = 0.004, 3.0e-4
V, W = 0.3, 0.5


@dataclass(frozen=True)
class Segment:
    v: float
    w: float
    seconds: float


def route() -> list[Segment]:
    segs = [Segment(0.0, 0.0, 5.0)]
    for _ in range(3 * 4):
        segs += [Segment(V, 0.0, 2.0 / V), Segment(0.0, W, (math.pi / 2) / W)]
    return segs


def truth(segs: list[Segment]) -> tuple[float, float, float]:
    x = y = th = 0.0
    for s in segs:
        ds, dth = s.v * s.seconds, s.w * s.seconds
        if dth == 0.0:
            x, y = x + ds * math.cos(th), y + ds * math.sin(th)
        elif ds != 0.0:
            rad = ds / dth
            x += rad * (math.sin(th + dth) - math.sin(th))
            y -= rad * (math.cos(th + dth) - math.cos(th))
        th += dth
    return x, y, th


def state_at(segs: list[Segment], t: float) -> tuple[float, float, float]:
    """(left joint angle, right joint angle, yaw rate) of the commanded motion at ``t``."""
    left = right = 0.0
    for s in segs:
        span = min(t, s.seconds)
        left += (s.v - 0.5 * s.w * B) / R * span
        right += (s.v + 0.5 * s.w * B) / R * span
        if t <= s.seconds:
            return left, right, s.w
        t -= s.seconds
    return left, right, 0.0


def scenario(seed: int, wheel_hz: int = 50, imu_hz: int = 200
             ) -> tuple[list[tuple[int, str, float, float]], tuple[float, float, float]]:
    rng = random.Random(seed)
    segs = route()
    total = sum(s.seconds for s in segs)
    starts, t = [], 0.0
    for s in segs:
        if s.v > 0.0:
            starts.append(t)
        t += s.seconds
    slips = [(t0 + rng.uniform(0.5, 2.0 / V - 1.0), rng.choice((0, 1)))
             for t0 in rng.sample(starts, 4)]

    def extra(t: float, side: int) -> float:
        return sum(8.0 * max(0.0, min(t, a + 0.4) - a) for a, s in slips if s == side)

    events: list[tuple[int, str, float, float]] = []
    for k in range(round(total * wheel_hz) + 1):
        t = k / wheel_hz
        left, right, _ = state_at(segs, t)
        events.append((T0 + round(t * 1e9), "j", left + extra(t, 0), right + extra(t, 1)))
    sigma = DENSITY * math.sqrt(imu_hz)
    for k in range(round(total * imu_hz) + 1):
        t = k / imu_hz
        events.append((T0 + round(t * 1e9), "i", state_at(segs, t)[2] + BIAS
                       + rng.gauss(0.0, sigma), 0.0))
    events.sort()  # an IMU sample ("i") before the wheel reading ("j") of its stamp
    return events, truth(segs)


MODES: dict[str, dict[str, object]] = {
    "wheels only": {"use_imu": False},
    "IMU yaw replaces wheels'": {"use_imu": True, "slip_threshold_sigmas": 1e-12,
                                 "slip_distance_from_other_wheel": False},
    "gyrodometry, mean distance": {"use_imu": True, "slip_distance_from_other_wheel": False},
    "gyrodometry (default)": {"use_imu": True},
}


def run(events: list[tuple[int, str, float, float]], values: dict[str, object]
        ) -> tuple[ReadingPipeline, float]:
    pipe = ReadingPipeline(odometry_settings({"wheel_radius": R, "wheel_separation": B,
                                              "gyro_noise_density": DENSITY, **values}))
    start = time.perf_counter()
    for stamp, kind, a, b in events:
        if kind == "i":
            pipe.feed_imu(stamp, 0.0, 0.0, a)
        else:
            pipe.feed(stamp, NAMES, (a, b))
    return pipe, time.perf_counter() - start


def accuracy(seeds: int) -> None:
    print(f"Slip scenario: 3 x 2 m square, 4 slips of 0.4 s, gyro bias {BIAS} rad/s, "
          f"{seeds} seeds")
    print(f"{'mode':28s} {'pos err mean [m]':>17s} {'max':>7s} {'yaw err mean [rad]':>19s} "
          f"{'max':>7s} {'slip events':>12s}")
    results: dict[str, list[tuple[float, float, int]]] = {m: [] for m in MODES}
    for seed in range(seeds):
        events, (x, y, th) = scenario(seed)
        for mode, values in MODES.items():
            pipe, _ = run(events, values)
            p = pipe.estimator.pose
            g = pipe.stats.gyro
            results[mode].append((math.hypot(p.x - x, p.y - y),
                                  abs(math.remainder(p.theta - th, 2 * math.pi)),
                                  0 if g is None else g.slips.events))
    for mode, rows in results.items():
        pos = [r[0] for r in rows]
        yaw = [r[1] for r in rows]
        ev = sum(r[2] for r in rows) / len(rows)
        print(f"{mode:28s} {sum(pos) / len(pos):17.4f} {max(pos):7.4f} "
              f"{sum(yaw) / len(yaw):19.4f} {max(yaw):7.4f} {ev:12.1f}")


def cpu(seconds: float) -> None:
    segs = route()
    n = round(seconds * 1000)
    joints = []
    for k in range(n):
        left, right, _ = state_at(segs, 5.0 + k / 1000)
        joints.append((T0 + k * 1_000_000, "j", left, right))
    imu = [(T0 + k * 1_000_000, "i", 0.0, 0.0) for k in range(n)]
    both = sorted(joints + imu)
    _, wheels = run(joints, {"use_imu": False})
    # Interleaved, medians: the gyro mode without and with the online geometry estimate.
    plain, online = [], []
    for _ in range(5):
        plain.append(run(both, {"use_imu": True, "online_calibration": "disabled"})[1])
        online.append(run(both, {"use_imu": True, "online_calibration": "monitor"})[1])
    gyro, mon = statistics.median(plain), statistics.median(online)
    print(f"\nCPU through the pipeline, {seconds:g} s of messages at 1 kHz:")
    print(f"  wheels only (1 kHz JointState):          {wheels / n * 1e6:7.1f} us per reading")
    print(f"  gyro-aided (1 kHz JointState + 1 kHz Imu): {gyro / n * 1e6:7.1f} us per reading "
          f"+ its IMU sample ({gyro / wheels:.2f} x)")
    print(f"  gyro-aided + online calibration (monitor): {mon / n * 1e6:7.1f} us per reading "
          f"+ its IMU sample ({mon / gyro:.2f} x gyro-aided; medians of 5 interleaved runs)")


def turtlebot3(plot: str | None) -> None:
    """The simulated TurtleBot3 bag of test/data: final error against Gazebo's /odom."""
    from pathlib import Path

    from rosbags.highlevel import AnyReader

    from diffdrive_odom.tools.bags import bagio, bagreadings
    from diffdrive_odom.tools.replaying.readings import replay_readings
    from diffdrive_odom.tools.replaying.sinks import Published

    bag = Path(__file__).resolve().parent.parent / "test" / "data" / "turtlebot3_sim" / \
        "turtlebot3.bag"
    if not bag.exists():
        print("\n(no test/data/turtlebot3_sim: TurtleBot3 figures skipped)")
        return
    gt = []
    with AnyReader([bag]) as reader:
        for conn, _, raw in reader.messages([c for c in reader.connections
                                             if c.topic == "/odom"]):
            m = reader.deserialize(raw, conn.msgtype)
            q = m.pose.pose.orientation
            gt.append((m.pose.pose.position.x, m.pose.pose.position.y,
                       math.atan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y**2 + q.z**2))))
    x0, y0, t0 = gt[0]
    c, s = math.cos(t0), math.sin(t0)
    truth = [(c * (x - x0) + s * (y - y0), -s * (x - x0) + c * (y - y0), t - t0)
             for x, y, t in gt]
    print("\nSimulated TurtleBot3 bag (its wheels slip), final error against Gazebo's /odom:")
    tracks = {}
    for mode in ("wheels only", "gyrodometry (default)"):
        values = {"wheel_radius": 0.033, "wheel_separation": 0.287,
                  "left_wheel_names": ["wheel_left_joint"],
                  "right_wheel_names": ["wheel_right_joint"], **MODES[mode]}
        out: list[Published] = []
        with bagio.open_bag(bag) as reader:
            items = list(bagreadings.iter_readings(
                reader, "/joint_states", "/imu" if values["use_imu"] else None))
        replay_readings(items, odometry_settings(values), out.append)
        end = out[-1].pose
        x, y, th = truth[-1]
        print(f"  {mode:28s} {math.hypot(end.x - x, end.y - y):.3f} m, "
              f"{abs(math.remainder(end.theta - th, 2 * math.pi)):.4f} rad")
        tracks[mode] = ([p.pose.x for p in out], [p.pose.y for p in out])
    if plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(6, 5))
        ax.plot([p[0] for p in truth], [p[1] for p in truth], "k-", label="Gazebo (truth)")
        for (mode, (xs, ys)), style in zip(tracks.items(), ("r--", "b-"), strict=True):
            ax.plot(xs, ys, style, label=mode)
        ax.set_aspect("equal")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_title("Simulated TurtleBot3 with slipping wheels")
        ax.legend()
        fig.savefig(plot, dpi=90, bbox_inches="tight")
        print(f"  plot: {plot}")


def _cpu_s(pid: int) -> float:
    """utime + stime [s] of a process (fields 14 and 15 of /proc/<pid>/stat)."""
    import os

    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def live(seconds: float) -> None:
    """The real odometry_node over DDS: its CPU per JointState at 1 kHz, wheels only and
    with a 1 kHz Imu beside it (publisher in this process, the node's own /proc time)."""
    import os
    import random as rnd
    import subprocess
    import sys
    from pathlib import Path

    import rclpy
    from rclpy.context import Context
    from sensor_msgs.msg import Imu, JointState

    from diffdrive_odom.wire.conversions import ns_to_stamp

    exe = str(Path(sys.executable).parent / "odometry_node")
    env = {**os.environ, "ROS_DOMAIN_ID": str(rnd.randint(150, 200)),
           "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    os.environ.update({k: env[k] for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")})
    print(f"\nodometry_node over DDS, {seconds:g} s at 1 kHz (CPU of the node's process):")
    ctx = Context()
    rclpy.init(context=ctx)
    try:
        node = rclpy.create_node("bench_gyro_pub", context=ctx)
        js_pub = node.create_publisher(JointState, "joint_states", 100)
        imu_pub = node.create_publisher(Imu, "imu", 100)
        base: float | None = None
        for use_imu in (False, True):
            proc = subprocess.Popen([exe, "--ros-args", "-p", f"wheel_radius:={R}", "-p",
                                     f"wheel_separation:={B}", "-p",
                                     f"use_imu:={str(use_imu).lower()}"],
                                    env=env, stdout=subprocess.DEVNULL,
                                    stderr=subprocess.DEVNULL)
            try:
                deadline = time.monotonic() + 20.0
                while js_pub.get_subscription_count() == 0 or (
                        use_imu and imu_pub.get_subscription_count() == 0):
                    if time.monotonic() > deadline:
                        raise RuntimeError("odometry_node never subscribed")
                    time.sleep(0.05)
                time.sleep(1.0)  # let the node settle after start-up
                js, imu = JointState(), Imu()
                js.name = list(NAMES)
                n = round(seconds * 1000)
                t0 = time.time_ns()
                cpu0 = _cpu_s(proc.pid)
                start = time.monotonic()
                for k in range(n):
                    stamp = t0 + k * 1_000_000
                    if use_imu:
                        ns_to_stamp(stamp, imu.header.stamp)
                        imu.angular_velocity.z = 0.1
                        imu_pub.publish(imu)
                    ns_to_stamp(stamp, js.header.stamp)
                    js.position = [k * 0.01, k * 0.0101]
                    js_pub.publish(js)
                    wait = start + (k + 1) / 1000 - time.monotonic()
                    if wait > 0:
                        time.sleep(wait)
                time.sleep(0.5)  # what is queued gets handled
                used = _cpu_s(proc.pid) - cpu0
            finally:
                proc.terminate()
                proc.wait(timeout=10)
            per = used / n * 1e6
            label = "gyro-aided (+ 1 kHz Imu)" if use_imu else "wheels only"
            ratio = f" ({per / base:.2f} x)" if base else ""
            print(f"  {label:26s} {per:7.1f} us CPU per JointState{ratio}")
            base = base or per
    finally:
        rclpy.shutdown(context=ctx)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="3 seeds, 2 s of CPU timing")
    ap.add_argument("--plot", metavar="PNG", help="plot the TurtleBot3 bag's trajectories")
    ap.add_argument("--live", action="store_true",
                    help="also the real node over DDS at 1 kHz (needs rclpy)")
    args = ap.parse_args()
    accuracy(3 if args.quick else 20)
    turtlebot3(args.plot)
    cpu(2.0 if args.quick else 20.0)
    if args.live:
        live(3.0 if args.quick else 10.0)


if __name__ == "__main__":
    main()
