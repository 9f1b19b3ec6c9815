"""The words of a refused configuration: per bad value, the dotted field, why, the value as it
came (shortened when long; NaN said as such: a comparison with it fails, so a bound alone would
name the wrong fault) and where it came from (the environment variable, or the file), so that
the operator finds the line to mend without guessing."""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from c3_matcher.config_sources import ENV_PREFIX, unknown_key_reason

__all__ = ["unparsed_env", "validation_problems"]

MAX_SHOWN = 60
"""A refused value's ``repr`` is cut to this many characters (a JSON table set by mistake)."""
_COLLECTIONS = {"tuple_type": "list", "list_type": "list", "dict_type": "table"}


@dataclass(frozen=True, slots=True)
class _ValueOrigins:
    """Where the values being validated came from: the environment ``env`` (its ``C3_MATCHER_``
    variables), else the tables ``data`` read from ``file`` (less what the environment
    replaced); a value in neither (a Python caller's, a strategy's defaults) has none."""

    env: Mapping[str, str]
    file: Path | None
    data: Mapping[str, Any]

    def of(self, loc: Sequence[object]) -> str | None:
        """``set by VARIABLE`` or ``set in FILE`` for the value at ``loc``; None when unknown. A
        variable naming the setting (or a key below it) replaced the file's value there; a
        section's JSON sets the key unless the file still holds it (the JSON leaves it out)."""
        path = [str(part) for part in loc]
        named = sorted(
            (len(parts), key)
            for key in self.env
            if key.upper().startswith(ENV_PREFIX)
            and (parts := key[len(ENV_PREFIX) :].lower().split("__")) == path[: len(parts)]
        )
        in_file = self.file is not None and _holds(self.data, path)
        if named and (named[-1][0] > 1 or len(path) == 1 or not in_file):
            return f"set by {named[-1][1]}"
        return f"set in {self.file}" if in_file else None


def _holds(data: Any, path: Sequence[str]) -> bool:
    """Whether ``data`` gives the value at ``path``: every key found down to it, or a value that
    is no table or list above it (the file's ``providers = "cpu"`` for ``providers.0``)."""
    for part in path:
        if isinstance(data, Mapping):
            if part not in data:
                return False
            data = data[part]
        elif isinstance(data, list) and part.isdigit() and int(part) < len(data):
            data = data[int(part)]
        else:
            return True
    return True


def validation_problems(
    exc: ValidationError,
    env: Mapping[str, str] | None = None,
    file: Path | None = None,
    data: Mapping[str, Any] | None = None,
) -> list[tuple[str, str]]:
    """(dotted field, reason) per validation error, the reason naming the value refused and
    where it was set when known: the variable of ``env`` that sets it, else ``file`` when its
    tables ``data`` (less what ``env`` replaced) hold it. A key no section has is named as a
    misspelling, as an unknown environment variable is; a word where a list or table belongs
    (``C3_MATCHER_ENGINES__PROVIDERS=cpu``) is told the form it takes."""
    origins = _ValueOrigins(env or {}, file, data or {})
    problems = []
    for error in exc.errors():  # a misspelt key is said as in the environment: the key alone
        origin = None if error["type"] == "extra_forbidden" else origins.of(error["loc"])
        reason = _reason(error) + (f", {origin}" if origin else "")
        problems.append((".".join(str(p) for p in error["loc"]) or "(root)", reason))
    return problems


def _reason(error: Any) -> str:
    """Why ``error`` (one of pydantic's) refused its value, with the value as it came."""
    if error["type"] == "extra_forbidden":
        return unknown_key_reason(error["loc"])
    value = error.get("input")
    got = f"got {_shown(value)}"
    kind = _COLLECTIONS.get(error["type"])
    if kind is not None and isinstance(value, str):
        example = '["a", "b"]' if kind == "list" else '{"key": 1}'
        return f"{error['msg']}, {got}: give a {kind}, e.g. {example} (in the environment, as JSON)"
    if _is_nan(value):  # every comparison with NaN fails: the bound named would mislead
        return f"not a number (NaN), {got}"
    return f"{error['msg']}, {got}"


def _shown(value: Any) -> str:
    """``repr(value)``, cut to ``MAX_SHOWN`` characters."""
    text = repr(value)
    return text if len(text) <= MAX_SHOWN else f"{text[: MAX_SHOWN - 3]}..."


def _is_nan(value: Any) -> bool:
    """Whether ``value`` is NaN: a float, or text as the environment gives it (``nan``)."""
    if isinstance(value, str):
        try:
            value = float(value)
        except ValueError:
            return False
    return isinstance(value, float) and math.isnan(value)


def unparsed_env(exc: Exception, env: Mapping[str, str]) -> list[tuple[str, str]]:
    """(variables, reason) for an environment value that pydantic-settings could not parse
    before validation (``C3_MATCHER_MATCHER__OPTIONS=not json``, or JSON nested too deep): the
    section's variable (``C3_MATCHER_MATCHER``) or its keys' (``C3_MATCHER_MATCHER__X``)."""
    text = str(exc)
    match = re.search(r'field "([a-z_]+)"', text)
    section = f"{ENV_PREFIX}{match.group(1).upper()}" if match else ENV_PREFIX
    named = sorted(k for k in env if k.upper() == section or k.upper().startswith(f"{section}__"))
    variables = ", ".join(named) or "environment"
    return [(variables, f"not valid JSON for a table or list value ({exc.__cause__ or text})")]
