"""``CommandContext``: what every command handler receives beside its arguments, built once per
process by the command line (``c3_matcher.cli``) after the plugins are discovered."""

from __future__ import annotations

import argparse
import contextlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, TextIO

from c3_matcher.errors import OutputStreamError

if TYPE_CHECKING:
    from c3_matcher.config import C3Settings
    from c3_matcher.plugins.manager import PluginHost

__all__ = ["CommandContext", "Handler"]


@dataclass(frozen=True)
class CommandContext:
    """What every command handler receives beside its arguments: the validated configuration
    (``--config`` file < environment), the plugin host the command line was built from (its
    profile, strategies, engine specs: discovered once per process) and the streams a command
    writes its result (``stdout``) and its progress and diagnostics (``stderr``) to."""

    settings: C3Settings
    plugin_host: PluginHost
    stdout: TextIO
    stderr: TextIO

    def out(self, text: str = "") -> None:
        """One line of the command's result on ``stdout`` (``OutputStreamError`` when it cannot
        be written)."""
        with _writing("stdout"):
            print(text, file=self.stdout)

    def flush(self) -> None:
        """Push the result written so far out of ``stdout``'s buffer (``OutputStreamError`` when
        it cannot be written): a status that says the result was written is then true."""
        with _writing("stdout"):
            self.stdout.flush()

    def err(self, text: str) -> None:
        """One line of progress or diagnostics on ``stderr`` (flushed)."""
        print(text, file=self.stderr, flush=True)


@contextlib.contextmanager
def _writing(stream: str) -> Iterator[None]:
    """A write to ``stream`` that fails (a full disk) as ``OutputStreamError``; a reader that
    stopped stays ``BrokenPipeError``, which the command line answers on its own."""
    try:
        yield
    except BrokenPipeError:
        raise
    except OSError as exc:
        raise OutputStreamError(stream, exc) from exc


Handler = Callable[[argparse.Namespace, CommandContext], int]
