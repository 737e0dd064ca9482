"""A reference pose stream (a lidar odometry, motion capture, AMCL) from a route's truth.

On its own clock: its own rate and phase, stamps at the true measurement time plus a
constant clock offset and a jitter, arriving ``latency`` (itself jittered) later (a
lidar odometry's processing), in a frame of its own (``map``: the truth turned and
shifted), mounted on the robot where it is (``mount``: off the axle, turned), with
white noise on each pose, an optional dropout and jumps (AMCL
relocalising: the pose off by a fixed amount from then on). :func:`merge` puts its
messages among a ``gyrostreams`` stream in receive-time order. Nothing here calls the
package.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from gyrostreams import T0, Message, Truth

# ('r', receive_ns, stamp_ns, x, y, yaw)
RefMessage = tuple[str, int, int, float, float, float]


@dataclass(frozen=True)
class Reference:
    """How the reference samples the truth (see the module)."""

    hz: float = 30.0
    phase: float = 7.3e-3  # s: its first pose after the wheels' first reading
    stamp_jitter: float = 0.5e-3  # s: uniform +- on each stamp
    stamp_offset: float = -3e-3  # s: its clock against the wheels' (constant)
    latency: float = 0.05  # s: measurement to arrival
    latency_jitter: float = 0.01  # s: uniform +- on each arrival
    position_stddev: float = 0.002  # m, white, per pose
    heading_stddev: float = 0.001  # rad, white, per pose
    frame: tuple[float, float, float] = (3.0, -2.0, 0.7)  # its frame's x, y, yaw in odom's
    mount: tuple[float, float, float] = (0.0, 0.0, 0.0)  # its own frame's x, y, yaw on the robot
    dropout: tuple[float, float] | None = None  # s: silent over this span
    jumps: tuple[tuple[float, float, float, float], ...] = ()  # (t, dx, dy, dyaw) from t on


def reference(tru: Truth, ref: Reference, seconds: float, seed: int = 7) -> list[RefMessage]:
    """The reference's messages over ``seconds`` of the route."""
    rng = np.random.default_rng(seed)
    t = np.arange(ref.phase, seconds, 1.0 / ref.hz)
    if ref.dropout is not None:
        a, b = ref.dropout
        t = t[(t < a) | (t > b)]
    fx, fy, fth = ref.frame
    c, s = math.cos(fth), math.sin(fth)
    out: list[RefMessage] = []
    for tk in t:
        x, y = float(np.interp(tk, tru.t, tru.x)), float(np.interp(tk, tru.t, tru.y))
        th = float(np.interp(tk, tru.t, tru.theta))
        mx, my, myaw = ref.mount  # the point it tracks and the way it faces on the robot
        x, y = x + math.cos(th) * mx - math.sin(th) * my, y + math.sin(th) * mx + math.cos(th) * my
        th += myaw
        for tj, dx, dy, dth in ref.jumps:
            if tk >= tj:
                x, y, th = x + dx, y + dy, th + dth
        n = rng.standard_normal(3)
        mx = fx + c * x - s * y + ref.position_stddev * n[0]
        my = fy + s * x + c * y + ref.position_stddev * n[1]
        yaw = math.remainder(fth + th + ref.heading_stddev * n[2], 2 * math.pi)
        stamp = T0 + round((tk + ref.stamp_offset + rng.uniform(-1, 1) * ref.stamp_jitter)
                           * 1e9)
        late = ref.latency + rng.uniform(-1, 1) * ref.latency_jitter
        out.append(("r", T0 + round((tk + late) * 1e9), stamp, mx, my, yaw))
    return out


def merge(messages: list[Message], refs: list[RefMessage]
          ) -> list[Message | RefMessage]:
    """Both streams in receive-time order, as a node gets them."""
    both: list[Message | RefMessage] = [*messages, *refs]
    both.sort(key=lambda m: (m[1], m[0]))
    return both
