"""Text for a terminal: :func:`without_controls`, which every line a command prints goes
through (``CommandContext`` and the few error lines printed before one exists), so that no name
or metadata from a hostile file moves the cursor, erases a line, retitles the window or shows
the rest of a line in reverse order."""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType

__all__ = ["without_controls"]

_BIDI_CONTROLS = (0x200E, 0x200F, 0x061C, *range(0x202A, 0x202F), *range(0x2066, 0x206A))
"""The bidirectional marks, embeddings, overrides and isolates: U+202E shows what follows it
right to left, so a file named ``photo\\u202egpj.exe`` reads as ``photoexe.jpg``."""

_CONTROL_ESCAPES: Mapping[int, str] = MappingProxyType(
    {
        code: f"\\x{code:02x}"
        for code in (*range(0x20), 0x7F, *range(0x80, 0xA0))
        if chr(code) not in "\n\t"
    }
    | {code: f"\\u{code:04x}" for code in _BIDI_CONTROLS}
)
"""The C0 and C1 control characters but newline and tab, and DEL, each to its escape (ESC:
``\\x1b``); the bidirectional controls to theirs (``\\u202e``)."""


def without_controls(text: str) -> str:
    """``text`` with its C0 and C1 control characters but newline and tab, DEL and the
    bidirectional controls as their escapes (``\\x1b``, ``\\u202e``): as a line for a
    terminal, which then obeys none of them."""
    return text.translate(_CONTROL_ESCAPES)
