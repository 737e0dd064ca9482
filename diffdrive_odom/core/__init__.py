"""The pure core, one sub-package per concern, in layers (setup.cfg's core contract).

From the bottom: ``errors``, ``compat`` and ``watchdog`` (the command timeout);
``geometry`` (SE(2), kinematics, the exact CIR step); ``uncertainty`` (covariance
through each step); ``estimation`` (readings to poses), ``commands`` (cmd_vel
limits), ``motion`` (routes, path following) and ``sim`` side by side; ``bulk``
(offline readings in blocks, the fast lane, the batch path); ``evaluation`` (metrics,
calibration) and ``health`` (diagnostics verdicts) on top. A sub-package imports only
those below it. May import the standard library, numpy and (lazily) scipy, and nothing
of this package outside ``diffdrive_odom.core``: never rclpy, message packages or bag
libraries.
"""

__all__ = [
           "bulk",
           "commands",
           "compat",
           "errors",
           "estimation",
           "evaluation",
           "geometry",
           "health",
           "motion",
           "sim",
           "uncertainty",
           "watchdog",
]
