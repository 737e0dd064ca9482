"""The simulated gyro and scripted slip of sim_node (issue 18), in the core and over DDS.

Core: a slip event adds exactly ``rate * duration`` to one side's encoders and nothing to
the ground; the gyro reads the true yaw rate plus its bias, with white noise of
``density * sqrt(rate)`` per sample, each sample the mean rate since the last, so they
add up to the ground truth's turn (slip noise and all). DDS: sim_node (gyro at 100 Hz,
a 0.5 s slip of the right wheel) and odometry_node with ``use_imu`` on the same graph,
driven straight: gyro-aided odometry stays with the ground truth where the wheels alone
turn 1 rad.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from diffdrive_odom.core.geometry.kinematics import Geometry
from diffdrive_odom.core.sim.model import DiffDriveSim, SimConfig, SimConfigError, SlipEvent
from diffdrive_odom.settings.errors import ParameterError
from diffdrive_odom.settings.sim import sim_settings

G = Geometry(0.033, 0.16)


def test_a_slip_event_turns_the_encoder_and_not_the_ground() -> None:
    sim = DiffDriveSim(SimConfig(G, command_timeout=0.0,
                                 slip_events=(SlipEvent("right", 1.0, 0.5, 10.0),)))
    sim.command([5.0, 5.0])
    for _ in range(150):
        sim.advance(20_000_000)  # 3 s
    # Straight on the ground: 5 rad/s * 0.033 m * 3 s.
    assert sim.pose.x == pytest.approx(5.0 * 0.033 * 3.0, abs=1e-12)
    assert sim.pose.y == 0.0 and sim.pose.theta == 0.0
    left, right = sim.joint_angles
    assert left == pytest.approx(15.0, abs=1e-12)
    assert right == pytest.approx(15.0 + 10.0 * 0.5, abs=1e-12)


def test_the_gyro_reads_the_true_rate_plus_bias_and_its_noise() -> None:
    sim = DiffDriveSim(SimConfig(G, command_timeout=0.0, gyro_bias=0.01))
    sim.command([-2.0, 2.0])  # turning on the spot: 2 * 2 * 0.033 / 0.16 rad/s
    sim.advance(10_000_000)
    assert sim.gyro(100.0) == pytest.approx(4 * 0.033 / 0.16 + 0.01, abs=1e-12)
    noisy = DiffDriveSim(SimConfig(G, command_timeout=0.0, gyro_noise_density=1e-3,
                                   gyro_bias=0.02))
    samples = np.array([noisy.gyro(400.0) for _ in range(20000)])
    assert samples.std() == pytest.approx(1e-3 * math.sqrt(400.0), rel=0.03)
    assert abs(samples.mean() - 0.02) < 4 * samples.std() / math.sqrt(len(samples))


def test_the_gyro_samples_add_up_to_the_turn_the_ground_made() -> None:
    # Slip noise on 1 ms substeps and a motor lag: the ground's rate over one substep is
    # mostly slip noise, yet the samples (each the mean over its 10 ms) sum to the turn.
    sim = DiffDriveSim(SimConfig(G, command_timeout=0.0, motor_time_constant=0.05,
                                 slip_stddev=0.01, substeps=10, seed=5, gyro_bias=0.01))
    turned = 0.0
    for k in range(200):  # 2 s, the command changing every 0.1 s
        if k % 10 == 0:
            sim.command([3.0 + math.sin(k), 5.0 + math.cos(k)])
        sim.advance(10_000_000)
        turned += (sim.gyro(100.0) - 0.01) * 0.01
    assert 0.5 < sim.pose.theta < 3.0  # turned without wrapping
    assert turned == pytest.approx(sim.pose.theta, abs=1e-12)


def test_the_gyro_scale_factor_multiplies_the_true_rate_not_the_bias() -> None:
    """Issue 25 item 5: ``sim_gyro_scale`` s reads s times the turn, the bias as it is."""
    sim = DiffDriveSim(SimConfig(G, command_timeout=0.0, gyro_bias=0.01, gyro_scale=1.02))
    sim.command([-2.0, 2.0])
    sim.advance(10_000_000)
    assert sim.gyro(100.0) == pytest.approx(1.02 * 4 * 0.033 / 0.16 + 0.01, abs=1e-12)
    assert sim_settings({"sim_gyro_scale": 0.98}).config.gyro_scale == 0.98
    for bad in (0.0, -1.0, math.inf):
        with pytest.raises((ParameterError, SimConfigError)) as err:
            sim_settings({"sim_gyro_scale": bad})
        assert getattr(err.value, "name", "") == "sim_gyro_scale"


def test_turning_the_gyro_on_keeps_the_slip_noise_of_a_seed() -> None:
    def run(density: float) -> float:
        sim = DiffDriveSim(SimConfig(G, command_timeout=0.0, slip_stddev=0.01, seed=3,
                                     gyro_noise_density=density))
        sim.command([5.0, 4.0])
        for _ in range(50):
            sim.advance(20_000_000)
            sim.gyro(50.0)
        return sim.pose.theta

    assert run(0.0) == run(1e-3)


@pytest.mark.parametrize("text", ["right 5 1", "up 5 1 15", "right 5 0 15", "right x 1 15"])
def test_bad_slip_events_are_named(text: str) -> None:
    with pytest.raises((ParameterError, SimConfigError)) as err:
        sim_settings({"slip_events": text})
    assert getattr(err.value, "name", "") == "slip_events"


def test_slip_events_parse() -> None:
    s = sim_settings({"slip_events": "right 5 1 15; left 9 0.5 -10;", "imu_rate": 200.0})
    assert s.config.slip_events == (SlipEvent("right", 5.0, 1.0, 15.0),
                                    SlipEvent("left", 9.0, 0.5, -10.0))
    assert s.imu_rate == 200.0
