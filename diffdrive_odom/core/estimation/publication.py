"""What the odometry node and ``replay`` publish for one pose: one rule, so the two never differ.

Given the pipeline's estimate (after :class:`~diffdrive_odom.core.estimation.pipeline.Outcome` says
``publish``), :func:`publication` returns the pose, twist and covariances to publish,
or a :class:`Refusal` with the reason when any of them is not finite (never sent:
a NaN in odometry poisons every consumer downstream). Pure Python.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from diffdrive_odom.core.estimation.pipeline import ReadingPipeline
from diffdrive_odom.core.geometry.integration import Pose2D

NON_FINITE = "non_finite_output"  # the refusal's code (the node's throttle key)


@dataclass(frozen=True, slots=True)
class Publication:
    """One pose as published: pose, twist and the 6x6 row-major covariances."""

    pose: Pose2D
    linear: float
    angular: float
    pose_covariance: Sequence[float]
    twist_covariance: Sequence[float]


@dataclass(frozen=True, slots=True)
class Refusal:
    """Why a pose is not published: ``code`` to count or throttle by, ``reason`` to say."""

    code: str
    reason: str


ODOMETRY_REFUSED = Refusal(NON_FINITE, "non-finite odometry suppressed")
COVARIANCE_REFUSED = Refusal(NON_FINITE, "non-finite covariance suppressed")


def _finite_odometry(pose: Pose2D, linear: float, angular: float) -> bool:
    return math.isfinite(pose.x + pose.y + pose.theta + linear + angular)


def publication(
    pose: Pose2D, linear: float, angular: float,
    pose_covariance: Sequence[float], twist_covariance: Sequence[float],
) -> Publication | Refusal:
    """What to publish, or the refusal: pose and twist first, then the covariances."""
    if not _finite_odometry(pose, linear, angular):
        return ODOMETRY_REFUSED
    if not math.isfinite(sum(pose_covariance) + sum(twist_covariance)):
        return COVARIANCE_REFUSED
    return Publication(pose, linear, angular, pose_covariance, twist_covariance)


def pipeline_publication(pipeline: ReadingPipeline) -> Publication | Refusal:
    """:func:`publication` of the pipeline's current estimate and covariances."""
    est = pipeline.estimator
    pose, linear, angular = est.pose, est.linear, est.angular
    if not _finite_odometry(pose, linear, angular):  # before the covariance, made from the pose
        return ODOMETRY_REFUSED
    return publication(pose, linear, angular, *pipeline.covariances())
