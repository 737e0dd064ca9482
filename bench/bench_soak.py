"""Soak: ``odometry_node`` fed at 1 kHz for minutes, its memory and CPU sampled.

    .venv/bin/python bench/bench_soak.py [--minutes 10] [--rate 1000] [--interval 10]
                                         [--quick]

The same three processes as ``bench_live.py`` (publisher -> the real console script
``odometry_node`` on its default executor -> subscriber, real DDS). Every
``--interval`` seconds the node's resident memory (VmRSS of /proc/<pid>/status) and
CPU time (/proc/<pid>/stat) are read. Growth is judged between the first and the last
fifth of the run (after a warm-up interval): a leak shows as RSS rising with the
messages, a slowdown as CPU per message rising.
"""

from __future__ import annotations

import argparse
import itertools
import os
import statistics
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_live

# The subscriber waits this long after the last message before it reports: long
# enough that a stall somewhere shows as lost messages, not as the end of the run.
IDLE_END_S = 5.0
RSS_SLACK_MB = 2.0  # allocator noise: more growth than this between the fifths is a leak
CPU_SLACK = 0.15  # relative; the machine's own noise


def rss_mb(pid: int) -> float:
    """Resident set size of a process [MB] (VmRSS in /proc/<pid>/status)."""
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    raise RuntimeError(f"no VmRSS for {pid}")


def soak(seconds: float, rate: int, interval: float) -> bool:
    """Run the soak and print its table; True when neither memory nor CPU grew."""
    with bench_live.systems(("events",), ("node",)) as (system,):
        time.sleep(2.0)
        out: list[bench_live.Trial] = []
        feeder = threading.Thread(
            target=lambda: out.append(bench_live.trial(system, rate, seconds, time.time_ns(),
                                                       idle_end=IDLE_END_S)))
        feeder.start()
        # The trial waits for discovery and warms up before it counts: start the
        # clock at the node's first busy interval.
        cpu0 = bench_live.cpu_seconds(system.pid)
        while feeder.is_alive() and bench_live.cpu_seconds(system.pid) - cpu0 < 0.05:
            time.sleep(0.1)
        samples: list[tuple[float, float, float]] = []  # (t, RSS MB, CPU s)
        # Sampled while fed only: the subscriber's idle wait at the end would otherwise
        # enter the last fifth as near-zero CPU and hide a slowdown.
        t0 = time.monotonic()
        while feeder.is_alive() and time.monotonic() - t0 <= seconds + 0.5 * interval:
            samples.append((time.monotonic() - t0, rss_mb(system.pid),
                            bench_live.cpu_seconds(system.pid)))
            feeder.join(interval)
        feeder.join()
    trial = out[0] if out else None
    return report(samples, rate, trial)


def report(samples: list[tuple[float, float, float]], rate: int,
           trial: bench_live.Trial | None) -> bool:
    print(f"Soak: odometry_node (EventsExecutor) fed at {rate} Hz")
    print(f"{'t s':>7s} {'RSS MB':>8s} {'CPU %':>7s} {'CPU us/msg':>11s}")
    per_msg: list[tuple[float, float]] = []  # (t, us per message over the interval)
    for (ta, _, ca), (tb, mb, cb) in itertools.pairwise(samples):
        busy = (cb - ca) / (tb - ta)
        us = busy / rate * 1e6
        per_msg.append((tb, us))
        print(f"{tb:7.0f} {mb:8.1f} {100 * busy:7.1f} {us:11.0f}")
    if len(per_msg) < 5:
        print("too short to judge growth")
        return True
    fifth = max(1, len(per_msg) // 5)
    rss = [r for _, r, _ in samples[1:]]
    rss_first, rss_last = statistics.median(rss[:fifth]), statistics.median(rss[-fifth:])
    cpu_first = statistics.median(u for _, u in per_msg[1:fifth + 1])
    cpu_last = statistics.median(u for _, u in per_msg[-fifth:])
    if trial is not None:
        print(f"\nmessages: {trial.sent} sent, {trial.sent - trial.received} lost; "
              f"p50 {trial.p50_ms:.2f} ms, p99 {trial.p99_ms:.2f} ms; "
              f"CPU {trial.cpu_us_per_msg:.0f} us/msg over the whole run")
        print(f"longest run of lost messages: {trial.max_lost_gap_ms:.0f} ms of stamps; "
              f"longest pause in arrivals: {trial.max_pause_ms:.0f} ms, "
              f"{trial.pause_at_s:.0f} s in")
    print(f"RSS: {rss_first:.1f} MB in the first fifth, {rss_last:.1f} MB in the last "
          f"({rss_last - rss_first:+.1f} MB)")
    print(f"CPU: {cpu_first:.0f} us/msg in the first fifth, {cpu_last:.0f} in the last "
          f"({cpu_last / cpu_first:.2f}x)")
    flat = (rss_last - rss_first <= RSS_SLACK_MB
            and cpu_last <= (1 + CPU_SLACK) * cpu_first)
    print("verdict: " + ("no growth" if flat else "GROWTH"))
    return flat


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--rate", type=int, default=1000)
    ap.add_argument("--interval", type=float, default=10.0, help="seconds between samples")
    ap.add_argument("--quick", action="store_true", help="10 s, a sample every second (smoke test)")
    args = ap.parse_args(argv)
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    seconds, interval = (10.0, 1.0) if args.quick else (60.0 * args.minutes, args.interval)
    soak(seconds, args.rate, interval)
    return 0


if __name__ == "__main__":
    sys.exit(main())
