"""The shared per-frame pipeline every strategy runs (the specification's steps 1-11, written once).

A strategy supplies only its model I/O as a ``FeatureBackend`` (extract features of a prepared
image, match two feature sets); ``PipelineMatcher.match`` composes the stages of
:mod:`c3_matcher.stages` around it, top to bottom:

1-2. the query frame, prepared once per GSD of the candidates (one, when they share a zoom)
     and extracted (``stages.query``; every quarter turn under rotation search);
3-4. per candidate, with drop and continue: its tile features, stored, cached or extracted
     (``stages.candidate_features``), matched against the query at its GSD and verified: that
     query's geometric prior, RANSAC through the shared ``RansacFilter`` (``stages.verify``);
     zero inliers or a refusal on geometry drop it;
     the optional refine pass of the best candidate (``stages.refine``);
5-6. the best inlier count against ``min_inliers_threshold``;
7.   the deterministic ranking (``stages.ranking``); no fix where a rival places the frame elsewhere
     (``stages.ambiguity``);
8-10. the residual warning, the single health update, the logs and the FDR records
     (``stages.recorder``, which also states the terminal FDR record of each outcome);
11.  the ``MatchResult``.
"""

from __future__ import annotations

import dataclasses
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Final

from c3_matcher.config import MatcherSettings, matcher_default
from c3_matcher.dto import (
    CameraCalibration,
    MatcherHealth,
    MatchResult,
    NavCameraFrame,
    RerankCandidate,
    RerankResult,
)
from c3_matcher.errors import (
    InsufficientInliersError,
    InvalidInputError,
    MatcherBackboneError,
    MatcherClosedError,
    describe,
)
from c3_matcher.fdr.forks import forked_from
from c3_matcher.fdr.turns import FrameTurns
from c3_matcher.health import RollingHealthWindow
from c3_matcher.logs import FDR_WRITE_FAILED, current_log_root, log_event, logging_as
from c3_matcher.preprocess import FramePreprocessor
from c3_matcher.prior import PriorTolerances
from c3_matcher.protocols import Clock, FdrClient, FeatureBackend, RansacFilter
from c3_matcher.stages.ambiguity import ambiguity
from c3_matcher.stages.candidate_features import CandidateFeatures
from c3_matcher.stages.candidate_features import feature_request as _feature_request
from c3_matcher.stages.extract import Extraction
from c3_matcher.stages.failure import CandidateStepError
from c3_matcher.stages.frame_inputs import check_inputs, frame_id_of
from c3_matcher.stages.interrupts import is_stop
from c3_matcher.stages.outcomes import Dropped, FrameEvidence, Survivor
from c3_matcher.stages.provenance import read_provenance
from c3_matcher.stages.query import QUERY_ROTATIONS_DEG
from c3_matcher.stages.ranking import best_inlier_count, ranked
from c3_matcher.stages.recorder import FrameRecorder, RecorderSinks
from c3_matcher.stages.refine import RefinePass
from c3_matcher.stages.scales import FrameScales, prepare_scales
from c3_matcher.stages.verify import VerifierSettings, candidate_verdict
from c3_matcher.tile_cache import TileFeatureCache

__all__ = ["QUERY_ROTATIONS_DEG", "FeatureBackend", "PipelineMatcher", "PipelineSettings"]


@dataclass(frozen=True, slots=True)
class PipelineSettings:
    """What the per-frame loop takes from ``[matcher]``, one object: the specified thresholds,
    its switches and the tile cache (``MatcherSettings``'s defaults, but the tile cache's)."""

    min_inliers_threshold: int = matcher_default("min_inliers_threshold")
    residual_warn_threshold_px: float = matcher_default("residual_warn_threshold_px")
    ransac_threshold_px: float = matcher_default("ransac_threshold_px")
    # a store's map features when built (else: extract)
    stored_features: bool = matcher_default("stored_features")
    # only acts when the frame had attitude and height
    geometric_prior: bool = matcher_default("geometric_prior")
    prior_tolerances: PriorTolerances = field(default_factory=PriorTolerances)
    photometric: str = "none"  # query and tiles alike (photometry.normalise_photometry)
    # frames without attitude tried at 4 turns (opt-in)
    rotation_search: bool = matcher_default("rotation_search")
    refine: bool = matcher_default("refine")  # a second pass through the best's homography
    # tiles whose features are kept between frames; 0 (none) for a loop built by hand,
    # [matcher]'s own (16) through from_settings
    tile_cache_size: int = 0
    # a candidate's tile above it (width x height) is refused: c3_matcher.tile_limit
    max_image_pixels: int = matcher_default("max_image_pixels")

    @classmethod
    def from_settings(cls, matcher: MatcherSettings) -> PipelineSettings:
        """Every pipeline setting from ``[matcher]``: each field reads the setting of its name."""
        named = {
            f.name: getattr(matcher, f.name)
            for f in dataclasses.fields(cls)
            if f.name not in ("prior_tolerances", "photometric")
        }
        # photometric unset: resolved per strategy before it gets here
        return cls(
            **named,
            prior_tolerances=PriorTolerances.from_settings(matcher),
            photometric=matcher.photometric or "none",
        )


class PipelineMatcher:
    """The one ``CrossDomainMatcher`` of every strategy: the per-frame loop over a strategy's
    ``FeatureBackend``. One frame at a time: calls from several threads are serialised (a
    second caller waits, served in the order called), and ``close()`` waits for a frame in
    progress. ``settings.tile_cache_size`` tiles keep their features between frames (0: off)."""

    def __init__(
        self,
        backend: FeatureBackend,
        ransac_filter: RansacFilter,
        fdr_client: FdrClient,
        health_window: RollingHealthWindow,
        clock: Clock,
        settings: PipelineSettings,
    ) -> None:
        self.backend: Final = backend
        self._verification = VerifierSettings(
            ransac_filter,
            settings.ransac_threshold_px,
            settings.geometric_prior,
            settings.prior_tolerances,
        )
        self._sinks = RecorderSinks(fdr_client, health_window, clock, backend)
        self.settings: Final = settings
        self._pre = FramePreprocessor(backend.input_rule, photometric=settings.photometric)
        cache = TileFeatureCache(settings.tile_cache_size)
        request = _feature_request(backend, self._pre)
        self._extraction = extraction = Extraction(backend)  # its budget read, a cut said once
        tiles = (cache, request, settings.stored_features, settings.max_image_pixels)
        self._tiles = CandidateFeatures(extraction, self._pre, *tiles)
        self._refine = RefinePass(self._pre, extraction)
        self._turns = FrameTurns(_close_failed)
        self._log_root = current_log_root()  # composed by a root: its frames log as its own
        self._pid = os.getpid()  # its recorder and log sinks are this process's alone

    @property
    def label(self) -> str:
        """The strategy's name in its results and records (``matcher_label``): the strategy
        selected (``record_as``), else the backend's ``label``."""
        return self._sinks.label

    def record_as(self, strategy: str) -> None:
        """Name the results and records after ``strategy``, the one selected (the composition
        calls it at start-up): one backend may serve several strategies under one ``label``,
        which a backbone-error record keeps as its ``backbone``."""
        self._sinks = dataclasses.replace(self._sinks, strategy=strategy)

    @property
    def stored_features(self) -> bool:
        """Whether candidate features come from precomputed map features when the tile store
        has them (``features build``); False: always extract. A composition input
        (``[matcher] stored_features``), fixed for the matcher's life."""
        return self._tiles.use_stored

    def health_snapshot(self) -> MatcherHealth:
        return self._sinks.health.snapshot()

    def provenance(self) -> dict[str, Any]:
        """Its backend's provenance, read as the frame records read it: a failure to read it
        is said as ``provenance_error`` (``stages.provenance``), never raised."""
        return read_provenance(self.backend)

    # -- the contract -----------------------------------------------------------------------
    def match(
        self, frame: NavCameraFrame, rerank_result: RerankResult, calibration: CameraCalibration
    ) -> MatchResult:
        if (forked := forked_from(self._pid)) is not None:  # a copy in a fork's child: no turn
            FrameRecorder(self._sinks, None).update_health(0)  # (the parent's frame holds it)
            raise MatcherClosedError(self.label, forked)
        with logging_as(self._log_root), self._turns.turn() as admitted:  # as its root's
            # one frame at a time, first come first served
            if not admitted:  # closed: no fix from this call either, the health window says so
                FrameRecorder(self._sinks, None).update_health(0)
                raise MatcherClosedError(self.label)
            return self._contract_match(frame, rerank_result, calibration)

    def close(self) -> None:
        """Refuse every later ``match`` (``MatcherClosedError``), callers still waiting
        included; a frame in progress finishes first, with its records: ``close()`` waits for
        it, or, called from within it (a signal handler's), returns at once, and the recorder
        and log sinks closed meanwhile on that thread close once it is done
        (``c3_matcher.fdr.turns``). Idempotent. ``ComposedRoot.close()`` calls it before it
        releases the recorder and the log sinks. In a fork's child it has no frame to wait for."""
        if forked_from(self._pid) is None:  # the parent's frame in progress is not the child's
            self._turns.close()

    def _contract_match(
        self, frame: NavCameraFrame, rerank_result: RerankResult, calibration: CameraCalibration
    ) -> MatchResult:
        recorder = FrameRecorder(self._sinks, frame_id_of(frame, rerank_result, calibration))
        try:
            check_inputs(frame, rerank_result, calibration)
        except InvalidInputError as exc:  # refused input still leaves its evidence in the FDR
            recorder.invalid_input(exc)
            raise
        try:
            if frame is None:  # no nav frame arrived: a query failure, as a decode failure is
                exc = InvalidInputError("frame", "is None (no nav frame)")
                recorder.query_failed(exc)
                raise MatcherBackboneError("query_extract", None, exc) from exc
            recorder.captured(frame.captured_at_ns)
            if rerank_result.frame_id != frame.frame_id:  # candidates of another frame
                raise recorder.stale_rerank(rerank_result, self.settings.min_inliers_threshold)
            if not rerank_result.candidates:  # the re-ranker proposed no tile: no fix, as when
                raise recorder.insufficient(  # every candidate fails (the VIO fallback's cue)
                    FrameEvidence(0, dropped=0), 0, [], self.settings.min_inliers_threshold
                )
            return self._match(frame, rerank_result, calibration, recorder)
        except BaseException as exc:
            if isinstance(exc, MatcherBackboneError | InsufficientInliersError) and recorder.ended:
                raise  # the frame's own, recorded (one a plugin raised is not: internal)
            if is_stop(exc):  # Ctrl-C, SIGTERM's, the host's sys.exit, a closing generator:
                recorder.interrupted(exc)  # they go on, the frame recorded first where safe
                raise
            recorder.internal_error(exc)  # a bug (an internal check included) or a plugin's
            raise MatcherBackboneError("internal", None, exc) from exc  # own BaseException

    # -- steps ------------------------------------------------------------------------------
    def _match(
        self,
        frame: NavCameraFrame,
        rerank: RerankResult,
        calibration: CameraCalibration,
        recorder: FrameRecorder,
    ) -> MatchResult:
        started = time.perf_counter()
        timings: dict[str, float] = {}
        scales = self._scales(frame, calibration, rerank.candidates, recorder, timings)  # 1-2
        candidates = [  # steps 3-4
            self._candidate(index, candidate, scales, recorder)
            for index, candidate in enumerate(rerank.candidates)
        ]
        survivors = [c for c in candidates if isinstance(c, Survivor)]
        refine = None
        if self.settings.refine and survivors:
            survivors, refine = self._refine.run(frame, calibration, scales, survivors, recorder)
        search = scales.rotation_search
        evidence = FrameEvidence.of(candidates, rotation_search=search, refine=refine)
        best_count = best_inlier_count(survivors)  # step 5
        recorder.candidates(survivors)
        threshold = self.settings.min_inliers_threshold
        survivors = ranked(survivors)  # step 7 (best first in the no-fix record too)
        enough = bool(survivors) and best_count >= threshold  # step 6
        rival = ambiguity(survivors, rerank.candidates, calibration) if enough else None
        if not enough or rival is not None:  # no fix, with the frame's timings too
            timings["total"] = (time.perf_counter() - started) * 1e3
            raise recorder.insufficient(
                evidence, best_count, survivors, threshold, timings=timings, ambiguity=rival
            )
        best = survivors[0].match_set
        if best.per_candidate_residual_px > self.settings.residual_warn_threshold_px:  # step 8
            recorder.residual_above_threshold(best, self.settings.residual_warn_threshold_px)
        timings["total"] = (time.perf_counter() - started) * 1e3
        diagnostics = self._diagnostics(evidence, survivors, scales, timings)
        rectification = scales.of(survivors[0].input_index).query.image.working_from_undistorted
        result = MatchResult(  # step 11 first: once the frame is recorded nothing may fail it
            frame_id=rerank.frame_id,
            per_candidate=tuple(s.match_set for s in survivors),
            best_candidate_idx=0,
            reprojection_residual_px=best.per_candidate_residual_px,
            matched_at=recorder.now_ns(),  # the frame's one reading of the clock
            matcher_label=self.label,
            candidates_input=evidence.candidates_input,
            candidates_dropped=evidence.dropped,
            diagnostics=diagnostics,
        )
        recorder.frame_done(evidence, survivors, rectification, timings, threshold)  # steps 9-10
        return result

    def _scales(
        self,
        frame: NavCameraFrame,
        calibration: CameraCalibration,
        candidates: Sequence[RerankCandidate],
        recorder: FrameRecorder,
        timings: dict[str, float],
    ) -> FrameScales:
        """Steps 1-2, once per GSD of the candidates (``stages.scales``); the frame failing at
        every GSD is a query failure (``query_extract``)."""
        try:
            return prepare_scales(
                self._pre,
                self._extraction,
                frame,
                calibration,
                candidates,
                rotation_search=self.settings.rotation_search,
                verification=self._verification,
                timings=timings,
            )
        except BaseException as exc:  # a plugin's own BaseException too
            if is_stop(exc):  # Ctrl-C, a signal handler's exit: they go on
                raise
            recorder.query_failed(exc)
            raise MatcherBackboneError("query_extract", None, exc) from exc

    def _candidate(
        self,
        index: int,
        candidate: RerankCandidate,
        scales: FrameScales,
        recorder: FrameRecorder,
    ) -> Survivor | Dropped:
        """Steps 3-4 for one candidate: features, matching against the query at its GSD (its
        one of ``scales``) and verification; a backbone failure drops it (recorded with its
        phase), as do zero inliers and a refusal on geometry."""
        timings: dict[str, float] = {}
        if index in scales.failed:  # the frame could not be prepared at its GSD
            failure = scales.failed[index]
            recorder.backbone_error(candidate.tile_id, "query_extract", failure, index)
            return Dropped(index, "none", timings)
        scale = scales.of(index)
        query, verifier = scale.query, scale.verifier
        try:
            tile = self._tiles.fetch(candidate, recorder, timings)
            verdict = candidate_verdict(  # query points in ORIGINAL frame px
                self.backend, verifier, query, candidate.tile_id, tile, timings
            )
        except CandidateStepError as failure:  # drop and continue
            recorder.backbone_error(
                candidate.tile_id, failure.phase, failure.cause, candidate_index=index
            )
            return Dropped(index, failure.source, timings)
        match_set = verdict.match_set
        if match_set.inlier_count == 0:  # step 4e
            recorder.zero_inliers(candidate.tile_id, index, verdict.raw_matches)
            return Dropped(index, tile.source, timings)
        if verdict.refused:  # refused on geometry, whatever its inliers
            refusal = verdict.refusal(index, query.rotation_search)
            recorder.geometry_refused(refusal)
            return Dropped(index, tile.source, timings, refusal)
        return Survivor(
            match_set, index, verdict.homography, verdict.rotation_deg, tile, verdict.model, timings
        )

    def _diagnostics(
        self,
        evidence: FrameEvidence,
        survivors: Sequence[Survivor],
        scales: FrameScales,
        timings: dict[str, float],
    ) -> dict[str, Any]:
        """``MatchResult.diagnostics``: timings, the survivors' input order, homographies
        (from WORKING px of each one's query, and ``query_to_tile`` from UNDISTORTED px), turns
        and models, whether the frame ran with a geometric prior, the tile cache's counters and
        the frame's evidence."""
        cache = self._tiles.cache
        return {
            "timings_ms": dict(timings),
            "per_candidate_timings_ms": list(evidence.per_candidate_ms),
            "input_index": [s.input_index for s in survivors],
            "homographies": [s.homography for s in survivors],
            "query_to_tile": [scales.query_to_tile(s) for s in survivors],
            "tile_cache": {"hits": cache.hits, "misses": cache.misses},
            "candidate_features": list(evidence.sources),
            "geometric_prior": scales.geometric_prior,
            "geometry_refused": [r.as_record() for r in evidence.refused],
            "rotation_search": evidence.rotation_search,
            "rotation_deg": [s.rotation_deg for s in survivors],
            "models": [s.model for s in survivors],
            "refine": evidence.refine.as_record() if evidence.refine is not None else None,
        }


def _close_failed(exc: Exception) -> None:
    """A sink close kept for the end of a frame failed (records it could not write)."""
    log_event("ERROR", FDR_WRITE_FAILED, f"closing after the frame: {exc}", error=describe(exc))
