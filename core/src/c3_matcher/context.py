"""``CommandContext``: what every command handler receives beside its arguments, built once per
process by the command line (``c3_matcher.cli``) after the plugins are discovered."""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, TextIO

from c3_matcher.errors import OutputStreamError
from c3_matcher.terminal_text import without_controls

if TYPE_CHECKING:
    from c3_matcher.config import C3Settings
    from c3_matcher.plugins.manager import PluginHost

__all__ = ["CommandContext", "Handler", "result_stream"]


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
        be written); control characters and what its encoding cannot hold escaped
        (:func:`_encodable`)."""
        with _writing("stdout"):
            print(_encodable(text, self.stdout), file=self.stdout)

    def flush(self) -> None:
        """Push the result written so far out of ``stdout``'s buffer (``OutputStreamError`` when
        it cannot be written): a status that says the result was written is then true."""
        with _writing("stdout"):
            self.stdout.flush()

    def err(self, text: str) -> None:
        """One line of progress or diagnostics on ``stderr`` (flushed), escaped as ``out`` is. A
        line that cannot be written (a full log disk, a closed pipe) is lost, not the command:
        its result, exit status and files say what happened."""
        with contextlib.suppress(OSError, ValueError):
            print(_encodable(text, self.stderr), file=self.stderr, flush=True)


def _encodable(text: str, stream: TextIO) -> str:
    """``text`` as ``stream`` can write it and no terminal obeys: C0 and C1 control characters
    but newline and tab (ESC, CR, BEL, CSI: a name or a store's metadata from a hostile file
    would otherwise erase lines and print fake ones) as ``\\x1b``; what its encoding cannot
    hold (a file name's byte that is no UTF-8, which Python holds as a lone surrogate; a CJK
    name under a Latin-1 locale) as Python's escapes (``\\udce9``, ``\\u6771``), as Python's own
    stderr writes it. A name then costs no command its result; JSON text is ASCII already,
    its control characters escaped (``json.dumps``), so it is written as it is."""
    text = without_controls(text)
    encoding = getattr(stream, "encoding", None)
    if not encoding:  # a stream of text, not of bytes (``io.StringIO``): it takes anything
        return text
    try:
        text.encode(encoding, getattr(stream, "errors", None) or "strict")
    except UnicodeEncodeError:
        return text.encode(encoding, "backslashreplace").decode(encoding)
    return text


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


@contextlib.contextmanager
def result_stream() -> Iterator[TextIO]:
    """The stream a command writes its result to while it runs, with everything else written
    to stdout sent to stderr: Python's ``print`` and what a plugin's native library writes to
    descriptor 1 (C's ``printf``), which would otherwise mix into a JSON result. Descriptor 1
    points at descriptor 2 until the command ends (C's buffered output flushed first); the
    result goes to a copy of the original descriptor 1, or to ``sys.stdout`` itself where that
    is no descriptor (a stream replaced in-process)."""
    stdout = sys.stdout
    with contextlib.suppress(AttributeError, OSError, ValueError):
        stdout.flush()
    try:
        saved = os.dup(1)
    except OSError:  # no descriptor 1: nothing native can mix into the result either
        with contextlib.redirect_stdout(sys.stderr):
            yield stdout
        return
    result = _copy(stdout, saved)
    try:
        with contextlib.suppress(OSError):  # no descriptor 2: native writes stay where they are
            os.dup2(2, 1)
        with contextlib.redirect_stdout(sys.stderr):
            yield result
    finally:
        _flush_native()  # what C's stdio holds for descriptor 1 goes out while it is stderr
        if result is not stdout:
            with contextlib.suppress(OSError):  # a reader gone or a full disk: said already
                result.close()
        os.dup2(saved, 1)
        os.close(saved)


def _copy(stdout: TextIO, saved: int) -> TextIO:
    """A text stream, buffered as ``stdout``, on a copy of ``saved`` (descriptor 1) where
    ``stdout`` writes to descriptor 1; else ``stdout``."""
    try:
        on_one = stdout.fileno() == 1
    except (AttributeError, OSError, ValueError):  # io.UnsupportedOperation: no descriptor
        on_one = False
    if not on_one:
        return stdout
    line = bool(getattr(stdout, "line_buffering", False))  # a terminal's: each line at once
    return open(
        os.dup(saved),
        "w",
        buffering=1 if line else -1,
        encoding=stdout.encoding,
        errors=stdout.errors,
    )


def _flush_native() -> None:
    """C's ``fflush(NULL)``: what native code's ``printf`` buffered is written out now."""
    import ctypes

    with contextlib.suppress(Exception):  # no C library to ask: nothing buffered there
        ctypes.CDLL(None).fflush(None)


Handler = Callable[[argparse.Namespace, CommandContext], int]
