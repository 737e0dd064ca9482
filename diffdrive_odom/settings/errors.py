"""The parameter error a user sees, and the one conversion from the core's ConfigError.

A core object raises :class:`~diffdrive_odom.core.errors.ConfigError` naming its own
field; the parameter layer turns it into a :class:`ParameterError` naming the ROS
parameter (one line at start, or the reason of a refused ``ros2 param set``).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping
from contextlib import contextmanager

from diffdrive_odom.core.errors import ConfigError


class ParameterError(ValueError):
    """A parameter value that cannot be used; ``name`` is the ROS parameter's name."""

    def __init__(self, name: str, reason: str) -> None:
        super().__init__(f"invalid parameter '{name}': {reason}")
        self.name = name
        self.reason = reason


def one_of(name: str, value: str, choices: Iterable[str]) -> str:
    """``value`` if it is one of ``choices``, else the ParameterError that lists them."""
    options = tuple(choices)  # once: an iterator would be spent by the test
    if value not in options:
        raise ParameterError(name, f"must be one of {', '.join(options)}, got {value!r}")
    return value


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
