"""Text for a terminal: :func:`without_controls`, which every line a command prints goes
through (``CommandContext`` and the few error lines printed before one exists), so that no name
or metadata from a hostile file moves the cursor, erases a line or retitles the window."""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType

__all__ = ["without_controls"]

_CONTROL_ESCAPES: Mapping[int, str] = MappingProxyType(
    {
        code: f"\\x{code:02x}"
        for code in (*range(0x20), *range(0x80, 0xA0))
        if chr(code) not in "\n\t"
    }
)
"""The C0 and C1 control characters but newline and tab, each to its escape (ESC: ``\\x1b``)."""


def without_controls(text: str) -> str:
    """``text`` with its C0 and C1 control characters but newline and tab as their escapes
    (``\\x1b``): as a line for a terminal, which then obeys none of them."""
    return text.translate(_CONTROL_ESCAPES)
