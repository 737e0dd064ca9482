"""Where a reference sits on the robot: its poses and motions moved onto base_link.

Expected values from plain trigonometry written here (the reference's point is
``p + R(theta) (x, y)``, its heading ``theta + yaw``), not from the module.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from diffdrive_odom.core.geometry.mount import AXLE, Mount
from diffdrive_odom.core.geometry.se2 import between

LEVER = st.floats(-0.3, 0.3)
ANGLE = st.floats(-math.pi, math.pi)


def _mounted(poses: np.ndarray, x: float, y: float, yaw: float) -> np.ndarray:
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    return np.column_stack((poses[:, 0] + c * x - s * y, poses[:, 1] + s * x + c * y,
                            poses[:, 2] + yaw))


@settings(max_examples=50)
@given(x=LEVER, y=LEVER, yaw=ANGLE, seed=st.integers(0, 2**16))
def test_base_poses_undo_the_mount_and_motions_follow(x: float, y: float, yaw: float,
                                                      seed: int) -> None:
    rng = np.random.default_rng(seed)
    base = np.column_stack((rng.uniform(-5, 5, 20), rng.uniform(-5, 5, 20),
                            np.cumsum(rng.uniform(-1, 1, 20))))
    ref = _mounted(base, x, y, yaw)
    m = Mount(x, y, yaw)
    assert m.base_poses(ref) == pytest.approx(base, abs=1e-12)
    for i in (0, 7, 19):
        assert m.base_pose(*ref[i]) == pytest.approx(tuple(base[i]), abs=1e-12)
    # a motion of the reference's frame, seen from its start, moved onto base_link, is
    # base_link's own motion from its start
    start = np.repeat(ref[:1], len(ref), axis=0)
    want = between(np.repeat(base[:1], len(base), axis=0), base)
    assert m.base_motions(between(start, ref)) == pytest.approx(want, abs=1e-12)


def test_the_axle_changes_nothing_and_a_mount_prints_itself() -> None:
    poses = np.array([[1.0, 2.0, 0.3], [-1.0, 0.5, -2.0]])
    assert np.array_equal(AXLE.base_poses(poses), poses)
    m = Mount(-0.12, 0.2, math.radians(150.0))
    assert m.lever == pytest.approx(math.hypot(0.12, 0.2))
    assert m.text() == "x -0.1200 m, y +0.2000 m, yaw +150.00 deg"
    assert m.text((0.001, 0.002, math.radians(0.5))) == (
        "x -0.1200 +- 0.0010 m, y +0.2000 +- 0.0020 m, yaw +150.00 +- 0.50 deg")
    with pytest.raises(ValueError, match="finite"):
        Mount(math.nan, 0.0, 0.0)
