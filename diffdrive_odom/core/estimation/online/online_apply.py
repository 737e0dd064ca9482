"""Which geometry the steps integrate with: ``online_calibration: apply``'s one rule.

The pipeline (:mod:`~diffdrive_odom.core.estimation.pipeline`, so the node, replay and
the demo alike) asks :func:`geometry_in_use` before each reading: the applied estimate
(:attr:`~diffdrive_odom.core.estimation.online.online_geometry.OnlineGeometry.applied`) once
there is one, else the configured geometry. A switch falls between two steps: the pose
is never re-integrated, only the steps after it use the new geometry. The parameters
never change by themselves, and the cmd_vel node keeps its configured geometry (it
maps a commanded twist to wheel rates; a path follower closing its loop on the odometry
takes up the difference).
"""

from __future__ import annotations

from diffdrive_odom.core.estimation.online.online_geometry import OnlineGeometry
from diffdrive_odom.core.geometry.kinematics import Geometry
from diffdrive_odom.core.uncertainty.propagation import PoseUncertainty

__all__ = ["APPLIED_NOTE", "APPLY_FIELDS", "CONFIGURED_NOTE", "geometry_in_use"]

# ``~/geometry_estimate``'s fields for apply, after online_geometry's and online_scale's
# (fields are only ever appended): 1.0 while the odometry integrates with the estimate.
APPLY_FIELDS = ("applied",)

APPLIED_NOTE = ("online calibration: integrating with the estimate from now on (the "
                "parameters stay as set): ")
CONFIGURED_NOTE = "online calibration: integrating with the configured geometry again"


def geometry_in_use(online: OnlineGeometry | None, configured: Geometry,
                    uncertainty: PoseUncertainty | None) -> tuple[Geometry, str]:
    """The geometry the next steps integrate with, and a note when that changes.

    The applied estimate, else the configured one: the one rule for the node, replay
    and the demo (the pipeline asks before each reading, so a switch falls between two
    steps). The covariance follows: the applied estimate's ``S`` while it is in use,
    refreshed with it; a switch either way, and the estimate's scale becoming the
    reference's, folds the stretch before (:meth:`PoseUncertainty.switch_geometry`).
    """
    applied = None if online is None else online.applied
    note = ""
    if online is not None and (applied is None) != (online.in_use is None):
        online.in_use = applied
        note = (APPLIED_NOTE + online.estimate().line() if applied is not None
                else CONFIGURED_NOTE)
    rescaled = (online is not None and applied is not None
                and online.applied_scaled != online.in_use_scaled)
    if rescaled and online is not None:
        online.in_use_scaled = online.applied_scaled
    if uncertainty is not None:
        s = None if online is None or applied is None else online.applied_covariance
        if (s is None) != (uncertainty.geometry_covariance is None) or rescaled:
            # to or from the estimate, or its scale now the reference's: the error so far
            # was made with another S, folded in (the published covariance never drops)
            uncertainty.switch_geometry(s)
        elif s is not None:
            uncertainty.geometry_covariance = s
    return (configured if applied is None else applied), note
