"""The ``features build`` command a user is told to run (:func:`build_command`): the set of a
strategy, window and grid beside a store, built under the configuration of the command that
says it (:class:`GivenSettings`: its ``--config`` file, and the ``C3_MATCHER_*`` variables of
the settings that key a set, which no command line carries)."""

from __future__ import annotations

import os
import shlex
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from c3_matcher.config_sources import ENV_PREFIX

__all__ = ["NO_SETTINGS_GIVEN", "BuildCommand", "GivenSettings", "build_command", "given_settings"]

_SET_SECTIONS = ("matcher", "engines")
"""The sections whose settings key the set a flight asks for: its extractor engine and provider
(``[engines]``), its photometric normalisation and input rule, a strategy's options included
(``[matcher]``)."""


@dataclass(frozen=True)
class GivenSettings:
    """How a command was configured, as a command it prints must be: the ``--config`` file it
    was given, as given (None: none), and the names of the ``C3_MATCHER_*`` variables set of
    the settings that key a set (``[matcher]`` and ``[engines]``), sorted."""

    config: Path | None = None
    variables: tuple[str, ...] = ()

    def option(self) -> str:
        """The global option that gives the same file (``--config FILE ``), or nothing."""
        return "" if self.config is None else f"--config {shlex.quote(str(self.config))} "

    def environment(self) -> str:
        """What a command run under these settings needs of the environment, in words (nothing
        when no variable keys a set)."""
        if not self.variables:
            return ""
        named = ", ".join(self.variables)
        are, they, them = (
            ("is", "it", "it") if len(self.variables) == 1 else ("are", "they", "them")
        )
        return (
            f"run it where {named} {are} set as {they} {are} here: no command line carries {them}"
        )


NO_SETTINGS_GIVEN = GivenSettings()


def given_settings(config: Path | None, env: Mapping[str, str] | None = None) -> GivenSettings:
    """The settings a command was given: its ``--config`` file (``config``) and the variables
    of ``env`` (default: ``os.environ``, only read) that set a ``[matcher]`` or ``[engines]``
    setting, or the whole section."""
    environ = os.environ if env is None else env
    variables = sorted(
        name
        for name in environ
        if name.startswith(ENV_PREFIX)
        and name[len(ENV_PREFIX) :].lower().split("__")[0] in _SET_SECTIONS
    )
    return GivenSettings(config, tuple(variables))


@dataclass(frozen=True)
class BuildCommand:
    """A ``features build`` command: ``line``, what a script runs as it is, and ``note``, what
    the user must know to run it right, in words (empty: nothing). In text, the line with its
    note in brackets after it."""

    line: str
    note: str = ""

    def __str__(self) -> str:
        return f"{self.line} ({self.note})" if self.note else self.line


def build_command(
    given: Path,
    strategy: object,
    window: object,
    stride: object,
    flight_only: bool | None,
    settings: GivenSettings = NO_SETTINGS_GIVEN,
) -> BuildCommand:
    """The command that builds (or extracts again) the set of ``strategy`` with ``window`` px
    windows on a ``stride`` px grid beside the store ``given`` names (a store, or a flight
    directory, as the user gave it), under ``settings`` (its ``--config`` option; the variables
    it needs set, said in its note); ``flight_only``: with ``--flight-candidates``
    (only that flight's candidates' windows), None where that cannot be told (a set does not
    record it), which the command then says."""
    command = (
        f"c3-matcher {settings.option()}features build {shlex.quote(str(given))} "
        f"--strategy {strategy} --window {window} --stride {stride}"
        + (" --flight-candidates" if flight_only else "")
    )
    unknown = (
        "add --flight-candidates for only its candidates' windows"
        if given.is_dir()
        else "a set does not record whether it was built for a flight: for one that was, give "
        "that flight's directory and --flight-candidates instead of the store"
    )
    notes = [unknown if flight_only is None else "", settings.environment()]
    return BuildCommand(command, "; ".join(note for note in notes if note))
