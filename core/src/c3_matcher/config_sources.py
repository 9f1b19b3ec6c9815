"""Where the configuration comes from, read without side effects: the TOML file ``--config``
names and the environment variables (``C3_MATCHER_``, ``__`` between levels, upper case as
documented) of a given mapping or ``os.environ``, never changed; unknown keys named so that a
typo does not pass silently, and so is a variable spelt in another case (two spellings of one
setting would otherwise both be read, the later one winning); a value the environment gives
replaces the file's whole (a table too), the file's values it leaves out named
(``ReplacedByEnvironment``); a relative path made absolute against the working
directory (a file's and the environment's, as a command's path flags are read), so that
``config`` and every message name the place meant."""

from __future__ import annotations

import difflib
import json
import os
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final, get_args

from pydantic import BaseModel, ConfigDict, ValidationInfo, field_validator
from pydantic_settings import (
    BaseSettings,
    EnvSettingsSource,
    InitSettingsSource,
    PydanticBaseSettingsSource,
)
from pydantic_settings.sources.utils import parse_env_vars

from c3_matcher.errors import ConfigurationError
from c3_matcher.file_kinds import special_kind
from c3_matcher.json_text import NESTED_TOO_DEEP, loads_json

__all__ = [
    "ENV_PREFIX",
    "PROCESS_SWITCHES",
    "REPLACED_KIND",
    "UNKNOWN_SETTING",
    "GivenSectionsSource",
    "MappingEnvSource",
    "ReplacedByEnvironment",
    "ReplacedValue",
    "SettingsSection",
    "read_toml",
    "unknown_env_keys",
    "unknown_key_reason",
    "without_env_values",
]

ENV_PREFIX = "C3_MATCHER_"
UNKNOWN_SETTING = "unknown setting (check the spelling)"
ENGINE_FILE_KEYS: Final = ("disk_weights_path",)
"""``[matcher]`` keys the component specification names for an engine file, which this product
finds in ``[engines] directory`` by its manifest instead: refused, saying so."""
_ENGINE_FILE = (
    "not a setting: every strategy's engines are found in [engines] directory by their "
    "manifests (c3-matcher engines build writes them there); set [engines] directory to the "
    "folder that holds them"
)
PROCESS_SWITCHES: Final = ("TOOLS_NO_PYPROJ", "TOOLS_NO_RASTERIO", "TRACEBACK")
"""The ``C3_MATCHER_<NAME>`` variables that are switches of a process, not settings: the
command's traceback on an internal error, the ground tools' hand-written fallbacks. Any other
name without ``__`` must be a section (its JSON)."""


class MappingEnvSource(EnvSettingsSource):
    """A settings class's environment source reading ``env`` (default: ``os.environ``, only
    read) that refuses a ``C3_MATCHER_`` variable naming no setting and no process switch
    (``ConfigurationError``, ``unknown_env_keys``) when it is read."""

    def __init__(
        self, settings_cls: type[BaseSettings], env: Mapping[str, str] | None = None
    ) -> None:
        self._given = dict(os.environ if env is None else env)
        super().__init__(settings_cls)

    def _load_env_vars(self) -> Mapping[str, str | None]:
        return parse_env_vars(
            self._given, self.case_sensitive, self.env_ignore_empty, self.env_parse_none_str
        )

    def __call__(self) -> dict[str, Any]:
        unknown = unknown_env_keys(self.settings_cls, self._given)
        if unknown:
            raise ConfigurationError("environment", unknown)
        return super().__call__()


class GivenSectionsSource(InitSettingsSource):
    """A settings class's keyword arguments, each section given as its model
    (``C3Settings(engines=EngineSettings(...))``) read as the fields its caller set
    (``model_dump(exclude_unset=True)``), so that the environment's keys merge into it as into
    its dict form: pydantic-settings merges tables key by key but replaces a model whole by the
    environment's table, losing every field the caller set."""

    @classmethod
    def replacing(cls, source: PydanticBaseSettingsSource) -> PydanticBaseSettingsSource:
        """``source`` (pydantic-settings' keyword arguments source) read as this one."""
        if not isinstance(source, InitSettingsSource):
            return source
        return cls(source.settings_cls, source.init_kwargs)

    def __call__(self) -> dict[str, Any]:
        fields = self.settings_cls.model_fields
        return {
            key: value.model_dump(exclude_unset=True)
            if key in fields and _is_model_of(value, fields[key].annotation)
            else value
            for key, value in super().__call__().items()
        }


def _is_model_of(value: Any, annotation: Any) -> bool:
    """Whether ``value`` is a model of the section's type ``annotation`` (one of another type is
    left for validation to refuse)."""
    return (
        isinstance(annotation, type)
        and issubclass(annotation, BaseModel)
        and isinstance(value, annotation)
    )


MAX_TOML_BYTES = 1 << 20
"""A configuration file larger than this is refused unread (``--config`` naming an image), not
read into memory whole; a device (``/dev/zero``, a disk) or a FIFO is refused unopened."""


class SettingsSection(BaseModel):
    """A table of the configuration (``[matcher]``, ``[engines]``, ...): unknown keys refused,
    frozen, values read as a file or a shell means them."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    @field_validator("*", mode="before")
    @classmethod
    def _no_stand_ins(cls, value: Any, info: ValidationInfo) -> Any:
        """Refuse a boolean for a number (``tile_cache_size = true`` must not mean one tile) and
        an empty path (``Path("")`` is ``.``: ``C3_MATCHER_FDR__PATH=$UNSET`` must not pass);
        read a leading ``~`` in every path as the user's home, as a shell would, and a relative
        path against the working directory, made absolute here so that ``config`` and every
        message name the place it means."""
        field = cls.model_fields.get(info.field_name or "")
        types = set() if field is None else {field.annotation, *get_args(field.annotation)}
        if isinstance(value, bool) and {int, float} & types:
            raise ValueError(f"expected a number, got the boolean {str(value).lower()}")
        if value == "" and Path in types:
            raise ValueError("is empty: give a path, or remove the setting")
        if isinstance(value, str | Path) and Path in types:
            return _absolute(Path(value).expanduser())
        return value


def _absolute(path: Path) -> Path:
    """``path`` made absolute against the working directory (``ValueError`` when there is none
    to read: it was removed)."""
    try:
        return path.absolute()
    except OSError as exc:
        raise ValueError(
            f"{path} is relative to a working directory that is gone ({exc})"
        ) from None


def read_toml(toml_path: Path, source: str) -> dict[str, Any]:
    """The TOML file's tables; ``ConfigurationError`` (naming ``--config``) when it is no regular
    file (judged by ``stat``, never opened: a FIFO would be waited on for ever), missing,
    larger than ``MAX_TOML_BYTES``, not UTF-8 or not TOML (arrays or tables nested deeper than
    the parser's recursion allows included)."""
    special = special_kind(Path(toml_path))
    if special is not None:
        raise ConfigurationError(source, [("--config", f"is {special}, not a configuration file")])
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
            source, [("--config", f"unreadable TOML: {NESTED_TOO_DEEP}")]
        ) from None


def unknown_env_keys(
    settings_cls: type[BaseSettings], env: Mapping[str, str]
) -> list[tuple[str, str]]:
    """(variable, reason) for each ``C3_MATCHER_<SECTION>[__<KEY>]`` that names no setting of
    ``settings_cls`` and is no process switch (``PROCESS_SWITCHES``); a name that reads as a
    setting (single underscores, ``C3_MATCHER_ENGINES_PROVIDERS``; a key without its section,
    ``C3_MATCHER_STRATEGY``; a near miss, ``C3_MATCHER_ENGINE_DIR``) is told the variable
    meant, and so is one spelt in another case than the upper case documented."""
    sections = dict(settings_cls.model_fields)
    problems = []
    for key in env:
        name = key.upper()
        if not name.startswith(ENV_PREFIX):
            continue
        reason = _unknown(name[len(ENV_PREFIX) :].lower().split("__"), sections)
        if reason is None and key != name:
            reason = f"{UNKNOWN_SETTING}: did you mean {name}? (variables are upper case)"
        if reason is not None:
            problems.append((key, reason))
    return problems


def _unknown(parts: Sequence[str], sections: Mapping[str, Any]) -> str | None:
    """Why ``C3_MATCHER_<PARTS joined by __>`` names nothing read, or None when it names a
    section, a setting (or a key below one) or a process switch."""
    section = sections.get(parts[0])
    fields = getattr(section.annotation if section else None, "model_fields", {})
    if section is None and len(parts) == 1:
        return None if parts[0].upper() in PROCESS_SWITCHES else _not_a_switch(parts[0], sections)
    if section is None or (len(parts) > 1 and parts[1] not in fields):
        return unknown_key_reason(parts[:2])
    return None


def unknown_key_reason(loc: Sequence[object]) -> str:
    """Why the key at ``loc`` (section, key) is refused: a misspelling, or a key of the
    specification that this product replaced (``ENGINE_FILE_KEYS``)."""
    if len(loc) == 2 and loc[0] == "matcher" and loc[1] in ENGINE_FILE_KEYS:
        return _ENGINE_FILE
    return UNKNOWN_SETTING


def _not_a_switch(name: str, sections: Mapping[str, Any]) -> str:
    """Why ``C3_MATCHER_<NAME>`` (no ``__``, no section) is refused, with the setting it may
    have meant: a section and key joined by one underscore, a key without its section, or a
    near miss of either (``engine_dir``)."""
    variables = [
        (form, f"{ENV_PREFIX}{section.upper()}__{key.upper()}")
        for section, info in sections.items()
        for key in getattr(info.annotation, "model_fields", {})
        for form in (f"{section}_{key}", key)
    ]
    forms = [form for form, _ in variables]
    near = [name] if name in forms else difflib.get_close_matches(name, forms, 3, 0.7)
    meant = list(dict.fromkeys(variable for form, variable in variables if form in near))
    form = f"a setting is {ENV_PREFIX}<SECTION>__<KEY>, two underscores between section and key"
    if meant:
        return f"{UNKNOWN_SETTING}: did you mean {' or '.join(meant)}? ({form})"
    switches = ", ".join(ENV_PREFIX + s for s in PROCESS_SWITCHES)
    return f"{UNKNOWN_SETTING}: {form}, and the only other variables read are {switches}"


REPLACED_KIND: Final = "c3.config.file_values_replaced"
"""The kind of the WARNING record that names the file's values the environment left out."""


@dataclass(frozen=True, slots=True)
class ReplacedValue:
    """A value of the configuration file that no longer applies: the file sets ``key`` (dotted)
    to ``value``, and ``variable`` replaces the table holding it whole without giving it."""

    key: str
    value: Any
    variable: str


@dataclass(frozen=True, slots=True)
class ReplacedByEnvironment:
    """The values of the configuration ``file`` that the environment replaced (none: nothing of
    the file was left out, or no file)."""

    file: Path | None = None
    values: tuple[ReplacedValue, ...] = ()

    def line(self) -> str:
        """One line naming the file, each value left out and the variable that left it out."""
        named = "; ".join(f"{v.key} ({v.variable})" for v in self.values)
        return (
            f"{self.file}: these values of the file do not apply, a table set in the environment "
            f"replacing the file's whole: {named}; to keep one, give it in that variable too"
        )

    def fields(self) -> dict[str, list[str]]:
        """The dotted keys left out and the variable that left each out, as a record's fields."""
        return {
            "keys": [v.key for v in self.values],
            "variables": [v.variable for v in self.values],
        }

    def comments(self) -> str:
        """A TOML comment line per value left out, each ending in a newline, naming the file and
        the variable (in ASCII, control characters escaped as in JSON: a comment holds none)."""
        file = json.dumps(str(self.file))[1:-1]
        return "".join(
            f"# {v.key} = {json.dumps(v.value, default=str)} from {file}: "
            f"replaced by {v.variable}\n"
            for v in self.values
        )


def without_env_values(
    data: Mapping[str, Any], env: Mapping[str, str], file: Path | None = None
) -> tuple[dict[str, Any], ReplacedByEnvironment]:
    """``data`` (the tables of ``file``) less every value ``env`` sets, so that the environment's
    replaces it whole rather than being merged into it key by key: a variable naming a setting
    or a key below one (``C3_MATCHER_MATCHER__OPTIONS``, ``C3_MATCHER_MATCHER__OPTIONS__XFEAT``)
    takes the file's value at that place out, a table with all its keys; a section's JSON
    (``C3_MATCHER_MATCHER='{"options": ...}'``) takes out each setting it gives. The section's
    other settings still come from the file. Second: the file's values taken out that the
    environment does not give again (a key of a table it replaces without that key)."""
    out = _copied(data)
    replaced: list[ReplacedValue] = []
    for key, value in env.items():
        if not key.upper().startswith(ENV_PREFIX):
            continue
        path = key[len(ENV_PREFIX) :].lower().split("__")
        given = _json_object(value)
        if len(path) > 1:
            places = [(path, value if given is None else given)]
        else:
            places = [([path[0], k], v) for k, v in (given or {}).items()]
        for (*above, last), there in places:
            table: Any = out
            for part in above:
                table = table.get(part) if isinstance(table, dict) else None
            if isinstance(table, dict) and last in table:
                dotted = ".".join((*above, last))
                replaced += _left_out(table.pop(last), there, dotted, key)
    values = tuple(sorted(replaced, key=lambda v: (v.key, v.variable)))
    return out, ReplacedByEnvironment(file, values)


def _left_out(file_value: Any, given: Any, key: str, variable: str) -> list[ReplacedValue]:
    """Each value of ``file_value`` (at dotted ``key``) that ``given``, the value ``variable``
    sets in its place, does not set again."""
    if not isinstance(file_value, dict):
        return []
    out = []
    for name, value in file_value.items():
        dotted = f"{key}.{name}"
        if isinstance(given, dict) and name in given:
            out += _left_out(value, given[name], dotted, variable)
        elif isinstance(value, dict):
            out += _left_out(value, None, dotted, variable)
        else:
            out.append(ReplacedValue(dotted, value, variable))
    return out


def _copied(data: Mapping[str, Any]) -> dict[str, Any]:
    """``data`` with every table below it copied (the caller's is left as it is)."""
    return {k: _copied(v) if isinstance(v, Mapping) else v for k, v in data.items()}


def _json_object(value: str) -> dict[str, Any] | None:
    """``value`` read as a JSON object; None when it is not one (pydantic-settings then names
    the variable)."""
    try:
        given = loads_json(value)
    except ValueError:
        return None
    return given if isinstance(given, dict) else None
