"""Whether a frame's terminal record can still be written after Ctrl-C (or SIGTERM's
``KeyboardInterrupt``, a closing generator) stopped it.

It can unless the stop cut a write short: raised while the FDR or the logs (which forward to
the FDR) were writing, a line may be half on disk, and another record written now would be
glued to it. Then none is written; the FDR's next start cuts the torn tail. The stop is read
from its traceback: a frame of the recorder's sinks (their modules, or a method of the FDR
client the matcher was handed, whatever its module) is where it was raised.
"""

from __future__ import annotations

from typing import Final

__all__ = ["SINK_MODULES", "cut_a_write_short"]

SINK_MODULES: Final = ("c3_matcher.fdr", "c3_matcher.logs", "loguru", "logging")
"""The modules whose code writes the FDR and the logs (by name and prefix)."""


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
