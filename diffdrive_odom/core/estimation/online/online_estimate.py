"""The online geometry estimate as it is published: a snapshot, its layout, its test.

Apart from the filter (:mod:`~diffdrive_odom.core.estimation.online.online_geometry`) because
the node's ``~/geometry_estimate`` and ``/diagnostics``, ``replay``'s report, the demo
and the benchmarks read it without running a filter: :class:`OnlineEstimate` (in the
ratios and in diff_drive_controller's multipliers), :data:`FIELDS` (the message's
layout) and :data:`CHI2_2DOF_3SIGMA` (where the configured geometry is outside).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

from diffdrive_odom.core.estimation.online.online_scale import ScaleEstimate

__all__ = ["CHI2_2DOF_3SIGMA", "FIELDS", "OnlineEstimate"]

# Chi-square with 2 degrees of freedom at the two-sided 3-sigma level (99.73 %):
# -2 ln(1 - 0.9973002).
CHI2_2DOF_3SIGMA = -2.0 * math.log(1.0 - math.erf(3.0 / math.sqrt(2.0)))
# The layout of ``~/geometry_estimate`` (std_msgs/Float64MultiArray, one dimension
# labelled with these names, comma-separated): one value each, in this order.
FIELDS = (
    "determined",  # 1.0 once turned min_turn each way, else 0.0
    "left_wheel_radius_multiplier", "left_wheel_radius_multiplier_stddev",
    "right_wheel_radius_multiplier", "right_wheel_radius_multiplier_stddev",
    "wheel_separation_multiplier", "wheel_separation_multiplier_stddev",
    "ratio_right", "ratio_left",  # r_R / b, r_L / b [1]
    "ratio_right_variance", "ratio_covariance", "ratio_left_variance",
    "gyro_bias", "gyro_bias_stddev",  # rad/s
    "mahalanobis2",  # the configured geometry's, over the two ratios
    "outside",  # 1.0 when determined and mahalanobis2 > CHI2_2DOF_3SIGMA
    "turned_left", "turned_right", "distance",  # rad, rad, m over counted windows
    "steps", "excluded_slip", "excluded_standstill", "excluded_no_gyro", "excluded_outlier",
)


@dataclass(frozen=True)
class OnlineEstimate:
    """A snapshot of the estimate, in the ratios and in ddc's multipliers.

    ``ratios`` ``(r_R/b, r_L/b)`` [1/1] and their 2x2 ``covariance`` (row-major);
    ``multipliers`` ``(left, right, separation)`` with the configured mean radius held,
    ``stddevs`` their 1-sigma; ``mahalanobis2``: the configured geometry's squared
    distance from the estimate over the two ratios; ``outside``: determined and beyond
    :data:`CHI2_2DOF_3SIGMA`. ``turned``: radians turned (left, right) over counted
    windows; ``steps``: moving steps counted; ``excluded``: by reason (:data:`EXCLUDED`).
    """

    determined: bool
    ratios: tuple[float, float]
    covariance: tuple[float, float, float, float]
    bias: float
    bias_stddev: float
    multipliers: tuple[float, float, float]
    stddevs: tuple[float, float, float]
    mahalanobis2: float
    outside: bool
    turned: tuple[float, float]
    distance: float
    steps: int
    windows: int
    excluded: Mapping[str, int]
    applied: bool = False  # the odometry integrates with it (apply)
    scale: ScaleEstimate | None = None  # with a reference topic only

    def block(self) -> str:
        """The estimate as the three lines of a parameter YAML (to paste), with 1-sigma."""
        names = ("left_wheel_radius_multiplier", "right_wheel_radius_multiplier",
                 "wheel_separation_multiplier")
        return "\n".join(f"{n}: {m:.5f}  # +- {s:.5f} (1 sigma)"
                         for n, m, s in zip(names, self.multipliers, self.stddevs, strict=True))

    def values(self) -> tuple[float, ...]:
        """The estimate as :data:`FIELDS` says, one float each."""
        (ml, mr, mb), (sl, sr, sb) = self.multipliers, self.stddevs
        a, c, _, d = self.covariance
        ex = self.excluded
        return (float(self.determined), ml, sl, mr, sr, mb, sb, *self.ratios, a, c, d,
                self.bias, self.bias_stddev, self.mahalanobis2, float(self.outside),
                *self.turned, self.distance, float(self.steps),
                *(float(ex.get(k, 0)) for k in ("slip", "standstill", "no_gyro", "outlier")))

    def line(self) -> str:
        """One line: the multipliers with their sigma, the excitation, determined or not."""
        ml, mr, mb = self.multipliers
        sl, sr, sb = self.stddevs
        state = ("determined" if self.determined else "not yet determined (turn both ways)")
        state += ", applied" if self.applied else ""
        return (f"left {ml:.5f} +- {sl:.5f}, right {mr:.5f} +- {sr:.5f}, separation "
                f"{mb:.5f} +- {sb:.5f} (mean radius held); turned {self.turned[0]:.1f} rad "
                f"left, {self.turned[1]:.1f} rad right over {self.distance:.1f} m: {state}")
