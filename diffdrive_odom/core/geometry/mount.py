"""Where a reference sits on the robot: its frame's pose in base_link, and its poses moved there.

Pure Python + numpy. A reference (a motion capture's marker body, a camera, a GNSS
antenna, a prism) reports the pose of its own frame, not base_link's: ``R = B M``, with
``M`` the pose of the reference's frame in base_link (REP-103: x forward, y left, yaw
counter-clockwise; what ``--reference-offset X,Y,YAW`` and a base_link -> frame
transform give). The robot and its wheels do not change when the reference moves, so
everything that meets a reference first moves it onto base_link: a pose ``B = R M^-1``
(:meth:`Mount.base_poses`), a motion ``M D M^-1`` (:meth:`Mount.base_motions`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from diffdrive_odom.core.geometry.se2 import conjugate

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Mount:
    """The pose of the reference's frame in base_link: ``x``, ``y`` [m], ``yaw`` [rad]."""

    x: float = 0.0
    y: float = 0.0
    yaw: float = 0.0

    def __post_init__(self) -> None:
        if not all(math.isfinite(v) for v in (self.x, self.y, self.yaw)):
            raise ValueError(f"a mount must be finite, got ({self.x}, {self.y}, {self.yaw})")

    @property
    def lever(self) -> float:
        """The reference's distance from base_link's origin [m]."""
        return math.hypot(self.x, self.y)

    def base_poses(self, poses: FloatArray) -> FloatArray:
        """(n, 3) reference poses ``R`` as base_link's, ``R M^-1`` (headings kept continuous)."""
        heading = poses[:, 2] - self.yaw
        c, s = np.cos(heading), np.sin(heading)
        return np.column_stack((poses[:, 0] - c * self.x + s * self.y,
                                poses[:, 1] - s * self.x - c * self.y, heading))

    def base_pose(self, x: float, y: float, yaw: float) -> tuple[float, float, float]:
        """One reference pose as base_link's (for a stream: the online estimate's input)."""
        bx, by, heading = self.base_poses(np.array([[x, y, yaw]], dtype=float))[0]
        return float(bx), float(by), float(heading)

    def base_motions(self, motions: FloatArray) -> FloatArray:
        """(n, 3) motions of the reference's frame, each in its own start frame, as base_link's."""
        return conjugate(motions, self.x, self.y, self.yaw)

    def text(self, sigma: tuple[float, float, float] | None = None) -> str:
        """``x -0.120 m, y 0.200 m, yaw 150.00 deg``, each with ``+- sigma`` when given."""
        sig = sigma or (math.nan,) * 3
        parts = []
        for name, value, s, unit, scale, digits in (
                ("x", self.x, sig[0], "m", 1.0, 4), ("y", self.y, sig[1], "m", 1.0, 4),
                ("yaw", self.yaw, sig[2], "deg", math.degrees(1.0), 2)):
            pm = f" +- {s * scale:.{digits}f}" if math.isfinite(s) else ""
            parts.append(f"{name} {value * scale:+.{digits}f}{pm} {unit}")
        return ", ".join(parts)


AXLE = Mount()  # the reference on base_link itself (a simulator's truth, OptiOdom's runs)

