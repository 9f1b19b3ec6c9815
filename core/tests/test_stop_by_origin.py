"""A ``SystemExit`` is a stop only when one of the process's signal handlers raised it, whatever
shape the handler has (a function, a lambda, a bound method, a partial, a callable object, a
helper it calls); one raised anywhere else is a plugin's own exit. Ctrl-C and a closing
generator are stops wherever they come from."""

from __future__ import annotations

import functools
import signal
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any, NoReturn

import pytest

from c3_matcher.stages.interrupts import is_stop

from .host_exit import HOST_SIGNAL


def _exits(*args: Any) -> NoReturn:
    sys.exit(143)


class Host:
    def on_signal(self, signum: int, frame: Any) -> None:
        _exits()  # through a helper: the handler's frame is still on the traceback

    def __call__(self, signum: int, frame: Any) -> None:
        sys.exit(143)


HANDLERS: dict[str, Callable[[], Callable[..., Any]]] = {
    "a function": lambda: _exits,
    "a lambda": lambda: lambda signum, frame: sys.exit(143),
    "a bound method calling a helper": lambda: Host().on_signal,
    "a partial": lambda: functools.partial(_exits, "partial"),
    "a callable object": Host,
    "a partial of a bound method": lambda: functools.partial(Host().on_signal),
}


@contextmanager
def _installed(handler: Callable[..., Any]) -> Iterator[None]:
    previous = signal.signal(HOST_SIGNAL, handler)
    try:
        yield
    finally:
        signal.signal(HOST_SIGNAL, previous)


def _caught(raise_it: Callable[[], object]) -> BaseException:
    try:
        raise_it()
    except BaseException as exc:
        return exc
    raise AssertionError("nothing raised")


@pytest.mark.parametrize("make", HANDLERS.values(), ids=HANDLERS.keys())
def test_a_sys_exit_a_signal_handler_raised_is_a_stop(make: Callable[[], Callable[..., Any]]):
    with _installed(make()):
        caught = _caught(lambda: signal.raise_signal(HOST_SIGNAL))
        assert isinstance(caught, SystemExit) and is_stop(caught)


@pytest.mark.parametrize("make", HANDLERS.values(), ids=HANDLERS.keys())
def test_a_sys_exit_raised_outside_every_handler_is_no_stop(
    make: Callable[[], Callable[..., Any]],
):
    """A handler that exits installed, and an exit raised elsewhere (a plugin's own): no stop;
    nor with no handler of the host's at all."""
    with _installed(make()):
        caught = _caught(lambda: sys.exit(3))
        assert isinstance(caught, SystemExit) and not is_stop(caught)
    assert not is_stop(_caught(lambda: sys.exit(3)))


@pytest.mark.parametrize("stop", [KeyboardInterrupt(), GeneratorExit()], ids=repr)
def test_ctrl_c_and_a_closing_generator_are_stops_wherever_raised(stop: BaseException):
    assert is_stop(_caught(lambda: (_ for _ in ()).throw(stop)))
