"""SE(2) helpers: the one angle-wrap convention (-pi, pi] and relative motion, by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest

from diffdrive_odom.core.geometry.se2 import between, conjugate, wrap_angle, wrap_angles


def test_array_wrap_has_the_scalar_convention() -> None:
    a = np.array([0.0, math.pi, -math.pi, 3 * math.pi, -3.0, 3.0, 2 * math.pi, 7.5, -7.5])
    got = wrap_angles(a)
    assert got[1] == math.pi and got[2] == math.pi  # (-pi, pi]: -pi is pi
    assert np.all(got > -math.pi) and np.all(got <= math.pi)
    want = np.array([wrap_angle(float(x)) for x in a])
    assert np.allclose(got, want, rtol=0.0, atol=4 * np.spacing(math.pi))
    assert float(wrap_angles(-math.pi)) == math.pi  # a 0-d input stays usable as a float


def test_between_is_the_motion_seen_from_the_first_pose() -> None:
    a = np.array([[1.0, 2.0, 0.5 * math.pi], [0.0, 0.0, 0.0]])
    b = np.array([[1.0, 3.0, math.pi], [-1.0, 2.0, -0.25]])
    got = between(a, b)
    # Facing +y, one metre further along y is one metre ahead; turned by a quarter.
    assert got[0] == pytest.approx([1.0, 0.0, 0.5 * math.pi], abs=1e-15)
    assert got[1] == pytest.approx([-1.0, 2.0, -0.25], abs=0.0)


def test_conjugate_moves_a_motion_to_the_body() -> None:
    # A marker 0.5 m ahead of the axle: the body turning in place by a quarter moves
    # the marker from (0.5, 0) to (0, 0.5) of the body's start frame, i.e. the marker
    # sees the motion (-0.5, 0.5) in its own (aligned) frame.
    marker = np.array([[-0.5, 0.5, 0.5 * math.pi]])
    assert conjugate(marker, 0.5, 0.0, 0.0)[0] == pytest.approx([0.0, 0.0, 0.5 * math.pi],
                                                                 abs=1e-15)
