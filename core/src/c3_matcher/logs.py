"""Structured logging: loguru, configured once by the composition root.

A good library citizen: ``configure_logging`` only adds sinks and its handle removes only those,
so a program that embeds the matcher keeps its own sinks, before and after ``close()``, and they
receive the matcher's records as before. The one exception is loguru's default plain-text
stderr handler, installed by loguru at import rather than by the program: while it is still in
place, the matcher's JSON sink would print each of the matcher's records a second time on
stderr, below the configured level too. ``configure_logging`` therefore swaps it, once, for the
same handler without the matcher's records (every other record still reaches it, and it stays
so after ``close()``, so a second composition prints nothing twice either). A ``c3-matcher``
command owns its process and calls ``claim_stderr()`` first: loguru's default handler goes, so
every stderr log line of a command is JSON.

Every record carries a ``kind`` (``logger.bind(kind=...)``); the stderr sink writes one JSON
object per line. ERROR and WARNING records are also forwarded to the FDR as records of their own
kinds, ``log.error`` and ``log.warning``, so the matcher's own FDR kinds keep exactly one record
per event; a forward the FDR cannot write yet stays pending in the recorder (nothing on stderr),
and the FDR's own write failures (``FDR_WRITE_FAILED``, one line, also when a caller's own FDR
client fails a forward) stay in the log stream.

Several roots in one process (two cameras, or a root composed before the old one is closed):
each ``configure_logging`` is a root's set of sinks, and a record goes to one of them only. A
record logged while a root works (``logging_as``: ``compose_root`` composing it, its matcher's
frames, its ``close()``; on that thread, shared helpers and plugins included) is that root's:
only its sinks take it, and none once that root is closed. Any other record (a helper built
before composition, a thread of the program's, a root composed with ``configure_logs=False``
under sinks configured apart) goes to the earliest root still open. With one root, every
matcher record is that root's, as it always was.
"""

from __future__ import annotations

import contextlib
import json
import os
import sys
import threading
from collections.abc import Callable, Iterator, Mapping
from contextvars import ContextVar
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, TextIO

from loguru import logger

from c3_matcher.errors import describe
from c3_matcher.fdr import FdrWriteError, to_jsonable
from c3_matcher.fdr.turns import close_after_frame
from c3_matcher.protocols import FdrClient

if TYPE_CHECKING:
    from loguru import Message, Record

__all__ = [
    "FDR_WRITE_FAILED",
    "MATCHER_BACKBONE_ERROR",
    "MATCHER_GEOMETRY_REFUSED",
    "MATCHER_READY",
    "MATCHER_ZERO_INLIERS",
    "LoggingHandle",
    "claim_stderr",
    "configure_logging",
    "current_log_root",
    "drop_reason",
    "is_matcher_record",
    "log_event",
    "log_fdr_write_failed",
    "logging_as",
    "swap_default_handler",
]

FORWARDED_LEVELS = {"WARNING": "log.warning", "ERROR": "log.error", "CRITICAL": "log.error"}
FDR_WRITE_FAILED = "c3.fdr.write_failed"
"""The kind of the ERROR a failed FDR write logs: never forwarded into that FDR (the record it
concerns is kept pending and lands with its own time once the FDR can write again; one more
record per failure would only grow what is pending while the disk stays full)."""

# The matcher's log kinds that another module reads (the other kinds are only written, each in
# one place: the frame recorder, c3_matcher.stages.recorder); tests state them as literals.
MATCHER_READY = "c3.matcher.ready"
"""The INFO a composed matcher logs once, naming its strategy and thresholds."""
MATCHER_BACKBONE_ERROR = "c3.matcher.backbone_error"
"""The ERROR of a backbone failure (a candidate dropped, or the query or the matcher failing)."""
MATCHER_ZERO_INLIERS = "c3.matcher.zero_inliers"
"""The DEBUG of a candidate left without an inlier by RANSAC (dropped)."""
MATCHER_GEOMETRY_REFUSED = "c3.matcher.geometry_refused"
"""The DEBUG of a candidate the geometric prior refused, whatever its inliers (dropped)."""


def log_event(level: str, kind: str, message: str, **fields: Any) -> None:
    """Emit one structured log record: ``kind`` plus JSON-able ``fields``."""
    logger.bind(kind=kind, **fields).opt(depth=1).log(level, message)


def drop_reason(kind: str | None, fields: Mapping[str, Any]) -> str | None:
    """Why a candidate was dropped, in words, from the fields of the log event ``kind`` that
    dropped it: a backbone error, no inlier, or a refusal on geometry (None for another kind).
    The terminal FDR records and ``c3-matcher match``'s JSON say it alike."""
    if kind == MATCHER_BACKBONE_ERROR:
        return f"backbone error in {fields.get('phase')}: {fields.get('error')}"
    if kind == MATCHER_ZERO_INLIERS:
        return f"no inliers after RANSAC ({fields.get('raw_matches')} raw matches)"
    if kind == MATCHER_GEOMETRY_REFUSED:
        return f"refused on geometry: {fields.get('reason')} ({fields.get('inlier_count')} inliers)"
    return None


def _record_to_dict(record: Record) -> dict[str, Any]:
    extra = dict(record["extra"])
    kind = extra.pop("kind", "c3.log")
    return {
        "time": record["time"].isoformat(),
        "level": record["level"].name,
        "kind": kind,
        "message": record["message"],
        "module": record["name"],
        **{k: to_jsonable(v) for k, v in extra.items()},
    }


def is_matcher_record(record: Record) -> bool:
    """A record of the matcher or of a plugin: it carries a ``kind`` (``log_event``) or comes
    from a ``c3_matcher*`` module."""
    return "kind" in record["extra"] or (record["name"] or "").startswith("c3_matcher")


@dataclass(eq=False)
class LoggingHandle:
    """What ``configure_logging`` installed: a root's sinks (module docstring); ``close()``
    removes them. ``lines_lost``: JSON log lines its stream could not take (a full disk, a
    closed pipe), each dropped where it failed, never raised into the matcher."""

    sink_ids: list[int] = field(default_factory=list)
    lines_lost: int = 0

    def close(self) -> None:
        """Remove the sinks; called on a thread inside a matcher's frame (a signal handler's
        shutdown), once that frame is done (its log lines are said)."""
        if not close_after_frame(self._remove):
            self._remove()

    def takes(self) -> bool:
        """Whether the record being logged now, on this thread, is this root's to take."""
        root = _working_for.get()
        if root is not None:
            return root is self
        live = _roots.live  # replaced whole, never changed in place: read once
        return bool(live) and live[0] is self

    def _remove(self) -> None:
        _roots.leave(self)  # first: the next root takes the un-rooted records from now
        for sink_id in self.sink_ids:
            with contextlib.suppress(ValueError):
                logger.remove(sink_id)
        self.sink_ids.clear()


class _Roots:
    """The roots whose sinks are installed, earliest first."""

    def __init__(self) -> None:
        self.live: tuple[LoggingHandle, ...] = ()
        self._lock = threading.Lock()
        self._pid = os.getpid()

    def join(self, root: LoggingHandle) -> None:
        with self._locked():
            self.live = (*self.live, root)

    def leave(self, root: LoggingHandle) -> None:
        with self._locked():
            self.live = tuple(r for r in self.live if r is not root)

    def _locked(self) -> threading.Lock:
        """The lock, made anew in a process forked from the one that made it: a thread of the
        parent, absent here, may have held it at the fork (a child closing an inherited root
        waited for it forever)."""
        if self._pid != os.getpid():
            self._lock, self._pid = threading.Lock(), os.getpid()
        return self._lock


_roots = _Roots()
_working_for: ContextVar[LoggingHandle | None] = ContextVar("c3_matcher_log_root", default=None)


def current_log_root() -> LoggingHandle | None:
    """The root this thread is working for now (``logging_as``), or None."""
    return _working_for.get()


@contextlib.contextmanager
def logging_as(root: LoggingHandle | None) -> Iterator[None]:
    """Records logged in this block, on this thread, are ``root``'s: only its sinks take them
    (module docstring). None: they stay whose they were."""
    if root is None:
        yield
        return
    token = _working_for.set(root)
    try:
        yield
    finally:
        _working_for.reset(token)


def configure_logging(
    fdr: FdrClient | None,
    *,
    level: str = "INFO",
    stream: TextIO | None = None,
) -> LoggingHandle:
    """Add the JSON stderr sink (at ``level``) and the ERROR/WARN forwarder to ``fdr``, both
    for the matcher's records only (``is_matcher_record``), of this root only (module
    docstring); sinks added by anyone else are left alone, loguru's untouched default handler
    aside."""
    out = stream if stream is not None else sys.stderr
    handle = LoggingHandle()

    def json_sink(message: Message) -> None:
        line = json.dumps(_record_to_dict(message.record), separators=(",", ":")) + "\n"
        try:
            out.write(line)
            out.flush()
        except (OSError, ValueError):  # ValueError: closed. Not loguru's traceback per line
            handle.lines_lost += 1

    def ours(record: Record) -> bool:
        return is_matcher_record(record) and handle.takes()

    swap_default_handler()
    ids = handle.sink_ids
    ids.append(logger.add(json_sink, level=level.upper(), format="{message}", filter=ours))
    if fdr is not None:
        forwarder, forwarded = _fdr_forwarder(fdr, ours)
        ids.append(
            logger.add(forwarder, level="WARNING", format="{message}", filter=forwarded, catch=True)
        )
    _roots.join(handle)
    return handle


_LOGURU_DEFAULT_HANDLER = 0


def swap_default_handler() -> None:
    """Replace loguru's import-time stderr handler, if it is still installed, by the same
    handler minus the matcher's records (nothing happens when the program removed it or it was
    swapped already): ``configure_logging`` does, and so does ``build_default_helpers``, whose
    helpers log before ``compose_root`` configures the JSON sink (a plain-text line on stderr
    otherwise, at any configured level)."""
    try:
        logger.remove(_LOGURU_DEFAULT_HANDLER)
    except ValueError:
        return
    logger.add(sys.stderr, filter=lambda record: not is_matcher_record(record))


_OPENCV_SILENT = 0  # cv2.utils.logging.LOG_LEVEL_SILENT


def claim_stderr() -> None:
    """For a program that owns its process (the ``c3-matcher`` command): remove loguru's default
    plain-text stderr handler (id 0, installed at import), and keep OpenCV's own messages off
    stderr unless ``OPENCV_LOG_LEVEL`` asks for them (its "[ WARN:0@0.7] global loadsave.cpp"
    lines repeat, in its words, a failure the command says in one line of its own)."""
    with contextlib.suppress(ValueError):
        logger.remove(_LOGURU_DEFAULT_HANDLER)
    if "OPENCV_LOG_LEVEL" not in os.environ:
        import cv2

        cv2.setLogLevel(_OPENCV_SILENT)


def log_fdr_write_failed(kind: str, exc: BaseException) -> None:
    """The one ERROR line of an FDR record of ``kind`` that could not be written."""
    error = describe(exc)
    log_event(
        "ERROR",
        FDR_WRITE_FAILED,
        f"FDR write failed for {kind}: {error}",
        record_kind=kind,
        error=error,
    )


def _fdr_forwarder(
    fdr: FdrClient, ours: Callable[[Record], bool]
) -> tuple[Callable[[Message], None], Callable[[Record], bool]]:
    """The sink forwarding the WARNING and ERROR records ``ours`` takes (the matcher's, of its
    root) to ``fdr`` and its filter.
    The filter keeps out the FDR's own write failures and whatever is logged while a forward is
    under way on that thread (the FDR client's own logs), so a forward never runs inside
    another. A write the FDR keeps pending says nothing; any other failure of the client is
    one ERROR ``FDR_WRITE_FAILED`` line, no traceback."""
    forwarding = threading.local()

    def forwarded(record: Record) -> bool:
        return (
            ours(record)
            and record["extra"].get("kind") != FDR_WRITE_FAILED
            and not getattr(forwarding, "busy", False)
        )

    def forward(message: Message) -> None:
        record = message.record
        kind = FORWARDED_LEVELS.get(record["level"].name)
        if kind is None:
            return
        forwarding.busy = True
        try:
            fdr.record(kind, _record_to_dict(record))
        except FdrWriteError:
            pass  # kept pending by the recorder, written with the next record (no stderr noise)
        except Exception as exc:  # a caller's client failing: said once, on every other sink
            log_fdr_write_failed(kind, exc)
        finally:
            forwarding.busy = False

    return forward, forwarded
