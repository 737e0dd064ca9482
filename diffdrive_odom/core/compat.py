"""What the package needs from Python versions newer than its oldest (3.10).

Pure Python. ``enum.StrEnum`` arrived in 3.11; Ubuntu 22.04's Python is 3.10.
"""

from __future__ import annotations

import enum


class StrEnum(str, enum.Enum):
    """``enum.StrEnum`` on every Python: members are strings.

    ``str`` and formatting give the value, so a code reads ``too_fast`` in a log and
    keys a dict as that text.
    """

    def __str__(self) -> str:
        return str(self.value)

    def __format__(self, spec: str) -> str:
        return format(str(self.value), spec)
