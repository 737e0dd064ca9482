"""Message classes from type names (``pkg/msg/Type``), as bags and topic tables hold them."""

from __future__ import annotations

import importlib
from typing import Any


def message_class(type_name: str) -> Any:
    """``pkg/msg/Type`` -> the rclpy message class.

    Raises ImportError (ModuleNotFoundError) if the package is not installed here and
    AttributeError if it has no such type; ValueError if the name is not three parts.
    """
    pkg, kind, name = type_name.split("/")
    return getattr(importlib.import_module(f"{pkg}.{kind}"), name)
