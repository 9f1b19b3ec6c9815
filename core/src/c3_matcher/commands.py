"""The command line's extension point: ``CommandRegistry``, handed to every plugin's
``c3_matcher_register_commands`` hook (datasette's ``register_commands``, tox's ``tox_add_option``).

The core registers its flight commands (``plugins``, ``config``, ``match``,
``engines list|verify``) through the same registry; ground tooling (``c3-matcher-tools``) and
third parties add theirs, or subcommands of a group such as ``engines``. A leaf command sets its
handler with ``parser.set_defaults(handler=run)``; ``run(args, context) -> exit status``, where
``context`` is the process's ``c3_matcher.context.CommandContext`` (settings, plugin host, output
streams): the plugins are discovered once per process, by the command line, and every handler
shares them.
"""

from __future__ import annotations

import argparse
import math
import re
import sys
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from c3_matcher.terminal_text import without_controls

if TYPE_CHECKING:
    from c3_matcher.config import C3Settings

__all__ = [
    "EXIT_FAILURE",
    "EXIT_INSUFFICIENT",
    "EXIT_OK",
    "EXIT_USAGE",
    "CommandRegistry",
    "add_max_keypoints_option",
    "bounded_float",
    "bounded_int",
    "keypoint_budget",
    "with_keypoint_budget",
]

EXIT_OK, EXIT_FAILURE, EXIT_USAGE, EXIT_INSUFFICIENT = 0, 1, 2, 3


class DefaultsHelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Help that shows each option's default, unless the text already says it or there is none
    to show (None, False)."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        if "default" in text or action.default in (None, False, argparse.SUPPRESS):
            return text
        return super()._get_help_string(action)


_UNSIGNED = r"(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?"
_NEGATIVE_NUMBERS = re.compile(rf"^-{_UNSIGNED}(,-?{_UNSIGNED})*$")


class UsageParser(argparse.ArgumentParser):
    """An argument parser whose usage errors exit 2 with one line on stderr and whose help shows
    the defaults."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("formatter_class", DefaultsHelpFormatter)
        super().__init__(*args, **kwargs)
        # argparse's own rule (a word that looks like a negative number is a value, while no
        # option looks like one), extended to lists: ``--attitude -3,1,90`` is a negative roll
        self._negative_number_matcher = _NEGATIVE_NUMBERS

    def error(self, message: str) -> None:  # type: ignore[override]
        print(f"{self.prog}: error: {without_controls(message)}", file=sys.stderr)
        raise SystemExit(EXIT_USAGE)


class CommandRegistry:
    """Commands (and groups of subcommands) of ``c3-matcher``, on argparse subparsers."""

    def __init__(self, subparsers: Any, dest: str = "command") -> None:
        self._sub = subparsers
        self._dest = dest
        self._groups: dict[str, CommandRegistry] = {}
        self._names: set[str] = set()

    def add(self, name: str, *, help: str, **kwargs: Any) -> argparse.ArgumentParser:
        """A new command's parser; the caller adds arguments and ``set_defaults(handler=...)``."""
        if name in self._names:
            raise ValueError(f"command {name!r} is registered twice")
        self._names.add(name)
        parser: argparse.ArgumentParser = self._sub.add_parser(name, help=help, **kwargs)
        return parser

    def group(self, name: str, *, help: str = "") -> CommandRegistry:
        """The registry of the subcommands of group ``name`` (created on first use)."""
        if name not in self._groups:
            parser = self.add(name, help=help)
            dest = f"{name}_command"
            sub = parser.add_subparsers(dest=dest, required=True, parser_class=UsageParser)
            self._groups[name] = CommandRegistry(sub, dest)
        return self._groups[name]


def bounded_int(low: int = 1, high: int | None = None) -> Callable[[str], int]:
    """An argparse type: an int in [low, high], else a usage error (exit 2); argparse names the
    option."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if value < low or (high is not None and value > high):
            bound = f">= {low}" if high is None else f"in [{low}, {high}]"
            raise argparse.ArgumentTypeError(f"must be {bound}, got {value}")
        return value

    return parse


def bounded_float(
    low: float = -math.inf, high: float = math.inf, *, above: bool = False
) -> Callable[[str], float]:
    """An argparse type: a finite float in [low, high] (in (low, high] when ``above``), else a
    usage error (exit 2); argparse names the option."""
    bounds = _bounds_text(low, high, above)

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        inside = (value > low if above else value >= low) and value <= high
        if not (math.isfinite(value) and inside):
            raise argparse.ArgumentTypeError(f"must be finite{bounds}, got {value}")
        return value

    return parse


def _bounds_text(low: float, high: float, above: bool) -> str:
    """`` and >= 0``, `` and in (0, 1]``, ... for :func:`bounded_float`'s message."""
    if high == math.inf:
        return "" if low == -math.inf else f" and {'>' if above else '>='} {low:g}"
    if low == -math.inf:
        return f" and <= {high:g}"
    return f" and in {'(' if above else '['}{low:g}, {high:g}]"


def add_max_keypoints_option(
    p: argparse.ArgumentParser,
    help: str = "override [matcher] max_keypoints",
    **kwargs: Any,
) -> None:
    """``--max-keypoints N``: a keypoint budget per image, in ``KEYPOINT_BUDGET_RANGE``."""
    from c3_matcher.config import KEYPOINT_BUDGET_RANGE

    low, high = KEYPOINT_BUDGET_RANGE
    p.add_argument(
        "--max-keypoints",
        type=keypoint_budget(),
        default=None,
        help=f"{help} ({low}..{high})",
        **kwargs,
    )


def with_keypoint_budget(settings: C3Settings, budget: int) -> C3Settings:
    """``settings`` with a command's ``--max-keypoints``: the run's budget above every one the
    configuration sets, ``[matcher] max_keypoints`` and each strategy's own ``max_keypoints``
    option alike (within the configuration the strategy's option is the more specific and wins;
    a command-line flag is above the configuration)."""
    tables = {
        name: {k: v for k, v in table.items() if k != "max_keypoints"}
        for name, table in settings.matcher.options.items()
    }
    matcher = settings.matcher.model_copy(update={"max_keypoints": budget, "options": tables})
    return settings.model_copy(update={"matcher": matcher})


def keypoint_budget() -> Callable[[str], int]:
    """An argparse type: a keypoint budget in ``KEYPOINT_BUDGET_RANGE``."""
    from c3_matcher.config import KEYPOINT_BUDGET_RANGE

    return bounded_int(*KEYPOINT_BUDGET_RANGE)
