"""The two errors every configuration path raises, in one place.

Core objects (geometry, encoders, estimator, limits, routes, sim) raise
:class:`ConfigError` naming their own field; the parameter layer turns it into a
:class:`ParameterError` naming the ROS parameter, which is what a user sees (one line
at start, or the reason of a refused ``ros2 param set``).
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from contextlib import contextmanager


class ConfigError(ValueError):
    """A setting of a core object that cannot work; ``field`` names it."""

    def __init__(self, field: str, reason: str) -> None:
        super().__init__(f"{field}: {reason}")
        self.field = field
        self.reason = reason


class ParameterError(ValueError):
    """A parameter value that cannot be used; ``name`` is the ROS parameter's name."""

    def __init__(self, name: str, reason: str) -> None:
        super().__init__(f"invalid parameter '{name}': {reason}")
        self.name = name
        self.reason = reason


@contextmanager
def as_parameter_error(
    prefix: str = "", rename: Mapping[str, str] | None = None
) -> Iterator[None]:
    """Re-raise a core ConfigError as the ParameterError of parameter ``prefix + field``.

    ``rename`` maps a core field whose ROS parameter has another name to that full
    name (the one conversion, so no caller re-wraps errors by hand).
    """
    try:
        yield
    except ConfigError as err:
        name = (rename or {}).get(err.field, prefix + err.field)
        raise ParameterError(name, err.reason) from err
