"""The configuration file a command line names: ``--config FILE`` (or ``--config=FILE``) taken
out of it before argparse reads the rest, wherever it stands, so that ``c3-matcher config
--config c3.toml`` reads the file as ``c3-matcher --config c3.toml config`` does, and a second
one is refused rather than one of the two dropped unsaid."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from c3_matcher.errors import ConfigurationError

__all__ = ["CONFIG_FLAG", "split_config"]

CONFIG_FLAG = "--config"
"""The option naming the configuration file, taken out of a command line by :func:`split_config`."""


def split_config(argv: Sequence[str]) -> tuple[list[str], Path | None]:
    """Take ``--config FILE`` / ``--config=FILE`` out of ``argv`` wherever it is (before or
    after the subcommand), and before the subcommand any abbreviation of it argparse read as it
    (``--conf FILE``; the top-level parser itself now takes none, so that no form names a file
    this does not see). A second one is refused (``ConfigurationError`` naming both files):
    one file is read, and taking either would drop the other's settings unsaid. A ``--config``
    without a value is left for the parser to refuse, by its full name."""
    rest: list[str] = []
    configs: list[str] = []
    items = list(argv)
    command_named = False
    i = 0
    while i < len(items):
        arg = items[i]
        if arg == "--":
            rest.extend(items[i:])
            break
        name, equals, value = arg.partition("=")
        if _names_config(name, command_named):
            if equals:
                configs.append(value)
            elif i + 1 < len(items) and not items[i + 1].startswith("--"):
                configs.append(items[i + 1])
                i += 1
            else:
                rest.append(CONFIG_FLAG)
            i += 1
            continue
        command_named = command_named or not arg.startswith("-")
        rest.append(arg)
        i += 1
    if len(configs) > 1:
        files = " and ".join(repr(c) for c in configs)
        why = f"given {len(configs)} times ({files}), but one configuration file is taken"
        raise ConfigurationError("command line", [(CONFIG_FLAG, f"{why}: merge them into one")])
    return rest, Path(configs[0]) if configs else None


def _names_config(name: str, command_named: bool) -> bool:
    """Whether the option ``name`` is ``--config``: in full anywhere, or before the command's
    name (where the other options, ``--help`` and ``--version``, start otherwise) cut short to
    ``--c`` or more, as argparse read such a prefix."""
    if name == CONFIG_FLAG:
        return True
    return not command_named and len(name) >= len("--c") and CONFIG_FLAG.startswith(name)
