"""The simulated base against closed forms (no ROS): kinematics, motor, encoders, slip."""

from __future__ import annotations

import math

import numpy as np
import pytest

from diffdrive_odom.core.estimation.wheels.encoders import unwrap_difference
from diffdrive_odom.core.geometry.kinematics import Geometry, wheel_rates
from diffdrive_odom.core.motion.routes import square
from diffdrive_odom.core.sim.model import DiffDriveSim, SimConfig, SimConfigError

import oracle

STEP_NS = 10_000_000  # 10 ms


def drive(sim: DiffDriveSim, rates: list[float], seconds: float, step_ns: int = STEP_NS) -> None:
    sim.command(rates)
    for _ in range(round(seconds * 1e9 / step_ns)):
        sim.advance(step_ns)


def test_equal_rates_drive_straight() -> None:
    g = Geometry(0.05, 0.3)
    sim = DiffDriveSim(SimConfig(g, command_timeout=0.0))
    drive(sim, [4.0, 4.0], 2.0)
    assert sim.pose.x == pytest.approx(0.05 * 4.0 * 2.0, abs=1e-12)
    assert sim.pose.y == pytest.approx(0.0, abs=1e-15)
    assert sim.pose.theta == pytest.approx(0.0, abs=1e-15)
    assert sim.distance == pytest.approx(0.4, abs=1e-12)


@pytest.mark.parametrize("step_ns", [1_000_000, 20_000_000, 700_000_000])
def test_unequal_radii_drive_the_textbook_circle(step_ns: int) -> None:
    # ELEC6530 homework eq. 1 with r_L != r_R, then x = R sin(wt), y = R (1 - cos wt).
    r_left, r_right, b = 0.05, 0.052, 0.3
    g = Geometry(0.05, b, right_wheel_radius_multiplier=r_right / 0.05)
    w_left, w_right = 3.0, 5.0
    v = 0.5 * (r_left * w_left + r_right * w_right)
    w = (r_right * w_right - r_left * w_left) / b
    sim = DiffDriveSim(SimConfig(g, command_timeout=0.0))
    t = 2.1
    drive(sim, [w_left, w_right], t, step_ns)
    x, y, _ = oracle.arc(v * t, w * t)
    assert sim.pose.x == pytest.approx(x, abs=1e-12)
    assert sim.pose.y == pytest.approx(y, abs=1e-12)
    assert sim.pose.theta == pytest.approx(w * t, abs=1e-12)
    assert sim.twist.linear == pytest.approx(v, rel=1e-12)
    assert sim.twist.angular == pytest.approx(w, rel=1e-12)


def test_flipped_joint_counts_backwards_and_takes_flipped_commands() -> None:
    g = Geometry(0.05, 0.3, right_wheel_sign=-1)
    sim = DiffDriveSim(SimConfig(g, command_timeout=0.0))
    left, right = wheel_rates(g, 0.2, 0.0)
    assert right == pytest.approx(-left)
    drive(sim, [left, right], 1.0)
    assert sim.pose.x == pytest.approx(0.2, abs=1e-12)
    assert sim.pose.y == pytest.approx(0.0, abs=1e-15)
    angles = sim.joint_angles
    assert angles[0] == pytest.approx(0.2 / 0.05)
    assert angles[1] == pytest.approx(-0.2 / 0.05)


def test_first_order_motor_matches_the_exponential_response() -> None:
    tau, omega = 0.15, 6.0
    g = Geometry(0.05, 0.3)
    sims = [
        DiffDriveSim(SimConfig(g, motor_time_constant=tau, command_timeout=0.0, substeps=k))
        for k in (1, 7)
    ]
    for sim in sims:
        sim.command([omega, omega])
    times = [0.02, 0.1, 0.45, 1.0]
    elapsed = 0.0
    for t in times:
        step_ns = round((t - elapsed) * 1e9)
        for sim in sims:
            sim.advance(step_ns)
        elapsed = t
        angle = omega * (t - tau * (1.0 - math.exp(-t / tau)))
        rate = omega * (1.0 - math.exp(-t / tau))
        for sim in sims:
            assert sim.joint_angles[0] == pytest.approx(angle, rel=1e-12)
            assert sim.joint_rates[1] == pytest.approx(rate, rel=1e-12)
            assert sim.pose.x == pytest.approx(0.05 * angle, rel=1e-12)


def test_command_timeout_stops_the_wheels() -> None:
    g = Geometry(0.05, 0.3)
    sim = DiffDriveSim(SimConfig(g, command_timeout=0.5))
    drive(sim, [2.0, 2.0], 2.0)
    # Moved for exactly the timeout, then stood still.
    assert sim.pose.x == pytest.approx(0.05 * 2.0 * 0.5, abs=1e-12)
    assert np.all(sim.joint_rates == 0.0)
    # A fresh command moves it again.
    drive(sim, [2.0, 2.0], 0.2)
    assert sim.pose.x == pytest.approx(0.05 * 2.0 * 0.7, abs=1e-12)


def test_encoder_counts_truncate_and_wrap() -> None:
    tpr, bits = 1000.0, 16
    start = 2**16 - 5.5
    g = Geometry(0.05, 0.3)
    sim = DiffDriveSim(SimConfig(g, ticks_per_revolution=tpr, counter_bits=bits,
                                 initial_count=start, command_timeout=0.0))
    assert list(sim.encoder_counts()) == [2**16 - 6, 2**16 - 6]
    # 0.1 rad/s left, 0.2 rad/s right for 1 s: 15.9 and 31.8 ticks.
    drive(sim, [0.1, 0.2], 1.0)
    angles = sim.joint_angles
    expected = [math.floor(start + a * tpr / (2 * math.pi)) % 2**16 for a in angles]
    counts = sim.encoder_counts()
    assert list(counts) == expected
    assert counts[0] < 100 and counts[1] < 100  # wrapped past zero
    for i, a in enumerate(angles):
        delta = unwrap_difference(counts[i] - (2**16 - 6), bits)
        assert abs(delta * 2 * math.pi / tpr - a) <= 2 * math.pi / tpr


def test_encoder_radians_are_whole_ticks_within_one_tick() -> None:
    tpr = 360.0
    g = Geometry(0.05, 0.3)
    sim = DiffDriveSim(SimConfig(g, ticks_per_revolution=tpr, command_timeout=0.0))
    drive(sim, [1.234, -0.77], 0.73)
    tick = 2 * math.pi / tpr
    for measured, true in zip(sim.encoder_radians(), sim.joint_angles, strict=True):
        assert 0.0 <= true - measured < tick
        assert measured / tick == pytest.approx(round(measured / tick), abs=1e-9)


def test_slip_variance_grows_with_distance_not_steps() -> None:
    # Each side's ground arc error ~ N(0, sigma^2 * arc). Straight at equal rates:
    # distance error var = sigma^2 (sL + sR) / 4, heading var = sigma^2 (sL + sR) / b^2.
    sigma, b, runs = 0.02, 0.3, 300
    g = Geometry(0.05, b)
    for metres, step_ns in ((1.0, 50_000_000), (2.0, 200_000_000)):
        dist, heading = [], []
        for seed in range(runs):
            sim = DiffDriveSim(SimConfig(g, slip_stddev=sigma, command_timeout=0.0, seed=seed))
            drive(sim, [4.0, 4.0], metres / 0.2, step_ns)
            dist.append(sim.distance - metres)
            heading.append(sim.pose.theta)
        # Sample variances of 300 normals are within ~3 standard errors (25 %).
        assert np.var(dist) == pytest.approx(sigma**2 * 2 * metres / 4, rel=0.25)
        assert np.var(heading) == pytest.approx(sigma**2 * 2 * metres / b**2, rel=0.25)
        assert abs(np.mean(heading)) < 4 * math.sqrt(sigma**2 * 2 * metres / b**2 / runs)


def test_same_seed_same_run_other_seed_other_run() -> None:
    g = Geometry(0.05, 0.3)

    def final(seed: int) -> tuple[float, float, float]:
        sim = DiffDriveSim(SimConfig(g, slip_stddev=0.01, seed=seed, command_timeout=0.0))
        drive(sim, [3.0, 2.0], 1.5)
        return sim.pose.x, sim.pose.y, sim.pose.theta

    assert final(7) == final(7)
    assert final(7) != final(8)


def test_route_driven_through_the_sim_ends_where_the_closed_form_says() -> None:
    # Route commands -> inverse kinematics -> sim (CIR steps) vs routes' arcs.
    g = Geometry(0.05, 0.3)
    route = square(1.0, 0.25, 0.5, pause=0.0)
    sim = DiffDriveSim(SimConfig(g, command_timeout=0.0))
    step_ns = 10_000_000
    for seg in route.segments:
        left, right = wheel_rates(g, seg.linear, seg.angular)
        sim.command([left, right])
        total = round(seg.duration * 1e9)
        while total > 0:  # whole steps, then the remainder
            sim.advance(min(step_ns, total))
            total -= step_ns
    x, y, theta = oracle.route_end(route.segments)
    assert math.hypot(x, y) < 1e-12 and abs(math.remainder(theta, 2 * math.pi)) < 1e-12
    assert sim.pose.x == pytest.approx(x, abs=1e-9)
    assert sim.pose.y == pytest.approx(y, abs=1e-9)
    assert math.remainder(sim.pose.theta - theta, 2 * math.pi) == pytest.approx(0.0, abs=1e-9)
    assert sim.distance == pytest.approx(4.0, abs=1e-9)


def test_several_wheels_per_side_are_averaged() -> None:
    g = Geometry(0.05, 0.3)
    sim = DiffDriveSim(SimConfig(g, wheels_per_side=2, command_timeout=0.0))
    drive(sim, [1.0, 3.0, 2.0, 2.0], 1.0)  # left mean 2, right mean 2: straight
    assert sim.pose.x == pytest.approx(0.1, abs=1e-12)
    assert sim.pose.theta == pytest.approx(0.0, abs=1e-15)
    with pytest.raises(ValueError):
        sim.command([1.0, 1.0])
    with pytest.raises(ValueError):
        sim.command([1.0, math.nan, 1.0, 1.0])


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"motor_time_constant": -1.0}, "motor_time_constant"),
        ({"slip_stddev": math.inf}, "slip_stddev"),
        ({"command_timeout": math.nan}, "command_timeout"),
        ({"ticks_per_revolution": -2.0}, "ticks_per_revolution"),
        ({"counter_bits": 16}, "encoder_counter_bits"),
        ({"ticks_per_revolution": 100.0, "counter_bits": 65}, "encoder_counter_bits"),
        ({"wheels_per_side": 0}, "wheels_per_side"),
        ({"substeps": 0}, "substeps"),
    ],
)
def test_bad_config_names_the_field(kwargs: dict[str, float], field: str) -> None:
    with pytest.raises(SimConfigError) as err:
        SimConfig(Geometry(0.05, 0.3), **kwargs)  # type: ignore[arg-type]
    assert err.value.field == field
