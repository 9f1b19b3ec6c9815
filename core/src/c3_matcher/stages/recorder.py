"""Steps 6 and 8-10: what a frame leaves behind: the one health update, the logs and the FDR
records.

Terminal FDR record per ``match`` call, exactly one of: ``matcher.frame_done`` (success),
``matcher.insufficient_inliers`` (raised InsufficientInliersError), ``matcher.backbone_error``
with ``phase="query_extract"`` (the query frame itself failed) or ``phase="internal"`` (a bug,
answered with the contract's error), ``matcher.invalid_input``, or ``matcher.interrupted`` (a
stop, Ctrl-C or a signal handler's exit; none when it cut a write short: ``stages.interrupts``). Per
dropped candidate, one ``matcher.backbone_error`` record with its ``tile_id`` and ``phase``. A
recorder failure is logged, never fails the frame; every payload is made before the frame's
health update, so the health window counts only what the caller gets.

The success and no-fix records name the strategy (``matcher_label``), carry the frame's stage
timings (``timings_ms``; on a no-fix frame when its candidates were matched) and account for
every input candidate by its input position: each kept one's row carries its
``candidate_index``, each dropped one is in ``dropped`` with its tile id and why. In flight the
FDR is the only account of a drop for zero inliers or on geometry (their log lines are DEBUG).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from c3_matcher.arrays import F64
from c3_matcher.clocks import SteadyClock, read_said
from c3_matcher.dto import CandidateMatchSet, RerankResult
from c3_matcher.errors import InsufficientInliersError, InvalidInputError, describe
from c3_matcher.health import RollingHealthWindow
from c3_matcher.logs import (
    MATCHER_BACKBONE_ERROR,
    MATCHER_GEOMETRY_REFUSED,
    MATCHER_ZERO_INLIERS,
    drop_reason,
    log_event,
    log_fdr_write_failed,
)
from c3_matcher.protocols import Clock, FdrClient, FeatureBackend
from c3_matcher.stages.ambiguity import Ambiguity
from c3_matcher.stages.frame_records import TerminalRecord, candidates_record
from c3_matcher.stages.interrupts import cut_a_write_short
from c3_matcher.stages.no_fix import no_fix_error, no_fix_words
from c3_matcher.stages.outcomes import CandidateDrop, FrameEvidence, GeometryRefusal, Survivor
from c3_matcher.stages.provenance import ProvenanceFields
from c3_matcher.tilestore.features import NoStoredSet

__all__ = ["FrameRecorder", "RecorderSinks", "drop_reason"]


@dataclass(frozen=True)
class RecorderSinks:
    """Where a matcher's frames are recorded: the FDR, the health window (read with the clock,
    kept as a ``SteadyClock`` across frames), the backend (its label and provenance, read
    through ``provenance``, which says a failure or a clash once per matcher) and the strategy
    selected (None: the backend's)."""

    fdr: FdrClient
    health: RollingHealthWindow
    clock: Clock
    backend: FeatureBackend
    strategy: str | None = None
    provenance: ProvenanceFields = field(default_factory=ProvenanceFields, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "clock", SteadyClock.of(self.clock))

    @property
    def label(self) -> str:
        """``matcher_label``: the strategy selected, else the backend's ``label``."""
        return self.strategy or self.backend.label


class FrameRecorder:
    """The records of one ``match`` call about ``frame_id``. It updates the health window
    exactly once (the first update wins) and counts the backbone errors it records, which the
    health update reports."""

    def __init__(self, sinks: RecorderSinks, frame_id: Any) -> None:
        self._sinks = sinks
        self._frame_id = frame_id
        self._health_updated = False
        self._backbone_errors = 0
        self._drops: dict[int, CandidateDrop] = {}  # by input position
        self._capture: TerminalRecord = {}  # the frame's capture time, once its inputs passed
        self._now_ns: int | None = None  # the frame's one reading of the clock (``now_ns``)
        self._ended = False  # its terminal record made (written, or tried)

    def captured(self, captured_at_ns: int) -> None:
        """The frame's capture time, which its terminal records carry (``captured_at_ns``): how
        old a frame was when matched can be read from the FDR after a flight."""
        self._capture = {"captured_at_ns": int(captured_at_ns)}

    @property
    def frame_id(self) -> Any:
        """The frame this call's records are about."""
        return self._frame_id

    @property
    def ended(self) -> bool:
        """Whether the frame's terminal record was made (a contract error raised without one
        is not the matcher's own)."""
        return self._ended

    def _terminal(self, kind: str, payload: Mapping[str, Any]) -> None:
        """Write the frame's terminal record (one per frame, ``ended`` from its first try)."""
        self._ended = True
        self.record(kind, payload)

    def _with_provenance(self, core: TerminalRecord) -> dict[str, Any]:
        """``core`` and the backend's provenance, whose keys never replace the core's."""
        sinks = self._sinks
        return {**core, **sinks.provenance.of(sinks.backend, sinks.label, self.frame_id)}

    # -- health and the FDR -------------------------------------------------------------
    def now_ns(self) -> int:
        """The frame's one reading of the matcher's clock, taken at its first use (the health
        update, before any terminal record; the result's ``matched_at``) and always whole
        nanoseconds >= 0 (``clocks.read_said``): a clock gone bad mid-run fails no frame."""
        if self._now_ns is None:
            self._now_ns = read_said(self._sinks.clock)
        return self._now_ns

    def update_health(self, best_inlier_count: int, *, force_backbone_error: bool = False) -> None:
        """Step 9 (and its failure paths): the one health update of this frame."""
        if self._health_updated:
            return
        self._health_updated = True
        self._sinks.health.update(
            self.now_ns(),
            best_inlier_count=best_inlier_count,
            had_backbone_error=force_backbone_error or self._backbone_errors > 0,
        )

    def record(self, kind: str, payload: Mapping[str, Any]) -> None:
        """Write an FDR record; a recorder failure is logged, never fails the frame (the durable
        recorder keeps the record pending and writes it with the next one)."""
        try:
            self._sinks.fdr.record(kind, payload)
        except Exception as exc:
            log_fdr_write_failed(kind, exc)

    # -- per candidate --------------------------------------------------------------------
    def backbone_error(
        self, tile_id: Any, phase: str, exc: BaseException, candidate_index: int | None = None
    ) -> None:
        """A backbone failure: of a candidate (dropped), of the query or of the matcher."""
        self._backbone_errors += 1
        label = self._sinks.backend.label
        error = describe(exc)
        fields = {
            "frame_id": self.frame_id,
            "tile_id": tile_id,
            "candidate_index": candidate_index,
            "phase": phase,
            "error": error,
            "backbone": label,
        }
        log_event(
            "ERROR",
            MATCHER_BACKBONE_ERROR,
            f"C3 backbone error; frame={self.frame_id}; tile={tile_id}; phase={phase}; "
            f"backbone={label}; {error}",
            **fields,
        )
        self.record("matcher.backbone_error", dict(fields))
        self._dropped(MATCHER_BACKBONE_ERROR, fields)

    def stored_features_failed(self, tile_id: Any, exc: BaseException) -> None:
        log_event(
            "WARNING",
            "c3.matcher.stored_features_failed",
            f"C3 stored features unusable; frame={self.frame_id}; "
            f"tile={tile_id}; extracting instead: {describe(exc)}",
            frame_id=self.frame_id,
            tile_id=tile_id,
        )

    def stored_features_unserved(self, unserved: NoStoredSet) -> None:
        """A store's sidecar holds no set for this backend: its candidates are extracted."""
        log_event(
            "WARNING",
            "c3.matcher.stored_features_unserved",
            f"C3 stored features not served; frame={self.frame_id}; {unserved}",
            frame_id=self.frame_id,
            **unserved.as_record(),
        )

    def zero_inliers(self, tile_id: Any, candidate_index: int, raw_matches: int) -> None:
        """Step 4e: a candidate without an inlier, dropped."""
        fields = {
            "tile_id": tile_id,
            "candidate_index": candidate_index,
            "raw_matches": raw_matches,
        }
        log_event(
            "DEBUG",
            MATCHER_ZERO_INLIERS,
            f"C3 zero inliers; frame={self.frame_id}; tile={tile_id}",
            frame_id=self.frame_id,
            **fields,
        )
        self._dropped(MATCHER_ZERO_INLIERS, fields)

    def geometry_refused(self, refusal: GeometryRefusal) -> None:
        log_event(
            "DEBUG",
            MATCHER_GEOMETRY_REFUSED,
            f"C3 candidate refused on geometry; frame={self.frame_id}; tile={refusal.tile_id}; "
            f"inliers={refusal.inlier_count}; {refusal.reason}",
            frame_id=self.frame_id,
            **refusal.as_record(),
        )
        self._dropped(MATCHER_GEOMETRY_REFUSED, refusal.as_record())

    def _dropped(self, kind: str, fields: Mapping[str, Any]) -> None:
        """Keep a candidate's drop for the frame's terminal record (a failure of the query or
        of the matcher, with no input position, is no candidate's)."""
        index, reason = fields.get("candidate_index"), drop_reason(kind, fields)
        if index is not None and reason is not None:
            self._drops[index] = CandidateDrop(index, fields.get("tile_id"), reason)

    @property
    def drops(self) -> list[CandidateDrop]:
        """The candidates dropped so far, in input order."""
        return [self._drops[index] for index in sorted(self._drops)]

    def refine_failed(self, tile_id: Any, exc: BaseException) -> None:
        log_event(
            "WARNING",
            "c3.matcher.refine_failed",
            f"C3 refine pass failed, first pass kept; frame={self.frame_id}; {describe(exc)}",
            frame_id=self.frame_id,
            tile_id=tile_id,
        )

    # -- the frame ------------------------------------------------------------------------
    def candidates(self, survivors: Sequence[Survivor]) -> None:
        """The survivors' (inliers, residual) in input order (DEBUG)."""
        summary = [
            (s.match_set.inlier_count, s.match_set.per_candidate_residual_px) for s in survivors
        ]
        log_event(
            "DEBUG",
            "c3.matcher.candidates",
            f"C3 frame={self.frame_id} candidates={summary}",
            frame_id=self.frame_id,
            candidates=summary,
        )

    def residual_above_threshold(self, best: CandidateMatchSet, threshold_px: float) -> None:
        """Step 8: the best candidate's residual is above the warning threshold."""
        log_event(
            "WARNING",
            "c3.matcher.residual_above_threshold",
            f"C3 residual={best.per_candidate_residual_px:.2f}px > threshold="
            f"{threshold_px}px; frame={self.frame_id}; will refine",
            residual_px=best.per_candidate_residual_px,
            threshold_px=threshold_px,
            frame_id=self.frame_id,
            tile_id=best.tile_id,
        )

    def frame_done(
        self,
        evidence: FrameEvidence,
        ranked: Sequence[Survivor],
        rectification: F64 | None,
        timings: dict[str, float],
        threshold: int,
    ) -> None:
        """Step 10: the success record (+ the best homography, from the px the query was
        matched in, and ``query_rectification``, UNDISTORTED query px to those, null for a
        query matched unrectified in its ORIGINAL px; the inlier ``threshold`` it passed, as
        the no-fix record names the one it missed; the matcher's label; the frame's and each
        candidate's stage timings in input order; the kept candidates ranked and the dropped
        ones, each by input position; provider, engines). The frame's health update (its best
        inlier count) comes once the record is made, before it is written."""
        best = ranked[0].match_set
        payload = self._with_provenance(
            {
                "frame_id": self.frame_id,
                **self._capture,
                "candidates_input": evidence.candidates_input,
                "candidates_dropped": evidence.dropped,
                "best_inlier_count": best.inlier_count,
                "threshold": threshold,
                "best_residual_px": best.per_candidate_residual_px,
                "best_tile_id": best.tile_id,
                "best_homography": ranked[0].homography,
                "query_rectification": rectification,
                "matcher_label": self._sinks.label,
                "timings_ms": timings,
                **candidates_record(evidence, ranked, self.drops),
            }
        )
        self.update_health(best.inlier_count)  # step 9
        self._terminal("matcher.frame_done", payload)

    def insufficient(
        self,
        evidence: FrameEvidence,
        best_count: int,
        survivors: Sequence[Survivor],
        threshold: int,
        *,
        stale_rerank_frame_id: Any = None,
        timings: Mapping[str, float] | None = None,
        ambiguity: Ambiguity | None = None,
    ) -> InsufficientInliersError:
        """Step 6, no fix for this frame: health 0, log, FDR record; returns the error to raise.
        With ``stale_rerank_frame_id`` every candidate was dropped unmatched: the re-rank was
        made for that other frame, so its tiles say where the vehicle was, not where it is.
        ``timings``: the frame's stage timings (``timings_ms``), given when it was matched.
        With ``ambiguity`` (step 7) the best had enough inliers but a rival places the frame
        elsewhere: :class:`~c3_matcher.errors.AmbiguousMatchError`, the record's ``ambiguous``."""
        label = self._sinks.label
        stale: TerminalRecord = {}
        if stale_rerank_frame_id is not None:
            stale["stale_rerank"] = stale_rerank_frame_id
        rival: TerminalRecord = {} if ambiguity is None else {"ambiguous": ambiguity.as_record()}
        timed: TerminalRecord = {} if timings is None else {"timings_ms": dict(timings)}
        payload = self._with_provenance(
            {
                "frame_id": self.frame_id,
                **self._capture,
                **stale,
                "candidates_input": evidence.candidates_input,
                "candidates_dropped": evidence.dropped,
                "best_inlier_count": best_count,
                "threshold": threshold,
                "matcher_label": label,
                **rival,
                **timed,
                **candidates_record(evidence, survivors, self.drops),
            }
        )
        self.update_health(0)  # best_inlier_count=0
        error = no_fix_error(self.frame_id, evidence, best_count, threshold, label, ambiguity)
        what, said = no_fix_words(error, evidence, threshold, ambiguity)
        log_event(
            "ERROR",
            "c3.matcher.insufficient_inliers",
            f"C3 {what}; frame={self.frame_id}; backbone={label}; {said}"
            + ("" if not stale else f"; re-rank is for frame {stale_rerank_frame_id}"),
            frame_id=self.frame_id,
            backbone=label,
            best_inlier_count=best_count,
            threshold=threshold,
            candidates_input=evidence.candidates_input,
            candidates_dropped=evidence.dropped,
            **{k: payload[k] for k in ("stale_rerank", "ambiguous") if k in payload},
        )
        self._terminal("matcher.insufficient_inliers", payload)
        return error

    def stale_rerank(self, rerank: RerankResult, threshold: int) -> InsufficientInliersError:
        """No fix: the re-rank was made for another frame (its tiles say where the vehicle
        was), so every candidate is dropped unmatched, each named with why in ``dropped``."""
        why = f"the re-rank was made for frame {rerank.frame_id}"
        for index, candidate in enumerate(rerank.candidates):
            self._drops[index] = CandidateDrop(index, candidate.tile_id, why)
        unmatched = len(rerank.candidates)
        evidence = FrameEvidence(unmatched, dropped=unmatched)
        return self.insufficient(evidence, 0, [], threshold, stale_rerank_frame_id=rerank.frame_id)

    def query_failed(self, exc: BaseException) -> None:
        """The nav frame itself could not be decoded or extracted: health (0, backbone error)
        and a ``query_extract`` backbone-error record."""
        self.update_health(0, force_backbone_error=True)
        self._ended = True
        self.backbone_error(None, "query_extract", exc)

    def invalid_input(self, exc: InvalidInputError) -> None:
        """Refused input still leaves its evidence in the FDR."""
        self.update_health(0)
        self._terminal(
            "matcher.invalid_input",
            {"frame_id": self.frame_id, "field": exc.field, "error": str(exc)},
        )

    def internal_error(self, exc: BaseException) -> None:
        """A bug (or a plugin's own ``BaseException``) must not take the vehicle down: health,
        an ``internal`` backbone-error record."""
        self.update_health(0, force_backbone_error=True)
        self._ended = True
        self.backbone_error(None, "internal", exc)

    def interrupted(self, stop: BaseException) -> None:
        """A stop (``stages.interrupts``: Ctrl-C, a handler's exit) ended the frame and goes on:
        its health update (no fix; it writes no record, so always) and a ``matcher.interrupted``
        record, unless its terminal record was made already or the stop cut a write short (a
        record now would be glued to a torn line)."""
        self.update_health(0)
        if self._ended or cut_a_write_short(stop, self._sinks.fdr):
            return
        self._terminal(
            "matcher.interrupted",
            {"frame_id": self.frame_id, **self._capture, "error": describe(stop)},
        )
