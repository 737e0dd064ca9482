"""The scale of the online estimate from a reference pose, and the gyro's scale factor.

Issue 25 items 4 and 5. The streams: wheels and IMU on their own clocks
(``gyrostreams``), a reference pose on a third (``refstreams``: 30 Hz, 50 ms late, in
a frame of its own, noisy), all in receive-time order. The robot's true geometry
differs from the configured one and its gyro reads ``s`` times the true yaw rate.
Expected values in closed form from the true geometry: the gyro alone estimates
``s r_R/b``, ``s r_L/b``; with the reference, the gyro scale ``s``, the mean radius
``(r_L + r_R) / 2R`` and ddc's multipliers ``r_L/R``, ``r_R/R``, ``b/B``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from functools import cache

import numpy as np
import pytest
from gyrostreams import ISSUE_ROUTE, NAMES, TIMINGS, B, Message, R, Truth, stream, truth
from refstreams import Reference, RefMessage, merge, reference

from diffdrive_odom.core.estimation.online.online_estimate import CHI2_2DOF_3SIGMA, OnlineEstimate
from diffdrive_odom.core.estimation.online.online_scale import SCALE_FIELDS, scale_values
from diffdrive_odom.core.estimation.pipeline import ReadingPipeline
from diffdrive_odom.settings.errors import ParameterError
from diffdrive_odom.settings.odometry import odometry_settings

from oracle import mahalanobis2

BIAS = math.radians(0.3)
ND = 3e-4
TRUE = (R * 0.998, R * 1.003, B * 1.01)  # the mean radius 0.05 % small, track 1 % wide
SCALE = 1.02  # the gyro reads 2 % too much
MIXED = ISSUE_ROUTE  # 76 s, 26 m, 7.6 rad left, 4.8 rad right, four slips
TIMING = {t.name: t for t in TIMINGS}["173 Hz jittered"]
EXACT_WHEELS = {"wheel_noise_k_left": 0.0, "wheel_noise_k_right": 0.0}
REF = {"online_calibration_reference_topic": "/ref",
       "online_calibration_reference_position_stddev": 0.002,
       "online_calibration_reference_heading_stddev": 0.001}


@cache
def _truth(geometry: tuple[float, float, float]) -> Truth:
    return truth(MIXED, *geometry)


def run(ref: Reference | None, geometry: tuple[float, float, float] = TRUE,
        scale: float = SCALE, seed: int = 1, trace: bool = False, as_numpy: bool = False,
        **values: object) -> tuple[OnlineEstimate, list[str], ReadingPipeline]:
    """Feed the streams as a node does; the final estimate and the warnings said.

    ``trace``: the pipeline keeps the estimate's history; ``as_numpy``: the reference's
    values given as numpy scalars (a script's own reader), not the decoders' floats.
    """
    tru = _truth(geometry)
    messages = stream(MIXED, TIMING, BIAS, ND, seed, tru, scale)
    both = merge(messages, [] if ref is None else reference(tru, ref, MIXED.seconds, seed))
    pipe = ReadingPipeline(odometry_settings(
        {"wheel_radius": R, "wheel_separation": B, "use_imu": True, **EXACT_WHEELS,
         **({} if ref is None else REF), **values}), trace=trace)
    warnings = feed(pipe, both, as_numpy=as_numpy)
    est = pipe.stats.online
    assert est is not None
    return est, warnings, pipe


def feed(pipe: ReadingPipeline, messages: list[Message | RefMessage],
         each: Callable[[], object] = lambda: None,
         as_numpy: bool = False) -> list[str]:
    """The merged streams into ``pipe`` in receive order, as a node takes them; the
    warnings said. ``each()`` after every wheel reading; ``as_numpy``: the reference's
    values as numpy scalars (a script's own reader), not the decoders' floats."""
    warnings = []
    for m in messages:
        if m[0] == "i":
            pipe.feed_imu(m[2], 0.0, 0.0, m[3], receive_ns=m[1])
        elif m[0] == "r":
            x, y, yaw = (np.float64(v) for v in m[3:6]) if as_numpy else m[3:6]  # type: ignore[misc]
            assert pipe.feed_reference(m[2], x, y, yaw) == ""
        else:
            if (w := pipe.feed(m[2], NAMES, (m[3], m[4]), receive_ns=m[1]).warning):
                warnings.append(w)
            each()
    return warnings


def distance2(est: OnlineEstimate, u: float, v: float) -> float:
    """The ratios ``(u, v)``'s squared Mahalanobis distance from the estimate."""
    return mahalanobis2(est.ratios, est.covariance, (u, v))


def test_without_reference_the_gyro_scale_maps_into_the_ratios() -> None:
    """The gyro alone finds ``s`` times the true ratios, and warns though nothing changed."""
    rl, rr, b = TRUE
    est, _, _ = run(None)
    assert est.scale is None and est.determined
    assert distance2(est, SCALE * rr / b, SCALE * rl / b) < CHI2_2DOF_3SIGMA
    assert distance2(est, rr / b, rl / b) > 100.0  # 2 % off: far outside
    # The separation it suggests is the true one over s (mean radius held).
    mb, sb = est.multipliers[2], est.stddevs[2]
    assert abs(mb - 2 * R * b / ((rl + rr) * B) / SCALE) < 3 * sb
    # The configured geometry is the truth, the gyro 2 % off: a false warning.
    _, warnings, _ = run(None, geometry=(R, R, B))
    assert any("outside" in w for w in warnings)
    values = scale_values(est.scale, est.multipliers, est.stddevs)
    named = dict(zip(SCALE_FIELDS, values, strict=True))
    assert named["reference"] == 0.0 and named["gyro_scale"] == 1.0
    assert named["scaled_wheel_separation_multiplier"] == est.multipliers[2]


def test_with_reference_scale_and_separation_are_recovered() -> None:
    rl, rr, b = TRUE
    est, _, _ = run(Reference())
    sc = est.scale
    assert sc is not None and sc.determined and est.determined
    (s, ss), (k, sk) = sc.gyro_scale, sc.mean_radius
    assert abs(s - SCALE) < 3 * ss and ss < 0.002
    assert abs(k - (rl + rr) / (2 * R)) < 3 * sk and sk < 0.002
    for got, sigma, want in zip(sc.multipliers, sc.stddevs, (rl / R, rr / R, b / B),
                                strict=True):
        assert abs(got - want) < 3 * sigma
        assert sigma < 0.003
    # The ratios are corrected by s: the truth is inside their 3-sigma region.
    assert distance2(est, rr / b, rl / b) < CHI2_2DOF_3SIGMA
    assert sc.windows > 50 and not sc.excluded.get("outlier")


def test_with_reference_no_false_warning_from_the_gyro_scale() -> None:
    _, warnings, _ = run(Reference(), geometry=(R, R, B))
    assert not any("outside" in w for w in warnings)


def test_a_lagging_dropping_jumping_reference() -> None:
    """AMCL-like: 2 Hz, 0.4 s late, silent 7 s, three jumps: refused and counted."""
    rl, rr, b = TRUE
    amcl = Reference(hz=2.0, latency=0.4, position_stddev=0.005, heading_stddev=0.003,
                     dropout=(35.0, 42.0), jumps=((20.0, 0.15, -0.1, 0.0),
                                                  (48.0, 0.0, 0.2, 0.05),
                                                  (65.0, -0.2, 0.0, -0.08)))
    est, _, _ = run(amcl, online_calibration_reference_position_stddev=0.005,
                    online_calibration_reference_heading_stddev=0.003)
    sc = est.scale
    assert sc is not None and sc.determined
    assert sc.excluded["outlier"] >= 3  # each jump spoils the window across it
    (s, ss), (k, sk) = sc.gyro_scale, sc.mean_radius
    assert abs(s - SCALE) < 3 * ss
    assert abs(k - (rl + rr) / (2 * R)) < 3 * sk
    assert abs(sc.multipliers[2] - b / B) < 3 * sc.stddevs[2]


def test_settings_are_checked_at_start() -> None:
    base = {"wheel_radius": R, "wheel_separation": B, "use_imu": True}
    with pytest.raises(ParameterError, match="online_calibration_reference_type"):
        odometry_settings({**base, **REF, "online_calibration_reference_type": "tf"})
    with pytest.raises(ParameterError, match="online_calibration_reference_position_stddev"):
        odometry_settings({**base, "online_calibration_reference_position_stddev": 0.0})
    cfg = odometry_settings({**base, **REF, "online_calibration_reference_type":
                             "pose_stamped"}).online
    assert cfg is not None and cfg.reference is not None
    assert cfg.reference.kind == "pose_stamped" and cfg.reference.topic == "/ref"
    off = odometry_settings(base).online
    assert off is not None and off.reference is None
    # Without a reference topic (or without the online estimate) a pose is ignored.
    assert ReadingPipeline(odometry_settings(base)).feed_reference(1, 0.0, 0.0, 0.0) == ""


def test_scale_core_exact_data_and_a_time_reset() -> None:
    """OnlineScale alone on exact data: k and s in closed form; a bag loop starts over."""
    from diffdrive_odom.core.estimation.online.online_scale import OnlineScale, ReferenceConfig
    from diffdrive_odom.core.geometry.kinematics import Geometry
    from diffdrive_odom.core.uncertainty.noise import NoiseModel

    g = Geometry(R, B)
    k, s = 1.01, 0.98  # the true radii 1 % larger; the gyro reads 2 % less
    scale = OnlineScale(ReferenceConfig("/ref", position_stddev=1e-4, heading_stddev=1e-4),
                        g, 1e-5, NoiseModel(k_left=0.0, k_right=0.0), 1.0, 0.0)
    state = [s * k * R / B, s * k * R / B, 0.0]  # the gyro's ratios: s times the truth

    def drive(t0: int, seconds: float, v: float, w: float, pose: list[float]) -> int:
        dt = 20_000_000
        for i in range(round(seconds * 50)):
            a, b = t0 + i * dt, t0 + (i + 1) * dt
            # The wheels' angles for the true twist (radii k R, separation B).
            phi_l, phi_r = ((v - 0.5 * B * w) * 0.02 / (k * R),
                            (v + 0.5 * B * w) * 0.02 / (k * R))
            th = pose[2] + 0.5 * w * 0.02
            pose[0] += v * 0.02 * math.cos(th)
            pose[1] += v * 0.02 * math.sin(th)
            pose[2] += w * 0.02
            scale.observe(a, b, phi_r, phi_l, 0.5 * (phi_l + phi_r) * R, s * w * 0.02, False,
                          state)
            if i % 5 == 4:
                assert scale.feed(b, *pose) == ""
        return t0 + round(seconds * 50) * dt

    pose = [0.0, 0.0, 0.0]
    t = drive(10**18, 10.0, 0.5, 0.0, pose)
    assert not scale.determined and scale.turned < 0.01  # straight: s not seen yet
    assert scale.x[0] == pytest.approx(k, rel=1e-4)  # the distance is
    t = drive(t, 10.0, 0.3, 0.4, pose)
    t = drive(t, 10.0, 0.3, -0.4, pose)
    assert scale.x[:2] == pytest.approx([k, s], rel=1e-4)
    assert scale.determined and not scale.excluded
    windows = scale.windows
    drive(10**18, 10.0, 0.3, 0.5, [0.0, 0.0, 0.0])  # the bag again: time went back 30 s
    assert scale.windows > windows and not scale.excluded.get("stale")
    assert scale.x[:2] == pytest.approx([k, s], rel=1e-4)


def test_apply_with_reference_integrates_with_the_reference_scale() -> None:
    """In apply, once the scale is determined the radii and separation take it too."""
    rl, rr, b = TRUE
    est, _, pipe = run(Reference(), online_calibration="apply")
    online = pipe.online
    assert online is not None and est.applied and est.scale is not None
    assert est.scale.determined
    g = online.applied
    assert g is not None
    for got, sigma, want in zip((g.left_radius / R, g.right_radius / R, g.separation / B),
                                est.scale.stddevs, (rl / R, rr / R, b / B), strict=True):
        assert abs(got - want) < 3 * sigma
    # The truth's mean radius is 0.05 % small: held at the configured one it would not be.
    k = est.scale.mean_radius[0]
    assert (g.left_radius + g.right_radius) / (2 * R) == pytest.approx(k, rel=1e-12)
    assert online.applied_covariance is not None


def test_trace_and_numpy_inputs_change_nothing_but_what_is_kept() -> None:
    """The node keeps no history of the estimate (it builds one per update only for a
    tool); replay's trace ends at the same estimate. A reference given as numpy scalars
    gives the same estimate bit for bit, and the applied geometry stays Python floats
    (numpy's would make every later step's arithmetic several times slower)."""
    plain, _, pipe = run(Reference(), online_calibration="apply")
    assert pipe.online is not None and pipe.online.trace == []
    traced, _, tpipe = run(Reference(), trace=True, online_calibration="apply")
    assert tpipe.online is not None and len(tpipe.online.trace) > 10
    assert traced == plain
    assert tpipe.online.trace[-1][1].windows == plain.windows  # traced at every update
    numpy, _, npipe = run(Reference(), as_numpy=True, online_calibration="apply")
    assert numpy == plain
    applied = npipe.online.applied if npipe.online is not None else None
    assert applied is not None
    assert all(type(getattr(applied, f)) is float for f in (
        "left_wheel_radius_multiplier", "right_wheel_radius_multiplier",
        "wheel_separation_multiplier"))


def test_a_long_silent_reference_starts_anew_and_keeps_ten_seconds() -> None:
    """The reference silent 20 s mid-route (MAX_LAG_S is 10): the steps kept stay about
    10 s all along (they grew without bound while a window was open), the first pose
    after the silence starts a new window (counted ``uncovered``), and the estimate
    still covers the truth."""
    from diffdrive_odom.core.estimation.online.online_scale import MAX_LAG_S

    rl, rr, b = TRUE
    tru = _truth(TRUE)
    ref = Reference(dropout=(30.0, 50.0))
    both = merge(stream(MIXED, TIMING, BIAS, ND, 1, tru, SCALE),
                 reference(tru, ref, MIXED.seconds, 1))
    pipe = ReadingPipeline(odometry_settings(
        {"wheel_radius": R, "wheel_separation": B, "use_imu": True, **EXACT_WHEELS, **REF}))
    scale = pipe.online.scale if pipe.online is not None else None
    assert scale is not None
    kept: list[int] = []
    feed(pipe, both, lambda: kept.append(len(scale._stamps)))
    assert max(kept) <= MAX_LAG_S * 50 + 256 + 2  # 50 Hz wheels, pruned every 256 steps
    est = pipe.stats.online
    assert est is not None and est.scale is not None and est.scale.determined
    assert est.scale.excluded["uncovered"] >= 1
    (k, sk), sc = est.scale.mean_radius, est.scale
    assert abs(k - (rl + rr) / (2 * R)) < 3 * sk
    assert abs(sc.multipliers[2] - b / B) < 3 * sc.stddevs[2]


def test_runtime_settings_reach_the_reference_filter() -> None:
    """online_calibration_min_turn and _random_walk set at runtime (ros2 param set)
    reach the reference's filter as they reach the gyro's."""
    values = {"wheel_radius": R, "wheel_separation": B, "use_imu": True, **REF}
    pipe = ReadingPipeline(odometry_settings(values))
    pipe.reconfigure(odometry_settings({**values, "online_calibration_min_turn": 5.0,
                                        "online_calibration_random_walk": 2e-5}))
    online = pipe.online
    assert online is not None and online.scale is not None
    assert (online.scale.min_turn, online.scale.random_walk) == (5.0, 2e-5)


def test_the_covariance_does_not_drop_when_the_applied_scale_becomes_the_references() -> None:
    """The reference silent for the first 45 s: apply takes the gyro's estimate with the
    configured mean radius first, the reference's k later. Its S then holds k's sigma
    (several times smaller than the configured radii's): the error made so far with the
    old S is folded in, so the published position variance does not drop there (it
    dropped by 6.7e-5 m^2 when the old S was only replaced)."""
    tru = _truth(TRUE)
    both = merge(stream(MIXED, TIMING, BIAS, ND, 1, tru, SCALE),
                 reference(tru, Reference(dropout=(0.0, 45.0)), MIXED.seconds, 1))
    pipe = ReadingPipeline(odometry_settings(
        {"wheel_radius": R, "wheel_separation": B, "use_imu": True, **EXACT_WHEELS, **REF,
         "online_calibration": "apply"}))
    online, est = pipe.online, pipe.estimator
    assert online is not None and est.uncertainty is not None
    states, variance = [], []

    def record() -> None:
        assert online is not None and est.uncertainty is not None
        c = est.uncertainty.pose_covariance(est.pose, est.geometry)
        states.append((online.in_use is not None, online.in_use_scaled))
        variance.append(c[0][0] + c[1][1])

    feed(pipe, both, record)
    applied = states.index((True, False))  # the gyro's estimate, the configured scale
    scaled = states.index((True, True))  # then the reference's scale
    assert 0 < applied < scaled
    assert variance[scaled] >= variance[scaled - 1]


def test_a_reference_off_the_axle_is_moved_onto_it_by_its_offset() -> None:
    """A reference 0.25 m ahead, 0.15 m to the right, turned 100 deg (a marker body, a
    camera): its point moves sideways on every turn, which no wheel explains. Given its
    offset (online_calibration_reference_offset), the scale and the gyro's scale factor
    come out as on the axle, within their sigma, no window refused; not given, the
    windows that turn are refused as jumps (19 of them here)."""
    rl, rr, _ = TRUE
    mount = (0.25, -0.15, math.radians(100.0))
    axle, _, _ = run(Reference())
    given, _, _ = run(Reference(mount=mount),
                      online_calibration_reference_offset=list(mount))
    ignored, _, _ = run(Reference(mount=mount))
    a, g, n = (e.scale for e in (axle, given, ignored))
    assert a is not None and g is not None and n is not None and g.determined
    (k, sk), (s, ss) = g.mean_radius, g.gyro_scale
    assert abs(k - a.mean_radius[0]) < sk and abs(s - a.gyro_scale[0]) < ss
    assert abs(k - (rl + rr) / (2 * R)) < 3 * sk
    assert not g.excluded.get("outlier") and not a.excluded.get("outlier")
    assert n.excluded.get("outlier", 0) > 10, n.excluded


def test_a_reference_frame_waits_for_its_mount() -> None:
    """online_calibration_reference_frame: the mount comes from /tf_static (the node's);
    until it is set, every pose is refused as no_mount and none is counted."""
    settings = odometry_settings({"wheel_radius": R, "wheel_separation": B, "use_imu": True,
                                  **REF, "online_calibration_reference_frame": "/marker"})
    pipe = ReadingPipeline(settings)
    assert pipe.feed_reference(10**9, 1.0, 2.0, 0.3) == "no_mount"
    from diffdrive_odom.core.geometry.mount import Mount

    pipe.set_reference_mount(Mount(0.1, 0.0, 0.0))
    assert pipe.feed_reference(2 * 10**9, 1.0, 2.0, 0.3) == ""
    with pytest.raises(ParameterError, match="online_calibration_reference_offset"):
        odometry_settings({"wheel_radius": R, "wheel_separation": B, "use_imu": True, **REF,
                           "online_calibration_reference_offset": [0.1, 0.2]})
