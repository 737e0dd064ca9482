"""Online calibration with a reference pose (issue 25 items 4-5): Monte Carlo over seeds.

    .venv/bin/python bench/bench_online_scale.py [--seeds N] [--quick]

The core's simulated base (:class:`~diffdrive_odom.core.sim.model.DiffDriveSim`) drives
the issue's mixed route twice (about 52 m, turns both ways, 150 s): true right radius
+0.5 % and track +1 % (the mean radius so +0.25 %), random slip of 1 mm after 1 m on
each side (what the default ``wheel_noise_k`` 1e-6 m models) and four scripted slips, a
motor lag of 50 ms. Its gyro: scale factor 1.01 (reads 1 % too much), bias 0.3 deg/s,
white noise 3e-4 rad/s/sqrt(Hz) (the sim's: ``gyro_scale``, ``gyro_bias``,
``gyro_noise_density``), at 173 Hz on its own phase, stamps jittered 0.5 ms, arriving 3
+- 2 ms late; each sample the mean rate over its own period (the sim's ``gyro()``: an
integrating gyro, the mean since its last read).
Wheels at 50 Hz, arriving 1 ms late. A reference pose at 20 Hz in a frame of its own
(turned and shifted), white noise 5 mm / 3 mrad, arriving 80 ms late. Every message goes
through the node's ReadingPipeline in receive order. Truth in closed form from the sim's
geometry: ddc's multipliers ``r_L/R``, ``r_R/R``, ``b/B``, the mean radius ``(r_L +
r_R)/2R``, the gyro scale 1.01.

Prints per seed the errors and their sigmas, then the coverage of the sigma (the
fraction within 1 and 2 sigma, and a normal's 68 / 95 %), and the warnings of a node
configured with the TRUE geometry without and with the reference (without it the gyro's
scale factor maps into the ratios: a false WARN; with it the ratios are corrected).
"""

from __future__ import annotations

import argparse
import functools
import heapq
import math
import statistics
import sys
from pathlib import Path

import numpy as np

from diffdrive_odom.core.estimation.online.online_estimate import OnlineEstimate
from diffdrive_odom.core.estimation.pipeline import ReadingPipeline
from diffdrive_odom.core.geometry.kinematics import Geometry
from diffdrive_odom.core.sim.model import DiffDriveSim, SimConfig, SlipEvent
from diffdrive_odom.settings.odometry import odometry_settings

sys.path.insert(0, str(Path(__file__).resolve().parent))
from interleaved import interleaved, ratio_rows

R, B = 0.05, 0.3
TRUE = (R, R * 1.005, B * 1.01)  # left, right radius, separation
GYRO_SCALE = 1.01
BIAS, DENSITY = math.radians(0.3), 3e-4
WHEEL_HZ, IMU_HZ, REF_HZ = 50.0, 173.0, 20.0
REF_SIGMA = (0.005, 0.003)
# The route of test/gyrostreams.py: (seconds, v, w), driven twice after 3 s still.
SEGMENTS = ((8.0, 0.4, 0.0), (7.0, 0.3, 0.4), (10.0, 0.5, 0.0), (6.0, 0.3, -0.5),
            (9.0, 0.4, 0.0), (8.0, 0.2, 0.6), (10.0, 0.5, 0.0), (6.0, 0.3, -0.3),
            (6.0, 0.4, 0.0)) * 2
SLIPS = (SlipEvent("right", 13.0, 0.5, 12.0), SlipEvent("left", 27.0, 0.4, 15.0),
         SlipEvent("right", 45.0, 0.5, 10.0), SlipEvent("left", 63.0, 0.3, 20.0))
NAMES = ("left_wheel_joint", "right_wheel_joint")
T0 = 1_700_000_000_000_000_000


def messages(seed: int) -> list[tuple[int, str, int, tuple[float, ...]]]:
    """(receive ns, kind, stamp ns, values) of one run, in receive order."""
    rng = np.random.default_rng([seed, 99])
    rl, rr, b = TRUE
    sim = DiffDriveSim(SimConfig(
        Geometry(R, b, left_wheel_radius_multiplier=rl / R, right_wheel_radius_multiplier=rr / R),
        motor_time_constant=0.05, slip_stddev=0.001, command_timeout=0.0, seed=seed,
        slip_events=SLIPS, gyro_bias=BIAS, gyro_noise_density=DENSITY, gyro_scale=GYRO_SCALE))
    schedule, t = [], 3.0
    for seconds, v, w in SEGMENTS:  # commanded with the nominal geometry
        schedule.append((t, ((v - 0.5 * B * w) / R, (v + 0.5 * B * w) / R)))
        t += seconds
    end = t + 3.0
    schedule.append((t, (0.0, 0.0)))
    events: list[tuple[float, str]] = []
    for hz, kind, phase in ((WHEEL_HZ, "j", 0.0), (IMU_HZ, "i", 1.7e-3), (REF_HZ, "r", 7.3e-3)):
        events += [(phase + k / hz, kind) for k in range(int((end - phase) * hz))]
    events.sort()
    frame = (3.0, -2.0, 0.7)
    c, s = math.cos(frame[2]), math.sin(frame[2])
    out: list[tuple[int, str, int, tuple[float, ...]]] = []
    k_cmd = 0
    last_gyro = 0  # sim ns of the previous gyro read: a sample is the mean rate since
    for te, kind in events:
        while k_cmd < len(schedule) and schedule[k_cmd][0] <= te:
            sim.command(schedule[k_cmd][1])
            k_cmd += 1
        sim.advance(round(te * 1e9) - sim.time_ns)
        ns = T0 + sim.time_ns
        if kind == "j":
            out.append((ns + 1_000_000, "j", ns, tuple(float(a) for a in sim.joint_angles)))
        elif kind == "i":  # an integrating gyro: the mean rate over its own period,
            # stamped at the period's middle (as sim_node does), with jitter
            mid = T0 + (last_gyro + sim.time_ns) // 2
            last_gyro = sim.time_ns
            stamp = mid + round(rng.uniform(-0.5e-3, 0.5e-3) * 1e9)
            late = round((3e-3 + rng.uniform(-2e-3, 2e-3)) * 1e9)
            out.append((ns + late, "i", stamp, (float(sim.gyro(IMU_HZ)),)))
        else:
            p, n = sim.pose, rng.standard_normal(3)
            x = frame[0] + c * p.x - s * p.y + REF_SIGMA[0] * n[0]
            y = frame[1] + s * p.x + c * p.y + REF_SIGMA[0] * n[1]
            yaw = frame[2] + p.theta + REF_SIGMA[1] * n[2]
            # Python floats, as the node's decoders give them (numpy scalars would make
            # every step's arithmetic numpy's, several times slower)
            out.append((ns + 80_000_000, "r", ns, (float(x), float(y), float(yaw))))
    heapq.heapify(out)
    return [heapq.heappop(out) for _ in range(len(out))]


Message = tuple[int, str, int, tuple[float, ...]]


def pipeline(reference: bool, configured_true: bool = False, mode: str = "monitor"
             ) -> ReadingPipeline:
    """The node's pipeline with the gyro and ``online_calibration: mode``.

    ``configured_true``: the node is given the true geometry (a warning is then false);
    ``mode``: ``online_calibration`` (``disabled``: the gyro mode alone, no estimate).
    """
    rl, rr, b = TRUE if configured_true else (R, R, B)
    values: dict[str, object] = {"wheel_radius": R, "wheel_separation": b, "use_imu": True,
                                 "left_wheel_radius_multiplier": rl / R,
                                 "right_wheel_radius_multiplier": rr / R,
                                 "online_calibration": mode}
    if reference:
        values.update({"online_calibration_reference_topic": "/reference",
                       "online_calibration_reference_position_stddev": REF_SIGMA[0],
                       "online_calibration_reference_heading_stddev": REF_SIGMA[1]})
    return ReadingPipeline(odometry_settings(values))


def feed(pipe: ReadingPipeline, msg: Message) -> bool:
    """One message as the node gives it; True if it raised the online estimate's warning."""
    rx, kind, stamp, v = msg
    if kind == "i":
        pipe.feed_imu(stamp, 0.0, 0.0, v[0], receive_ns=rx)
    elif kind == "r":
        pipe.feed_reference(stamp, *v)
    else:
        return pipe.feed(stamp, NAMES, v, receive_ns=rx).warning.startswith(
            "online calibration")
    return False


def run(msgs: list[Message], reference: bool, configured_true: bool = False,
        mode: str = "monitor") -> tuple[OnlineEstimate | None, int]:
    """The final estimate and the number of warnings the node would have logged."""
    pipe = pipeline(reference, configured_true, mode)
    warnings = sum(feed(pipe, m) for m in msgs)
    return pipe.stats.online, warnings


def cpu(msgs: list[Message], rounds: int) -> None:
    """Time per wheel reading (its IMU samples and reference poses included).

    Against the gyro mode without online calibration (issue 25: within 1.3x), the four
    cases interleaved message by message (:mod:`interleaved`); the reference poses are
    fed in every case (unused without one).
    """
    wheels = sum(m[1] == "j" for m in msgs)
    cases = {"disabled": (False, "disabled"), "monitor": (False, "monitor"),
             "monitor + reference": (True, "monitor"), "apply + reference": (True, "apply")}
    times = interleaved({k: functools.partial(pipeline, ref, mode=mode)
                         for k, (ref, mode) in cases.items()}, feed, msgs, rounds)
    print(f"\nTime per wheel reading ({rounds} rounds, the cases interleaved message by "
          "message), use_imu, online_calibration:")
    print("\n".join(ratio_rows(times, "disabled", wheels)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=12)
    ap.add_argument("--quick", action="store_true", help="3 seeds, 1 CPU run")
    args = ap.parse_args()
    seeds = 3 if args.quick else args.seeds
    rl, rr, b = TRUE
    want = {"left": rl / R, "right": rr / R, "separation": b / B,
            "mean radius": (rl + rr) / (2 * R), "gyro scale": GYRO_SCALE}
    print(f"truth: left {want['left']:.5f}, right {want['right']:.5f}, separation "
          f"{want['separation']:.5f}, mean radius {want['mean radius']:.5f}, gyro scale "
          f"{GYRO_SCALE:.5f}")
    print("seed  separation err (sigma)   mean radius err (sigma)   gyro scale err (sigma)"
          "   windows  excluded             false warns (no ref / ref)")
    z: dict[str, list[float]] = {k: [] for k in want}
    errs: dict[str, list[float]] = {k: [] for k in want}
    sigmas: dict[str, list[float]] = {k: [] for k in want}
    for seed in range(seeds):
        msgs = messages(seed)
        warned = run(msgs, False, configured_true=True)[1]
        warned_ref = run(msgs, True, configured_true=True)[1]
        est = run(msgs, True)[0]
        assert est is not None
        sc = est.scale
        assert sc is not None
        got = {"left": (sc.multipliers[0], sc.stddevs[0]),
               "right": (sc.multipliers[1], sc.stddevs[1]),
               "separation": (sc.multipliers[2], sc.stddevs[2]),
               "mean radius": sc.mean_radius, "gyro scale": sc.gyro_scale}
        for k, (value, sigma) in got.items():
            errs[k].append(value - want[k])
            sigmas[k].append(sigma)
            z[k].append((value - want[k]) / sigma)
        cells = "   ".join(f"{(got[k][0] - want[k]) * 100:+.3f} % ({got[k][1] * 100:.3f} %)"
                           for k in ("separation", "mean radius", "gyro scale"))
        ex = ", ".join(f"{k} {v}" for k, v in sorted(sc.excluded.items()))
        print(f"{seed:4d}  {cells}   {sc.windows:7d}  {ex:19s}  {warned} / {warned_ref}"
              + ("" if sc.determined else "  (not determined)"))
    print("\ncoverage of the printed sigma over seeds (a normal: 68 % within 1, 95 % within 2):")
    for k in want:
        within1 = sum(abs(v) < 1 for v in z[k]) / seeds
        within2 = sum(abs(v) < 2 for v in z[k]) / seeds
        rms = math.sqrt(statistics.fmean(e * e for e in errs[k]))
        print(f"  {k:12s} within 1 sigma {within1:4.0%}, within 2 {within2:4.0%}; RMS error "
              f"{rms * 100:.3f} %, median sigma {statistics.median(sigmas[k]) * 100:.3f} %, "
              f"worst |error| {max(abs(e) for e in errs[k]) * 100:.3f} %")
    cpu(messages(0), 1 if args.quick else 7)


if __name__ == "__main__":
    main()
