"""The error every core object raises for a setting that cannot work, in one place.

Core objects (geometry, encoders, estimator, limits, routes, sim) raise
:class:`ConfigError` naming their own field; the settings layer
(:mod:`diffdrive_odom.settings.errors`) turns it into the ``ParameterError`` that names
the ROS parameter, which is what a user sees.
"""

from __future__ import annotations

import math
from collections.abc import Callable


class ConfigError(ValueError):
    """A setting of a core object that cannot work; ``field`` names it."""

    def __init__(self, field: str, reason: str) -> None:
        super().__init__(f"{field}: {reason}")
        self.field = field
        self.reason = reason


def require_finite_min(error: Callable[[str, str], Exception], field: str, value: float, *,
                       exclusive: bool = False) -> None:
    """Raise ``error`` naming ``field`` unless ``value`` is finite and >= 0 (> 0: ``exclusive``)."""
    if not (math.isfinite(value) and (value > 0.0 if exclusive else value >= 0.0)):
        raise error(field, f"must be finite and {'>' if exclusive else '>='} 0, got {value!r}")
