"""The error every core object raises for a setting that cannot work, in one place.

Core objects (geometry, encoders, estimator, limits, routes, sim) raise
:class:`ConfigError` naming their own field; the settings layer
(:mod:`diffdrive_odom.settings.errors`) turns it into the ``ParameterError`` that names
the ROS parameter, which is what a user sees.
"""

from __future__ import annotations


class ConfigError(ValueError):
    """A setting of a core object that cannot work; ``field`` names it."""

    def __init__(self, field: str, reason: str) -> None:
        super().__init__(f"{field}: {reason}")
        self.field = field
        self.reason = reason
