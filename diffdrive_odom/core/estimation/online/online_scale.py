"""The scale of the online geometry estimate, from a reference pose (a lidar odometry, AMCL).

The gyro fixes the two ratios ``u = r_R/b``, ``v = r_L/b`` but not the scale: the mean
radius (so ``b`` itself) is not observable from rotation, and a gyro whose scale factor
is ``s`` reads ``s`` times the turn, so its ratios are ``s u``, ``s v``. A reference
pose (``nav_msgs/Odometry`` or ``geometry_msgs/PoseStamped``) completes them, as the
second step of Censi, Franchi, Marchionni and Oriolo, "Simultaneous calibration of
odometry and sensor parameters for mobile robots" (IEEE T-RO 2013) does with a scan
matcher. Over a window between two reference poses:

- **distance**: the reference's displacement ``|dp|`` against the chord the wheels
  claim with the gyro's ratios at the configured mean radius ``m`` (the wheels'
  arcs ``r'_R dphi_R``, ``r'_L dphi_L`` laid along the gyro's heading): ``|dp| = k h``
  gives ``k``, the true mean radius over ``m`` (a scalar Kalman filter). Chord
  lengths do not depend on the frame, so the reference's (``map``, ``world``) is
  never aligned with ``odom``.
- **rotation**: the gyro's angle (bias removed) against the reference's turn:
  ``dtheta_gyro = s dtheta_ref`` gives ``s``, the gyro's scale factor.

The ratios are then ``u = u_gyro / s``, ``v = v_gyro / s`` (with ``s``'s variance
carried into theirs, :meth:`OnlineScale.correct`), the radii ``k`` times those with the
mean held, the separation ``k`` times the mean-held one.

Stamps are matched by interpolation in stamp time: the wheels' and the gyro's
cumulative angles (dense: every judged wheel step) at each reference stamp, so a
sparse reference (AMCL at 1-2 Hz) is never interpolated between its own poses. A
window counts only if no excluded step (slip, no gyro) or hole lies inside it.
Reference poses wait until the wheels' judged steps reach their stamp (a lagging
reference is fine up to ``MAX_LAG_S``); a dropout only makes a window longer; a jump
(AMCL relocalising) is a window whose innovation is beyond ``GATE_SIGMAS``: refused
and counted. Pure Python, no rclpy.

Each pose is first moved onto base_link by the reference's mount
(:mod:`~diffdrive_odom.core.geometry.mount`: ``online_calibration_reference_offset``,
or the transform to ``online_calibration_reference_frame`` the node finds on
/tf_static, :meth:`OnlineScale.set_mount`): a reference off the axle moves further
than base_link on every turn (``|l| dtheta``), which would read as a larger mean
radius. Until a frame's transform is known, poses are refused (``no_mount``).
"""

from __future__ import annotations

import bisect
import math
from collections import Counter, deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from types import MappingProxyType

from diffdrive_odom.core.errors import ConfigError, require_finite_min
from diffdrive_odom.core.estimation.online.kalman import kalman_update, quadratic
from diffdrive_odom.core.estimation.online.ratios import ratio_geometry
from diffdrive_odom.core.geometry.kinematics import Geometry
from diffdrive_odom.core.geometry.mount import AXLE, Mount
from diffdrive_odom.core.uncertainty.noise import NoiseModel

__all__ = ["REFERENCE_TYPES", "SCALE_FIELDS", "OnlineScale", "ReferenceConfig", "ScaleEstimate",
           "scale_values"]

ODOMETRY, POSE_STAMPED = "odometry", "pose_stamped"
REFERENCE_TYPES = (ODOMETRY, POSE_STAMPED)
PRIOR = 0.05  # relative 1-sigma of k and s at the start (1: the configured scale)
GATE_SIGMAS = 5.0  # a window whose innovation is beyond this many sigmas is refused
WINDOW_M = 0.5  # m the wheels travel before a window may close ...
WINDOW_RAD = 0.5  # ... or rad they turn ...
WINDOW_MAX_S = 5.0  # ... or s it lasts (at the first reference pose after)
MIN_CHORD = 0.2  # m: shorter chords give no distance update (|dp| is biased by noise)
MIN_DISTANCE = 5.0  # m of distance windows before the scale is determined
MAX_LAG_S = 10.0  # s of wheel steps kept for a reference that lags
MAX_PENDING = 4096  # reference poses waiting for the wheels (oldest dropped beyond)
TIMING_STDDEV = 0.01  # s: how far the reference's stamps may be off the wheels' (1 sigma)
RESTART_S = 1.0  # s: a stamp this far back is a new timeline (a bag loop), not a stale one
EXCLUDED = {
    "slip": "a step inside its window (or at its stamp) was excluded (slip, no gyro) or "
            "missing",
    "uncovered": "its stamp is outside the wheel steps kept (too late, or before the first), "
                 f"or its window would span over {MAX_LAG_S:g} s (the reference was silent)",
    "stale": "its stamp is not after the previous reference pose's",
    "outlier": f"its window disagreed with the estimate by over {GATE_SIGMAS:g} sigma "
               "(a reference jump)",
}

# Appended to ``online_estimate.FIELDS`` on ``~/geometry_estimate``, in this order.
SCALE_FIELDS = (
    "reference",  # 1.0: a reference topic sets the scale; 0.0: the configured scale
    "scale_determined",  # 1.0 once MIN_DISTANCE m and min_turn rad of reference windows
    "mean_radius_multiplier", "mean_radius_multiplier_stddev",  # k
    "scaled_left_wheel_radius_multiplier", "scaled_left_wheel_radius_multiplier_stddev",
    "scaled_right_wheel_radius_multiplier", "scaled_right_wheel_radius_multiplier_stddev",
    "scaled_wheel_separation_multiplier", "scaled_wheel_separation_multiplier_stddev",
    "gyro_scale", "gyro_scale_stddev",  # s (1: assumed without a reference)
    "reference_poses", "reference_windows", "reference_distance", "reference_turned",
    "reference_excluded_slip", "reference_excluded_uncovered", "reference_excluded_stale",
    "reference_excluded_outlier",
)


class ReferenceConfigError(ConfigError):
    """A reference setting that cannot work (names the parameter)."""


@dataclass(frozen=True)
class ReferenceConfig:
    """``online_calibration_reference_*``: the topic, its type, its noise per pose, its mount.

    ``mount``: where the reference's frame sits in base_link; ``frame``: '' (the mount
    as given), else the frame whose transform from base_link on /tf_static gives it.
    """

    topic: str
    kind: str = ODOMETRY
    position_stddev: float = 0.01  # m, of each pose
    heading_stddev: float = 0.005  # rad, of each pose
    mount: Mount = AXLE
    frame: str = ""

    def __post_init__(self) -> None:
        if self.kind not in REFERENCE_TYPES:
            raise ReferenceConfigError("online_calibration_reference_type",
                                       f"must be one of {', '.join(REFERENCE_TYPES)}, "
                                       f"got {self.kind!r}")
        if not self.topic.strip("/ "):
            raise ReferenceConfigError("online_calibration_reference_topic",
                                       "must name a topic ('' = no reference)")
        for name, value in (("position_stddev", self.position_stddev),
                            ("heading_stddev", self.heading_stddev)):
            require_finite_min(ReferenceConfigError, f"online_calibration_reference_{name}",
                               value, exclusive=True)


@dataclass(frozen=True)
class ScaleEstimate:
    """The reference's part of the estimate (see :data:`SCALE_FIELDS`).

    ``mean_radius``: ``k`` and its 1-sigma; ``gyro_scale``: ``s``; ``multipliers`` /
    ``stddevs``: ddc's three (left, right, separation) with the reference's scale.
    """

    determined: bool
    mean_radius: tuple[float, float]
    gyro_scale: tuple[float, float]
    multipliers: tuple[float, float, float]
    stddevs: tuple[float, float, float]
    poses: int
    windows: int
    distance: float
    turned: float
    excluded: Mapping[str, int]

    def line(self) -> str:
        """One line: the scale with its sigma, and the excitation."""
        (k, sk), (s, ss) = self.mean_radius, self.gyro_scale
        (ml, mr, mb), (sl, sr, sb) = self.multipliers, self.stddevs
        state = "determined" if self.determined else (
            f"not yet determined (needs {MIN_DISTANCE:g} m and turns)")
        return (f"with the reference: left {ml:.5f} +- {sl:.5f}, right {mr:.5f} +- {sr:.5f}, "
                f"separation {mb:.5f} +- {sb:.5f}; mean radius x {k:.5f} +- {sk:.5f}, gyro "
                f"scale {s:.5f} +- {ss:.5f}; {self.windows} windows over "
                f"{self.distance:.1f} m, {self.turned:.1f} rad: {state}")


def scale_values(scale: ScaleEstimate | None, multipliers: tuple[float, float, float],
                 stddevs: tuple[float, float, float]) -> tuple[float, ...]:
    """:data:`SCALE_FIELDS`' values; without a reference the configured scale, said so."""
    if scale is None:
        return (0.0, 0.0, 1.0, 0.0, *(v for p in zip(multipliers, stddevs, strict=True)
                                      for v in p), 1.0, 0.0, *(0.0,) * 8)
    ex = scale.excluded
    return (1.0, float(scale.determined), *scale.mean_radius,
            *(v for p in zip(scale.multipliers, scale.stddevs, strict=True) for v in p),
            *scale.gyro_scale, float(scale.poses), float(scale.windows), scale.distance,
            scale.turned, *(float(ex.get(k, 0)) for k in ("slip", "uncovered", "stale",
                                                           "outlier")))


# A wheel step's end: stamp, cumulative gyro heading (bias removed), the two wheels'
# angles laid along it (x, y each), excluded steps so far, travel [m], speed, turn rate.
_Point = tuple[int, float, float, float, float, float, int, float, float, float]


class OnlineScale:
    """``k`` (mean radius) and ``s`` (gyro scale) from windows between reference poses."""

    def __init__(self, config: ReferenceConfig, geometry: Geometry, noise_density: float,
                 noise: NoiseModel, min_turn: float, random_walk: float,
                 measured_density: Callable[[], float] = lambda: 0.0) -> None:
        self.config = config
        self.geometry = geometry  # the configured one: its mean radius is k's unit
        self.noise_density = noise_density
        self.measured_density = measured_density
        self.noise = noise
        self.min_turn = min_turn
        self.random_walk = random_walk
        # k, s, and the reference's error at the window's start pose (heading, x, y): windows
        # share their end poses, so that error is carried from one window to the next
        # instead of being counted afresh in each (their sum telescopes).
        self.x = [1.0, 1.0, 0.0, 0.0, 0.0]
        self.p = [[0.0] * 5 for _ in range(5)]
        self.p[0][0] = self.p[1][1] = PRIOR ** 2
        self._fresh_anchor()
        self.excluded: Counter[str] = Counter()
        self.poses = 0
        self.windows = 0
        self.distance = 0.0
        self.turned = 0.0
        self._stamps: list[int] = []
        self._points: list[_Point] = []
        self._refs: deque[tuple[int, float, float, float]] = deque()
        self._last_ref: int | None = None
        self._anchor: tuple[tuple[int, float, float, float], _Point] | None = None
        self._updated_ns: int | None = None
        self._ratios = (0.0, 0.0)  # the gyro's ratios, as last observed
        self._heading = 0.0  # the wheels' heading, true (the gyro's over s) [rad]
        # where the reference sits on the robot; None: its frame's transform not yet known
        self.mount: Mount | None = None if config.frame else config.mount

    def set_mount(self, mount: Mount) -> None:
        """The reference's mount, found (the node's /tf_static); poses move by it from now."""
        self.mount = mount

    # --- inputs ------------------------------------------------------------------

    def feed(self, stamp_ns: int, x: float, y: float, yaw: float) -> str:
        """One reference pose (its frame's); '' if kept, else the code it was refused with."""
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(yaw)) or stamp_ns <= 0:
            return "non_finite"
        if self.mount is None:
            return "no_mount"
        x, y, yaw = self.mount.base_pose(x, y, yaw)
        if self._last_ref is not None and stamp_ns <= self._last_ref:
            if self._last_ref - stamp_ns < RESTART_S * 1e9:
                self.excluded["stale"] += 1
                return "stale"
            self._refs.clear()  # a new timeline: the estimate carries on
            self._anchor = None
        self._last_ref = stamp_ns
        # Python floats whatever the caller gave (numpy's scalars would reach the applied
        # geometry and make every later step's arithmetic several times slower)
        self._refs.append((stamp_ns, float(x), float(y), float(yaw)))
        if len(self._refs) > MAX_PENDING:
            self._refs.popleft()
            self.excluded["uncovered"] += 1
        self._process()
        return ""

    def observe(self, t0: int, t1: int, phi_r: float, phi_l: float, advance: float,
                raw: float | None, slip: bool, state: list[float]) -> None:
        """One wheel step judged for good (as :meth:`OnlineGeometry.observe` gets it).

        ``phi_r``, ``phi_l``: the wheels' turns [rad]; ``advance``: the centre's arc [m];
        ``state``: the gyro filter's ``(u, v, bias)`` now.
        """
        if t1 <= t0:
            return
        dt = (t1 - t0) * 1e-9
        stamps, points = self._stamps, self._points
        if stamps and t0 < stamps[-1]:  # the wheels' time went back: start over
            stamps.clear()
            points.clear()
            self._anchor = None
        last = points[-1] if points else None
        if last is None or last[0] != t0:  # a hole: nothing is known over it
            last = (t0, 0.0, 0.0, 0.0, 0.0, 0.0, 1, 0.0, 0.0, 0.0) if last is None else (
                t0, *last[1:6], last[6] + 1, last[7], 0.0, 0.0)
            self._append(last)
        self._ratios = (state[0], state[1])
        turn = 0.0 if raw is None else raw - state[2] * dt
        # The wheels are laid along the true heading (the gyro's over its scale factor): a
        # chord along a heading turning s times too much would be off by about
        # (s - 1) theta^2 / 12 over a window turning theta.
        true_turn = turn / self.x[1]
        heading = self._heading
        self._heading = heading + true_turn
        mid = heading + 0.5 * true_turn
        c, s = math.cos(mid), math.sin(mid)
        self._append((t1, last[1] + turn, last[2] + phi_r * c, last[3] + phi_r * s,
                      last[4] + phi_l * c, last[5] + phi_l * s,
                      last[6] + 1 if raw is None or slip else last[6], last[7] + abs(advance),
                      advance / dt, turn / dt))
        if self._refs:  # reference poses waiting for the wheels to reach them
            self._process()

    def _append(self, point: _Point) -> None:
        self._stamps.append(point[0])
        self._points.append(point)
        if len(self._stamps) & 255:  # pruned every 256 steps
            return
        keep = point[0] - int(MAX_LAG_S * 1e9)  # a window's start pose is in its anchor
        cut = bisect.bisect_left(self._stamps, keep) - 1
        if cut > 0:
            del self._stamps[:cut]
            del self._points[:cut]

    def _at(self, stamp: int) -> _Point | str:
        """The wheels' and gyro's cumulative values at ``stamp``, else why not (a code)."""
        i = bisect.bisect_left(self._stamps, stamp)
        if i == 0 or i >= len(self._stamps):
            return (self._points[0] if i == 0 and self._stamps and self._stamps[0] == stamp
                    else "uncovered")
        a, b = self._points[i - 1], self._points[i]
        if b[6] != a[6]:
            return "slip"  # inside an excluded step
        f = (stamp - a[0]) / (b[0] - a[0])
        return (stamp, a[1] + f * (b[1] - a[1]), a[2] + f * (b[2] - a[2]),
                a[3] + f * (b[3] - a[3]), a[4] + f * (b[4] - a[4]), a[5] + f * (b[5] - a[5]),
                a[6], a[7] + f * (b[7] - a[7]), b[8], b[9])

    # --- windows -----------------------------------------------------------------

    def _process(self) -> None:
        refs = self._refs
        end = self._stamps[-1] if self._stamps else None
        while refs and end is not None and refs[0][0] <= end:
            ref = refs.popleft()
            self.poses += 1
            here = self._at(ref[0])
            if isinstance(here, str):
                self.excluded[here] += 1
                self._anchor = None
                continue
            if self._anchor is None:
                self._anchor = (ref, here)
                self._fresh_anchor()
                continue
            ref0, there = self._anchor
            if ref[0] - ref0[0] > MAX_LAG_S * 1e9:  # the reference was silent: too long a
                self.excluded["uncovered"] += 1  # window for its noise model, start anew
                self._anchor = (ref, here)
                self._fresh_anchor()
                continue
            if here[6] != there[6]:
                self.excluded["slip"] += 1
                self._anchor = (ref, here)
                self._fresh_anchor()
                continue
            dt = (ref[0] - ref0[0]) * 1e-9
            if (here[7] - there[7] >= WINDOW_M or abs(here[1] - there[1]) >= WINDOW_RAD
                    or dt >= WINDOW_MAX_S):
                self._update(ref0, there, ref, here)
                self._anchor = (ref, here)

    def _fresh_anchor(self) -> None:
        """A window's start pose whose error nothing has told about yet (its prior)."""
        x, p, cfg = self.x, self.p, self.config
        for i in range(2, 5):
            x[i] = 0.0
            for j in range(5):
                p[i][j] = p[j][i] = 0.0
        p[2][2] = cfg.heading_stddev ** 2
        p[3][3] = p[4][4] = cfg.position_stddev ** 2

    def _update(self, ref0: tuple[int, float, float, float], a: _Point,
                ref1: tuple[int, float, float, float], b: _Point) -> None:
        """One window: a rotation update of ``s`` and (long enough) a distance update of ``k``.

        The state is extended by the end pose's error (prior: the reference's noise), both
        updates run on it, then the start pose's error is dropped: the end pose starts the
        next window with what the updates told about its error.
        """
        dt = (ref1[0] - ref0[0]) * 1e-9
        cfg = self.config
        if self._updated_ns is not None:  # in the kept state: a refused window grows it too
            grow = max(ref1[0] - self._updated_ns, 0) * 1e-9 * self.random_walk ** 2
            self.p[0][0] += grow * self.x[0] ** 2
            self.p[1][1] += grow * self.x[1] ** 2
        self._updated_ns = ref1[0]
        x = [*self.x, 0.0, 0.0, 0.0]
        p = [[*row, 0.0, 0.0, 0.0] for row in self.p] + [[0.0] * 8 for _ in range(3)]
        p[5][5], p[6][6] = cfg.heading_stddev ** 2, cfg.position_stddev ** 2
        p[7][7] = p[6][6]
        gyro = b[1] - a[1]
        turn = gyro + math.remainder(ref1[3] - ref0[3] - gyro, math.tau)
        density = max(self.noise_density, self.measured_density())
        true_turn = turn - x[5] + x[2]
        # gyro = s (turn - n_end + n_start) + noise
        updates = [(gyro - x[1] * true_turn, [0.0, true_turn, x[1], 0.0, 0.0, -x[1], 0.0, 0.0],
                    density ** 2 * dt + (x[1] * (b[9] - a[9]) * TIMING_STDDEV) ** 2)]
        # The wheels' chord with the gyro's ratios at the configured mean radius.
        rl, rr, _ = ratio_geometry(self._ratios,
                                   0.5 * (self.geometry.left_radius + self.geometry.right_radius))
        h = 0.5 * math.hypot(rr * (b[2] - a[2]) + rl * (b[4] - a[4]),
                             rr * (b[3] - a[3]) + rl * (b[5] - a[5]))
        dx, dy = ref1[1] - ref0[1], ref1[2] - ref0[2]
        z = math.hypot(dx, dy)
        if h >= MIN_CHORD and z > 0.0:
            # |dp| = k h + (e_end - e_start) along the chord + noise
            ux, uy = dx / z, dy / z
            n = self.noise
            predicted = x[0] * h + ux * (x[6] - x[3]) + uy * (x[7] - x[4])
            updates.append((z - predicted, [h, 0.0, 0.0, -ux, -uy, 0.0, ux, uy],
                            x[0] ** 2 * 0.25 * (n.k_left + n.k_right) * (b[7] - a[7])
                            + (x[0] * (b[8] - a[8]) * TIMING_STDDEV) ** 2))
        for e, hv, r in updates:  # a jump shows in either: the whole window is refused
            if e * e > GATE_SIGMAS ** 2 * (quadratic(p, hv) + r):
                self.excluded["outlier"] += 1
                self._fresh_anchor()
                return
        for e, hv, r in updates:
            kalman_update(x, p, hv, e, r)
        keep = (0, 1, 5, 6, 7)
        self.x = [x[i] for i in keep]
        self.p = [[p[i][j] for j in keep] for i in keep]
        self.windows += 1
        self.turned += abs(turn)
        if len(updates) > 1:
            self.distance += h * self.x[0]

    # --- outputs -----------------------------------------------------------------

    @property
    def determined(self) -> bool:
        """``MIN_DISTANCE`` m of distance windows and ``min_turn`` rad of rotation ones."""
        return self.distance >= MIN_DISTANCE and self.turned >= self.min_turn

    def correct(self, ratios: tuple[float, float], cov: tuple[float, float, float, float]
                ) -> tuple[tuple[float, float], tuple[float, float, float, float]]:
        """The gyro's ratios over its scale factor, ``s``'s variance carried into theirs."""
        s, vs = self.x[1], self.p[1][1]
        u, v = ratios[0] / s, ratios[1] / s
        a, b, c, d = (e / (s * s) for e in cov)
        w = vs / (s * s)
        return (u, v), (a + u * u * w, b + u * v * w, c + u * v * w, d + v * v * w)

    def estimate(self, multipliers: tuple[float, float, float],
                 stddevs: tuple[float, float, float]) -> ScaleEstimate:
        """With the mean-held multipliers (of the corrected ratios): the scaled ones."""
        k, vk = self.x[0], self.p[0][0]
        mult = tuple(k * m for m in multipliers)
        sig = tuple(math.sqrt(k * k * sd * sd + m * m * vk)
                    for m, sd in zip(multipliers, stddevs, strict=True))
        return ScaleEstimate(
            determined=self.determined, mean_radius=(k, math.sqrt(max(vk, 0.0))),
            gyro_scale=(self.x[1], math.sqrt(max(self.p[1][1], 0.0))),
            multipliers=(mult[0], mult[1], mult[2]), stddevs=(sig[0], sig[1], sig[2]),
            poses=self.poses, windows=self.windows, distance=self.distance,
            turned=self.turned, excluded=MappingProxyType(dict(self.excluded)))
