"""Module attributes imported on first use (PEP 562), for the packages whose public names would
otherwise pull in heavy dependencies at import time."""

from __future__ import annotations

import importlib
from collections.abc import Mapping
from typing import Any

__all__ = ["load_export"]


def load_export(
    package: str, exports: Mapping[str, str], namespace: dict[str, Any], name: str
) -> Any:
    """``name`` from the module ``exports`` maps it to, imported now and kept in ``namespace``
    (the package's ``globals()``) so the next lookup is plain; ``AttributeError`` naming
    ``package`` when it exports no such name."""
    module = exports.get(name)
    if module is None:
        raise AttributeError(f"module {package!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    namespace[name] = value
    return value
