"""Settings as a TOML document (``c3-matcher config``): :func:`to_toml`, which
``load_settings`` reads back, each setting's description above it as a comment, and a setting
left unset shown with the value that applies instead (:class:`Unset`), as a comment too."""

from __future__ import annotations

import re
import textwrap
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from c3_matcher.errors import InvalidInputError

__all__ = ["Unset", "to_toml"]


@dataclass(frozen=True)
class Unset:
    """A setting the configuration leaves unset, in :func:`to_toml`'s data: written as a comment
    holding ``value``, the value that applies instead, and ``by``, whose it is (``"xfeat's
    default"``), so that the document read back leaves it unset; a table of nothing else is
    written commented out whole."""

    value: Any
    by: str


_NO_TOML = "has no TOML form (`c3-matcher config --json` prints it)"
_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")
_TOML_ESCAPES = {
    '"': '\\"',
    "\\": "\\\\",
    "\b": "\\b",
    "\t": "\\t",
    "\n": "\\n",
    "\f": "\\f",
    "\r": "\\r",
}


def _toml_string(text: str, key: str) -> str:
    """``text`` as a TOML basic string, in ASCII (\\u / \\U escapes); ``key`` names it when a
    character has no TOML form (a lone surrogate: bytes that are not UTF-8)."""
    out = []
    for char in text:
        code = ord(char)
        if char in _TOML_ESCAPES:
            out.append(_TOML_ESCAPES[char])
        elif 0xD800 <= code <= 0xDFFF:
            raise InvalidInputError(key, f"{text!r} is not Unicode text: {_NO_TOML}")
        elif code < 0x20 or code >= 0x7F:
            out.append(f"\\u{code:04x}" if code <= 0xFFFF else f"\\U{code:08x}")
        else:
            out.append(char)
    return '"' + "".join(out) + '"'


def _toml_key(key: str, where: str) -> str:
    """``key`` bare when TOML allows it, else quoted (``a.b`` stays one key)."""
    return key if _BARE_KEY.fullmatch(key) else _toml_string(key, where)


def _toml_value(value: Any, key: str = "value") -> str:
    """``value`` as a TOML value (a table inside a list as an inline table); ``key`` (dotted)
    names it when it has no TOML form (a null inside a list or table)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        return repr(value)
    if isinstance(value, str):
        return _toml_string(value, key)
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v, f"{key}[{i}]") for i, v in enumerate(value)) + "]"
    if isinstance(value, dict):
        items = (
            f"{_toml_key(str(k), key)} = {_toml_value(v, f'{key}.{k}')}" for k, v in value.items()
        )
        return "{" + ", ".join(items) + "}"
    if value is None:
        raise InvalidInputError(key, f"null {_NO_TOML}")
    raise InvalidInputError(key, f"a {type(value).__name__} {_NO_TOML}")


def to_toml(data: dict[str, Any], notes: Mapping[str, str] | None = None) -> str:
    """``data`` (JSON-able: tables of scalars, lists and tables) as a TOML document that
    ``load_settings`` reads back; ``notes`` (by dotted key) become comment lines above their
    key or table; a ``None`` value (unset: the default applies) and an :class:`Unset` are
    written as comments. Keys TOML does not allow bare are quoted; ``InvalidInputError`` names
    a value TOML cannot express (a null inside a list)."""
    return _toml_table(data, notes or {}, "", ())


def _toml_table(
    data: dict[str, Any], notes: Mapping[str, str], prefix: str, path: tuple[str, ...]
) -> str:
    lines: list[str] = []
    tables: list[tuple[str, tuple[str, ...], dict[str, Any]]] = []
    for key, value in data.items():
        dotted = f"{prefix}{key}"
        note = notes.get(dotted)
        if isinstance(value, dict):
            tables.append((dotted, (*path, _toml_key(key, dotted)), value))
            continue
        if note:
            lines.extend(textwrap.wrap(note, 96, initial_indent="# ", subsequent_indent="# "))
        if value is None:
            lines.append(f"# {key}: unset, the default applies")
        elif isinstance(value, Unset):
            lines.append(_unset_line(key, value, dotted))
        else:
            lines.append(f"{_toml_key(key, dotted)} = {_toml_value(value, dotted)}")
    for name, table_path, table in tables:
        shown_only = bool(table) and all(isinstance(v, Unset) for v in table.values())
        lines.append(f"\n{'# ' if shown_only else ''}[{'.'.join(table_path)}]")
        note = notes.get(name)
        if note:
            lines.extend(textwrap.wrap(note, 96, initial_indent="# ", subsequent_indent="# "))
        lines.append(_toml_table(table, notes, f"{name}.", table_path).strip("\n"))
    return "\n".join(line for line in lines if line).strip("\n")


def _unset_line(key: str, unset: Unset, dotted: str) -> str:
    """The comment line of a setting left unset: the value that applies and whose it is
    (``# photometric = "none"  # unset: xfeat's default``: the part before the second ``#``
    set as it reads); a value TOML cannot express is only named whose it is."""
    if unset.value is not None:
        try:
            shown = _toml_value(unset.value, dotted)
        except InvalidInputError:
            pass
        else:
            return f"# {_toml_key(key, dotted)} = {shown}  # unset: {unset.by}"
    return f"# {key}: unset, {unset.by} applies"
