"""The stops that go on to ``match``'s caller, and whether a frame's terminal record can still
be written after one stopped it.

A stop is Ctrl-C (SIGTERM's ``KeyboardInterrupt`` under the ``c3-matcher`` command line), a
closing generator, or a ``SystemExit`` one of the process's own signal handlers raised (an
embedding whose SIGTERM handler calls ``sys.exit``): the process or its caller is ending, so no
step of the frame may turn it into a failure of its own (a dropped candidate, the contract's
error). A ``SystemExit`` raised anywhere else can only be a plugin's ``sys.exit()`` (or a
library's it calls): it fails only its step, as anything else a plugin raises does, its own
``BaseException`` included; one plugin's exit must not end a whole replay. Which it was is read
from its traceback when it is caught: a handler's exit has a frame running that handler's code.

The record can be written unless the stop cut a write short: raised while the FDR or the logs
(which forward to the FDR) were writing, a line may be half on disk, and another record written
now would be glued to it. Then none is written; the FDR's next start cuts the torn tail. The
stop is read from its traceback: a frame of the recorder's sinks (their modules, or a method of
the FDR client the matcher was handed, whatever its module) is where it was raised.
"""

from __future__ import annotations

import functools
import signal
from types import (
    BuiltinFunctionType,
    CodeType,
    MethodDescriptorType,
    MethodWrapperType,
    WrapperDescriptorType,
)
from typing import Final

__all__ = ["ALWAYS_STOPS", "SINK_MODULES", "cut_a_write_short", "is_stop", "raised_by_a_handler"]

ALWAYS_STOPS: Final = (KeyboardInterrupt, GeneratorExit)
"""What stops a frame and goes on to the caller wherever it is raised. A ``SystemExit`` is a
stop by where it came from (``raised_by_a_handler``), not by its type."""

SINK_MODULES: Final = ("c3_matcher.fdr", "c3_matcher.logs", "loguru", "logging")
"""The modules whose code writes the FDR and the logs (by name and prefix)."""

_UNWRAP_DEPTH: Final = 8
"""How many wrappers (partials, callable objects) a handler is unwrapped through, at most."""

_NO_PYTHON_CODE: Final = (
    BuiltinFunctionType,
    MethodDescriptorType,
    MethodWrapperType,
    WrapperDescriptorType,
)
"""The callables written in C (``signal.default_int_handler`` among them): no frame of theirs
is on a traceback."""


def is_stop(exc: BaseException) -> bool:
    """Whether ``exc`` goes on to the caller (the frame recorded first where that is safe)
    rather than failing the step that raised it: one of ``ALWAYS_STOPS``, or a ``SystemExit``
    a signal handler of the process raised."""
    if isinstance(exc, ALWAYS_STOPS):
        return True
    return isinstance(exc, SystemExit) and raised_by_a_handler(exc)


def raised_by_a_handler(exc: BaseException) -> bool:
    """Whether a frame on ``exc``'s traceback runs the code of one of the process's current
    Python signal handlers: the host's own exit, not a plugin's. Read only when an exception
    is caught, so no frame pays for it otherwise."""
    codes = _handler_codes()
    tb = exc.__traceback__
    while tb is not None:
        if tb.tb_frame.f_code in codes:
            return True
        tb = tb.tb_next
    return False


def _handler_codes() -> frozenset[CodeType]:
    """The code objects of the Python signal handlers installed now, for every signal (none
    for ``SIG_DFL``, ``SIG_IGN``, a handler set from C, or a signal ``getsignal`` refuses)."""
    codes: set[CodeType] = set()
    for signum in signal.valid_signals():
        try:
            handler = signal.getsignal(signum)
        except (ValueError, OSError):
            continue
        if handler is None or isinstance(handler, int):  # SIG_DFL, SIG_IGN
            continue
        code = _code_of(handler)
        if code is not None:
            codes.add(code)
    return frozenset(codes)


def _code_of(handler: object) -> CodeType | None:
    """The code a handler runs when called: a function's or lambda's own, a bound method's
    function's, a ``functools.partial``'s function's, a callable object's ``__call__``'s;
    ``None`` for one with no Python code (a builtin)."""
    for _ in range(_UNWRAP_DEPTH):
        code = getattr(handler, "__code__", None)
        if isinstance(code, CodeType):
            return code
        if isinstance(handler, (*_NO_PYTHON_CODE, type)):  # C code, or a class
            return None
        method_of = getattr(handler, "__func__", None)  # a bound method's function
        if isinstance(handler, functools.partial):
            handler = handler.func
        elif method_of is not None:
            handler = method_of
        elif callable(handler):
            handler = type(handler).__call__
        else:
            return None
    return None


def cut_a_write_short(stop: BaseException, fdr: object) -> bool:
    """Whether ``stop`` was raised inside a sink's write: a module of ``SINK_MODULES`` or a
    method of ``fdr`` (the FDR client) on its traceback."""
    tb = stop.__traceback__
    while tb is not None:
        frame = tb.tb_frame
        module = str(frame.f_globals.get("__name__", ""))
        if any(module == m or module.startswith(m + ".") for m in SINK_MODULES):
            return True
        if frame.f_code.co_varnames[:1] == ("self",) and frame.f_locals.get("self") is fdr:
            return True
        tb = tb.tb_next
    return False
