"""The stops that go on to ``match``'s caller, and whether a frame's terminal record can still
be written after one stopped it.

A stop is Ctrl-C (SIGTERM's ``KeyboardInterrupt`` under the ``c3-matcher`` command line), the
host program's own ``sys.exit`` (a signal handler's, say) or a closing generator: the process or
its caller is ending, so no step of the frame may turn it into a failure of its own (a dropped
candidate, the contract's error). Anything else a plugin raises, its own ``BaseException``
included, fails only its step.

The record can be written unless the stop cut a write short: raised while the FDR or the logs
(which forward to the FDR) were writing, a line may be half on disk, and another record written
now would be glued to it. Then none is written; the FDR's next start cuts the torn tail. The
stop is read from its traceback: a frame of the recorder's sinks (their modules, or a method of
the FDR client the matcher was handed, whatever its module) is where it was raised.
"""

from __future__ import annotations

from typing import Final

__all__ = ["SINK_MODULES", "STOPS", "cut_a_write_short", "is_stop"]

STOPS: Final = (KeyboardInterrupt, SystemExit, GeneratorExit)
"""What stops a frame and goes on to the caller, whichever step it is raised in."""

SINK_MODULES: Final = ("c3_matcher.fdr", "c3_matcher.logs", "loguru", "logging")
"""The modules whose code writes the FDR and the logs (by name and prefix)."""


def is_stop(exc: BaseException) -> bool:
    """Whether ``exc`` is one of ``STOPS``: it goes on to the caller (the frame recorded first
    where that is safe) rather than failing the step that raised it."""
    return isinstance(exc, STOPS)


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
