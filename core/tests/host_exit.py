"""The ways a frame is stopped, raised as they are in a real process: Ctrl-C, and the host
program's own ``sys.exit`` from one of its signal handlers (an embedding's SIGTERM handler, say)
rather than a ``SystemExit`` made up in the test, which is a plugin's own exit."""

from __future__ import annotations

import signal
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any, Final, NoReturn

HOST_SIGNAL: Final = signal.SIGUSR1
"""The signal the host's handler answers with its exit (SIGTERM would end the test runner)."""

HOST_STATUS: Final = 143
"""The status the host's handler exits with."""


def _exit_as_the_host(signum: int, frame: Any) -> NoReturn:
    sys.exit(HOST_STATUS)


@contextmanager
def host_handler() -> Iterator[None]:
    """The host's handler for ``HOST_SIGNAL``, which calls ``sys.exit(HOST_STATUS)``, installed
    for the block; the handler before it put back after. Main thread only, as pytest runs."""
    previous = signal.signal(HOST_SIGNAL, _exit_as_the_host)
    try:
        yield
    finally:
        signal.signal(HOST_SIGNAL, previous)


def host_exit() -> NoReturn:
    """The host's exit at this step: ``HOST_SIGNAL`` raised, and its handler exits."""
    signal.raise_signal(HOST_SIGNAL)
    raise AssertionError("no handler of the host's exited: use host_handler()")


def ctrl_c() -> NoReturn:
    """Ctrl-C at this step."""
    raise KeyboardInterrupt
