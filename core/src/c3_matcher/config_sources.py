"""Where the configuration comes from, read without side effects: the TOML file and the
environment variables (``C3_MATCHER_``, ``__`` between levels) of a given mapping, never
``os.environ`` changed; unknown keys named so that a typo does not pass silently."""

from __future__ import annotations

import re
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from pydantic import ValidationError
from pydantic_settings import BaseSettings, EnvSettingsSource
from pydantic_settings.sources.utils import parse_env_vars

from c3_matcher.errors import ConfigurationError

__all__ = [
    "ENV_PREFIX",
    "UNKNOWN_SETTING",
    "MappingEnvSource",
    "read_toml",
    "unknown_env_keys",
    "unparsed_env",
    "validation_problems",
]

ENV_PREFIX = "C3_MATCHER_"
UNKNOWN_SETTING = "unknown setting (check the spelling)"


class MappingEnvSource(EnvSettingsSource):
    """A settings class's environment source reading ``env`` instead of ``os.environ``."""

    def __init__(self, settings_cls: type[BaseSettings], env: Mapping[str, str]) -> None:
        self._given = dict(env)
        super().__init__(settings_cls)

    def _load_env_vars(self) -> Mapping[str, str | None]:
        return parse_env_vars(
            self._given, self.case_sensitive, self.env_ignore_empty, self.env_parse_none_str
        )


MAX_TOML_BYTES = 1 << 20
"""A configuration file larger than this is refused unread (``--config`` naming an image, a
disk, ``/dev/zero``), not read into memory whole."""


def read_toml(toml_path: Path, source: str) -> dict[str, Any]:
    """The TOML file's tables; ``ConfigurationError`` (naming ``--config``) when it is missing,
    larger than ``MAX_TOML_BYTES``, not UTF-8 or not TOML (arrays or tables nested deeper than
    the parser's recursion allows included)."""
    try:
        with Path(toml_path).open("rb") as file:
            data = file.read(MAX_TOML_BYTES + 1)
        if len(data) > MAX_TOML_BYTES:
            raise ConfigurationError(
                source, [("--config", f"larger than {MAX_TOML_BYTES} bytes: not a configuration")]
            )
        return tomllib.loads(data.decode("utf-8"))
    except FileNotFoundError:
        raise ConfigurationError(source, [("--config", "file not found")]) from None
    except UnicodeDecodeError as exc:
        raise ConfigurationError(
            source, [("--config", f"not UTF-8 text (byte {exc.start}): {exc.reason}")]
        ) from None
    except (OSError, tomllib.TOMLDecodeError, ValueError) as exc:
        raise ConfigurationError(source, [("--config", f"unreadable TOML: {exc}")]) from None
    except RecursionError:
        raise ConfigurationError(
            source, [("--config", "unreadable TOML: nested too deep")]
        ) from None


def unknown_env_keys(
    settings_cls: type[BaseSettings], env: Mapping[str, str]
) -> list[tuple[str, str]]:
    """(variable, reason) for each ``C3_MATCHER_<SECTION>[__<KEY>]`` that names no setting of
    ``settings_cls``; a variable without ``__`` naming no section is a process switch
    (``C3_MATCHER_TRACEBACK``), not a setting."""
    sections = dict(settings_cls.model_fields)
    problems = []
    for key in env:
        if not key.upper().startswith(ENV_PREFIX):
            continue
        parts = key[len(ENV_PREFIX) :].lower().split("__")
        if len(parts) == 1 and parts[0] not in sections:
            continue  # a process switch, not a setting (C3_MATCHER_TRACEBACK, C3_MATCHER_TOOLS_*)
        section = sections.get(parts[0])
        annotation = section.annotation if section else None
        fields = getattr(annotation, "model_fields", {})
        if section is None or (len(parts) > 1 and parts[1] not in fields):
            problems.append((key, UNKNOWN_SETTING))
    return problems


def unparsed_env(exc: Exception, env: Mapping[str, str]) -> list[tuple[str, str]]:
    """(variables, reason) for an environment value that pydantic-settings could not parse
    before validation (``C3_MATCHER_MATCHER__OPTIONS=not json``, or JSON nested too deep): the
    section's variable (``C3_MATCHER_MATCHER``) or its keys' (``C3_MATCHER_MATCHER__X``)."""
    text = str(exc)
    match = re.search(r'field "([a-z_]+)"', text)
    section = f"{ENV_PREFIX}{match.group(1).upper()}" if match else ENV_PREFIX
    named = sorted(k for k in env if k.upper() == section or k.upper().startswith(f"{section}__"))
    field = ", ".join(named) or "environment"
    return [(field, f"not valid JSON for a table or list value ({exc.__cause__ or text})")]


_COLLECTIONS = {"tuple_type": "list", "list_type": "list", "dict_type": "table"}


def validation_problems(exc: ValidationError) -> list[tuple[str, str]]:
    """(dotted field, reason) per validation error; a key no section has is named as a
    misspelling, as an unknown environment variable is; a word where a list or table belongs
    (``C3_MATCHER_ENGINES__PROVIDERS=cpu``) is told the form it takes."""
    return [(".".join(str(p) for p in e["loc"]) or "(root)", _reason(e)) for e in exc.errors()]


def _reason(error: Any) -> str:
    if error["type"] == "extra_forbidden":
        return UNKNOWN_SETTING
    kind = _COLLECTIONS.get(error["type"])
    if kind is not None and isinstance(error.get("input"), str):
        example = '["a", "b"]' if kind == "list" else '{"key": 1}'
        got = f"{error['msg']}, got {error['input']!r}"
        return f"{got}: give a {kind}, e.g. {example} (in the environment, as JSON)"
    return str(error["msg"])
