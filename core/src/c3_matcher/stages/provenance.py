"""A backend's ``provenance()`` as the frame's records carry it: read so that it can fail no
frame, and kept from the core's own record fields.

A provenance that raises or returns something other than a mapping (or a mapping whose items
cannot be read) is said as ``provenance_error`` (the exception described) in the record instead:
the frame, its result and its record stand. A key the core writes itself
(``frame_records.TERMINAL_RECORD_FIELDS``: ``threshold``, ``timings_ms``, ...) is left out, so a
plugin cannot change what the core recorded; one WARNING per matcher names the strategy, the
backend's class and the keys. Left out and said, rather than refused at start-up: a backend's
provenance is read again for every frame and may name other keys later, so the check has to
stand where the record is made, and a clash harms nothing once the core's fields win.
"""

from __future__ import annotations

import threading
from collections.abc import Mapping
from typing import Any

from c3_matcher.errors import describe
from c3_matcher.fdr.records import to_jsonable
from c3_matcher.logs import log_event
from c3_matcher.protocols import FeatureBackend
from c3_matcher.stages.frame_records import TERMINAL_RECORD_FIELDS
from c3_matcher.stages.interrupts import is_stop

__all__ = [
    "PROVENANCE_RESERVED",
    "PROVENANCE_UNREADABLE",
    "ProvenanceFields",
    "read_provenance",
]

PROVENANCE_RESERVED = "c3.matcher.provenance_reserved"  # WARNING: keys the core's, left out
PROVENANCE_UNREADABLE = "c3.matcher.provenance_unreadable"  # WARNING: provenance() failed


def read_provenance(backend: FeatureBackend) -> dict[str, Any]:
    """``backend.provenance()`` as the frame records carry it, not said: JSON-native values
    under text keys, the core's own fields left out (``TERMINAL_RECORD_FIELDS``), or
    ``{"provenance_error": ...}`` saying why it could not be read (it raised, a plugin's own
    ``BaseException`` included, or returned no mapping); a stop (Ctrl-C, ``SystemExit``) goes on."""
    fields, error = _read(backend)
    return {"provenance_error": error} if fields is None else _unreserved(fields)


def _unreserved(fields: Mapping[str, Any]) -> dict[str, Any]:
    """``fields`` without the keys the frame records write themselves."""
    return {k: v for k, v in fields.items() if k not in TERMINAL_RECORD_FIELDS}


def _read(backend: FeatureBackend) -> tuple[dict[str, Any] | None, str]:
    """``backend``'s provenance read (``read_provenance``), or None and why it could not be."""
    try:
        said = backend.provenance()
        if not isinstance(said, Mapping):
            return None, f"provenance() returned {type(said).__name__}, not a mapping"
        read: dict[str, Any] = to_jsonable(dict(said))
        return read, ""
    except BaseException as exc:
        if is_stop(exc):
            raise
        return None, f"provenance() raised {describe(exc)}"


class ProvenanceFields:
    """One matcher's reading of its backend's provenance for the frame records: the core's
    fields left out, each key left out and each failure said once (a WARNING), not every
    frame."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._reserved_said: set[str] = set()
        self._unreadable_said = False

    def of(self, backend: FeatureBackend, strategy: str, frame_id: Any) -> dict[str, Any]:
        """What the frame's record carries of ``backend``'s provenance (``strategy``'s)."""
        fields, error = _read(backend)
        if fields is None:
            self._say_unreadable(strategy, frame_id, error)
            return {"provenance_error": error}
        reserved = sorted(fields.keys() & TERMINAL_RECORD_FIELDS)
        if reserved:
            self._say_reserved(backend, strategy, reserved)
        return _unreserved(fields)

    def _say_unreadable(self, strategy: str, frame_id: Any, error: str) -> None:
        with self._lock:
            said, self._unreadable_said = self._unreadable_said, True
        if not said:
            log_event(
                "WARNING",
                PROVENANCE_UNREADABLE,
                f"C3 provenance of strategy {strategy} could not be read; frame={frame_id}; "
                f"{error}; its frames are kept, their records say provenance_error",
                strategy=strategy,
                frame_id=frame_id,
                error=error,
            )

    def _say_reserved(self, backend: FeatureBackend, strategy: str, keys: list[str]) -> None:
        with self._lock:
            new = [k for k in keys if k not in self._reserved_said]
            self._reserved_said.update(new)
        if new:
            cls = type(backend)
            log_event(
                "WARNING",
                PROVENANCE_RESERVED,
                f"C3 provenance of strategy {strategy} ({cls.__module__}.{cls.__qualname__}) "
                f"names {', '.join(new)}, which the frame records write themselves: left out "
                "of them (rename them in provenance())",
                strategy=strategy,
                backend=f"{cls.__module__}.{cls.__qualname__}",
                keys=new,
            )
