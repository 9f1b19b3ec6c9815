"""The shared per-frame pipeline every strategy runs (the specification's steps 1-11, written once).

A strategy supplies only its model I/O as a ``FeatureBackend`` (extract features of a prepared
image, match two feature sets); this module does the rest: preprocessing, the per-candidate loop
with drop-and-continue, RANSAC through the shared ``RansacFilter``, the deterministic
ranking, the single health update, the logs and the FDR records.

Terminal FDR record per ``match`` call, exactly one of: ``matcher.frame_done`` (success),
``matcher.insufficient_inliers`` (raised InsufficientInliersError), or ``matcher.backbone_error``
with ``phase="query_extract"`` (the query frame itself failed). Per dropped
candidate, one ``matcher.backbone_error`` record with its ``tile_id`` and ``phase``.

Rotation search (``rotation_search``; off by default): a frame WITHOUT attitude is not
rectified, so its heading is unknown. With the option on, such a query is extracted turned by
0/90/180/270 deg (``np.rot90`` of the prepared image and its valid mask, the turn composed into
the engine -> working map, so correspondences still come back in WORKING px of the unturned
query); every candidate is matched against each turn and keeps the turn whose result ranks best
under ``ranking_key`` (inliers, then residual; the first turn on a tie). The kept turn is in
``diagnostics["rotation_deg"]`` and the FDR records (``rotation_deg`` per candidate).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, NoReturn, Protocol

import numpy as np
from numpy.typing import NDArray

from c3_matcher.config import MatcherSettings
from c3_matcher.dto import (
    CameraCalibration,
    CandidateMatchSet,
    MatcherHealth,
    MatchResult,
    NavCameraFrame,
    RerankCandidate,
    RerankResult,
    ranking_key,
)
from c3_matcher.errors import (
    InsufficientInliersError,
    InvalidInputError,
    MatcherBackboneError,
)
from c3_matcher.features import Features, RawMatches
from c3_matcher.health import RollingHealthWindow
from c3_matcher.logs import log_event
from c3_matcher.preprocess import FramePreprocessor, InputRule, PreparedImage, QueryGeometry
from c3_matcher.prior import GeometricPrior, HomographyCheck, PriorTolerances
from c3_matcher.protocols import Clock, FdrClient, RansacFilter
from c3_matcher.ransac import MIN_CORRESPONDENCES, homography_residuals
from c3_matcher.tile_cache import CachedTile, TileFeatureCache, tile_cache_key
from c3_matcher.tilestore.features import FeatureRequest

__all__ = ["QUERY_ROTATIONS_DEG", "FeatureBackend", "PipelineMatcher", "PipelineSettings"]

QUERY_ROTATIONS_DEG = (0, 90, 180, 270)  # rotation search: counter-clockwise turns of the query


class FeatureBackend(Protocol):
    """A strategy's model I/O. Exceptions raised here become per-candidate drops (or, for the
    query frame, a MatcherBackboneError); they never escape ``match`` otherwise."""

    @property
    def label(self) -> str:
        """``matcher_label`` of the results, e.g. ``"disk_lightglue"``."""
        ...

    @property
    def input_rule(self) -> InputRule: ...

    @property
    def extract_phase(self) -> str:
        """Phase name of an extraction failure, e.g. ``"disk_forward"``."""
        ...

    @property
    def match_phase(self) -> str:
        """Phase name of a matching failure, e.g. ``"lightglue_match"``."""
        ...

    def extract(self, image: PreparedImage) -> Features: ...

    def match(self, query: Features, tile: Features) -> RawMatches: ...

    def provenance(self) -> Mapping[str, Any]:
        """What an investigator needs after a flight: execution provider, engines' sha256."""
        ...


@dataclass(frozen=True, slots=True)
class PipelineSettings:
    """The specified thresholds (from ``MatcherSettings``)."""

    min_inliers_threshold: int = 60
    residual_warn_threshold_px: float = 2.5
    ransac_threshold_px: float = 3.0
    use_stored_features: bool = True  # a store's map features when built (else: extract)
    # only acts when the frame had attitude and height; defaults from [matcher]
    geometric_prior: bool = True
    prior_tolerances: PriorTolerances = field(default_factory=PriorTolerances)
    photometric: str = "none"  # query and tiles alike (preprocess.normalise_photometry)
    rotation_search: bool = False  # frames without attitude tried at 4 turns (opt-in)
    refine: bool = False  # a second pass through the best candidate's homography

    @classmethod
    def from_settings(cls, matcher: MatcherSettings) -> PipelineSettings:
        """Every pipeline setting from ``[matcher]`` (thresholds, stored features, the prior)."""
        return cls(
            matcher.min_inliers_threshold,
            matcher.residual_warn_threshold_px,
            matcher.ransac_threshold_px,
            matcher.stored_features,
            matcher.geometric_prior,
            PriorTolerances(
                rotation_deg=matcher.prior_rotation_tol_deg,
                scale=matcher.prior_scale_tol,
                shear=matcher.prior_shear_tol,
                base_px=matcher.prior_base_tol_px,
            ),
            matcher.photometric or "none",  # unset: resolved per strategy before (upstream here)
            matcher.rotation_search,
            matcher.refine,
        )

    def with_thresholds(
        self, min_inliers: int, residual_warn_px: float, ransac_px: float
    ) -> PipelineSettings:
        """These settings with a strategy config's thresholds."""
        return dataclasses.replace(
            self,
            min_inliers_threshold=min_inliers,
            residual_warn_threshold_px=residual_warn_px,
            ransac_threshold_px=ransac_px,
        )


@dataclass
class _Survivor:
    match_set: CandidateMatchSet
    input_index: int
    homography: NDArray[np.float64] | None
    rotation_deg: int = 0
    tile_image: PreparedImage | None = None  # kept for the refine pass
    tile: Features | None = None
    model: str = "homography"  # or "similarity" (_TurnOutcome.model)


@dataclass(frozen=True)
class _QueryView:
    """One extracted view of the query: its turn (deg, counter-clockwise), image, features."""

    rotation_deg: int
    image: PreparedImage
    features: Features


@dataclass
class _TurnOutcome:
    """A candidate matched against one query view: what RANSAC (and the prior) made of it."""

    rotation_deg: int
    match_set: CandidateMatchSet  # WORKING-px query points until the candidate is kept
    homography: NDArray[np.float64] | None
    check: HomographyCheck | None
    raw_matches: int
    model: str = "homography"  # "similarity": the prior's model, after the homography failed


@dataclass
class _FrameState:
    frame_id: Any
    candidates_input: int
    dropped: int = 0
    backbone_errors: int = 0
    health_updated: bool = False
    timings_ms: dict[str, float] = field(default_factory=dict)
    per_candidate_ms: list[dict[str, float]] = field(default_factory=list)
    feature_sources: list[str] = field(default_factory=list)
    prior: GeometricPrior | None = None
    geometry_refused: list[dict[str, Any]] = field(default_factory=list)
    rotation_search: bool = False  # this frame's query was extracted at every turn
    refine: dict[str, Any] | None = None  # the refine pass's record, when it ran


class PipelineMatcher:
    """The one ``CrossDomainMatcher`` of every strategy: the per-frame loop over a strategy's
    ``FeatureBackend``. Single-threaded. ``tile_cache_size`` tiles keep their features
    between frames (0: off)."""

    def __init__(
        self,
        backend: FeatureBackend,
        ransac_filter: RansacFilter,
        fdr_client: FdrClient,
        health_window: RollingHealthWindow,
        clock: Clock,
        settings: PipelineSettings,
        *,
        tile_cache_size: int = 0,
        preprocessor: FramePreprocessor | None = None,
    ) -> None:
        self._backend = backend
        self._ransac = ransac_filter
        self._fdr = fdr_client
        self._health = health_window
        self._clock = clock
        self._settings = settings
        self._pre = preprocessor or FramePreprocessor(
            backend.input_rule, photometric=settings.photometric
        )
        self._cache = TileFeatureCache(tile_cache_size)
        self._feature_request = _feature_request(backend, self._pre)
        self._use_stored = settings.use_stored_features and self._feature_request is not None

    @property
    def stored_features(self) -> bool:
        """Whether candidate features come from precomputed map features when the tile store
        has them (``features build``); False: always extract (the bench's comparison)."""
        return self._use_stored

    @stored_features.setter
    def stored_features(self, enabled: bool) -> None:
        self._use_stored = bool(enabled) and self._feature_request is not None

    @property
    def backend(self) -> FeatureBackend:
        return self._backend

    @property
    def settings(self) -> PipelineSettings:
        return self._settings

    def health_snapshot(self) -> MatcherHealth:
        return self._health.snapshot()

    # -- the contract -----------------------------------------------------------------------
    def match(
        self, frame: NavCameraFrame, rerank_result: RerankResult, calibration: CameraCalibration
    ) -> MatchResult:
        state = _FrameState(
            getattr(rerank_result, "frame_id", None),
            len(getattr(rerank_result, "candidates", ()) or ()),
        )
        try:
            _check_inputs(frame, rerank_result, calibration)
            if frame is None:  # no nav frame arrived: a query failure, as a decode failure is
                self._query_failed(state, InvalidInputError("frame", "is None (no nav frame)"))
            if rerank_result.frame_id != frame.frame_id:  # candidates of another frame
                state.frame_id, state.dropped = frame.frame_id, state.candidates_input
                self._insufficient(state, 0, [], stale_rerank_frame_id=rerank_result.frame_id)
            return self._match(frame, rerank_result, calibration, state)
        except (MatcherBackboneError, InsufficientInliersError):
            raise
        except InvalidInputError as exc:  # refused input still leaves its evidence in the FDR
            self._update_health(state, 0)
            self._record(
                "matcher.invalid_input",
                {"frame_id": state.frame_id, "field": exc.field, "error": str(exc)},
            )
            raise
        except Exception as exc:  # a bug must not take the vehicle down: contract error instead
            self._update_health(state, 0, force_backbone_error=True)
            self._record_backbone_error(state, None, "internal", exc)
            raise MatcherBackboneError("internal", None, exc) from exc

    # -- steps ------------------------------------------------------------------------------
    def _match(
        self,
        frame: NavCameraFrame,
        rerank: RerankResult,
        calibration: CameraCalibration,
        state: _FrameState,
    ) -> MatchResult:
        started = time.perf_counter()
        try:  # steps 1-2: the query frame, once (a failure is a query failure)
            with _timed(state.timings_ms, "query_preprocess"):
                geometry = self._pre.query_geometry(
                    frame, calibration, _tile_gsd(rerank.candidates)
                )
                query_image = self._pre.render_query(frame, calibration, geometry)
                # rotation search: only for a frame without attitude (unknown heading)
                state.rotation_search = self._settings.rotation_search and frame.attitude is None
                turns = QUERY_ROTATIONS_DEG if state.rotation_search else (0,)
                images = [(deg, _turned(query_image, deg)) for deg in turns]
            with _timed(state.timings_ms, "query_extract"):
                views = [
                    _QueryView(deg, image, self._backend.extract(image)) for deg, image in images
                ]
        except Exception as exc:
            self._query_failed(state, exc)
        state.prior = self._prior(query_image)

        survivors: list[_Survivor] = []
        for index, candidate in enumerate(rerank.candidates):  # steps 3-4
            timings: dict[str, float] = {}
            state.per_candidate_ms.append(timings)
            survivor = self._match_candidate(index, candidate, query_image, views, state, timings)
            if survivor is not None:
                survivors.append(survivor)
        if self._settings.refine and survivors:
            self._refine(frame, calibration, geometry, query_image, survivors, state)

        best_count = max((s.match_set.inlier_count for s in survivors), default=0)  # step 5
        candidates_summary = [
            (s.match_set.inlier_count, s.match_set.per_candidate_residual_px) for s in survivors
        ]
        log_event(
            "DEBUG",
            "c3.matcher.candidates",
            f"C3 frame={state.frame_id} candidates={candidates_summary}",
            frame_id=state.frame_id,
            candidates=candidates_summary,
        )
        if not survivors or best_count < self._settings.min_inliers_threshold:  # step 6
            return self._insufficient(state, best_count, survivors)

        survivors.sort(key=lambda s: ranking_key(s.match_set))  # step 7, stable
        best = survivors[0].match_set
        if best.per_candidate_residual_px > self._settings.residual_warn_threshold_px:  # step 8
            log_event(
                "WARNING",
                "c3.matcher.residual_above_threshold",
                f"C3 residual={best.per_candidate_residual_px:.2f}px > threshold="
                f"{self._settings.residual_warn_threshold_px}px; frame={state.frame_id}; "
                "will refine",
                residual_px=best.per_candidate_residual_px,
                threshold_px=self._settings.residual_warn_threshold_px,
                frame_id=state.frame_id,
                tile_id=best.tile_id,
            )
        self._update_health(state, best.inlier_count)  # step 9
        state.timings_ms["total"] = (time.perf_counter() - started) * 1e3
        diagnostics = {
            "timings_ms": dict(state.timings_ms),
            "per_candidate_timings_ms": list(state.per_candidate_ms),
            "input_index": [s.input_index for s in survivors],
            "homographies": [s.homography for s in survivors],
            "tile_cache": {"hits": self._cache.hits, "misses": self._cache.misses},
            "candidate_features": list(state.feature_sources),
            "geometric_prior": state.prior is not None,
            "geometry_refused": list(state.geometry_refused),
            "rotation_search": state.rotation_search,
            "rotation_deg": [s.rotation_deg for s in survivors],
            "models": [s.model for s in survivors],
            "refine": state.refine,
        }
        self._record(
            "matcher.frame_done",
            {  # step 10 (+ homography, timings, provider, engines)
                "frame_id": state.frame_id,
                "candidates_input": state.candidates_input,
                "candidates_dropped": state.dropped,
                "best_inlier_count": best.inlier_count,
                "best_residual_px": best.per_candidate_residual_px,
                "best_tile_id": best.tile_id,
                "best_homography": survivors[0].homography,
                "per_candidate": _per_candidate_records(state, survivors),
                "candidate_features": list(state.feature_sources),
                **_rotation_record(state),
                **_refine_record(state),
                "timings_ms": state.timings_ms,
                **self._backend.provenance(),
            },
        )
        return MatchResult(  # step 11
            frame_id=rerank.frame_id,
            per_candidate=tuple(s.match_set for s in survivors),
            best_candidate_idx=0,
            reprojection_residual_px=best.per_candidate_residual_px,
            matched_at=self._clock.monotonic_ns(),
            matcher_label=self._backend.label,
            candidates_input=state.candidates_input,
            candidates_dropped=state.dropped,
            diagnostics=diagnostics,
        )

    def _match_candidate(
        self,
        index: int,
        candidate: RerankCandidate,
        query_image: PreparedImage,
        views: list[_QueryView],
        state: _FrameState,
        timings: dict[str, float],
    ) -> _Survivor | None:
        tile_id = candidate.tile_id
        phase = "tile_decode"
        state.feature_sources.append("none")
        try:
            stored = None
            if self._use_stored:
                with _timed(timings, "assemble"):
                    stored = self._stored(candidate, state)
            key = (
                tile_cache_key(tile_id, candidate.tile_pixels_handle)
                if self._cache.enabled and stored is None
                else None
            )
            cached = self._cache.get(key) if key is not None else None
            if stored is not None:
                tile_image, tile = stored
                state.feature_sources[-1] = "stored"
            elif cached is not None:
                tile_image, tile = cached.prepared, cached.features
                state.feature_sources[-1] = "cached"
            else:
                state.feature_sources[-1] = "extracted"
                with _timed(timings, "decode"):
                    pixels = candidate.tile_pixels_handle.decode()
                with _timed(timings, "preprocess"):
                    tile_image = self._pre.prepare_tile(pixels)
                phase = self._backend.extract_phase
                with _timed(timings, "extract"):
                    tile = self._backend.extract(tile_image)
                if key is not None:
                    self._cache.put(key, CachedTile(tile_image, tile))
            chosen: _TurnOutcome | None = None
            for view in views:  # one view, or every turn (rotation search)
                phase = self._backend.match_phase
                with _timed(timings, "match"):
                    raw = self._backend.match(view.features, tile)
                    correspondences = _correspondences(
                        view.image, view.features, tile_image, tile, raw
                    )
                phase = "ransac"
                with _timed(timings, "ransac"):
                    outcome = self._verify(tile_id, view.rotation_deg, correspondences, state)
                outcome.raw_matches = len(raw)
                if chosen is None or _turn_rank(outcome) < _turn_rank(chosen):  # first on ties
                    chosen = outcome
            assert chosen is not None  # views is never empty
            inliers = chosen.match_set.inlier_correspondences
            check = chosen.check
            if inliers.shape[0] > 0:
                with _timed(timings, "ransac"):
                    inliers = _in_original_px(query_image, inliers)
        except Exception as exc:  # drop and continue
            state.dropped += 1
            state.backbone_errors += 1
            self._record_backbone_error(state, tile_id, phase, exc, candidate_index=index)
            return None
        if inliers.shape[0] == 0:  # step 4e
            state.dropped += 1
            log_event(
                "DEBUG",
                "c3.matcher.zero_inliers",
                f"C3 zero inliers; frame={state.frame_id}; tile={tile_id}",
                frame_id=state.frame_id,
                tile_id=tile_id,
                raw_matches=chosen.raw_matches,
            )
            return None
        if check is not None and not check.ok:  # refused on geometry, whatever its inliers
            state.dropped += 1
            refused = {
                "tile_id": tile_id,
                "candidate_index": index,
                "inlier_count": int(inliers.shape[0]),
                "reason": check.reason,
            }
            if state.rotation_search:
                refused["rotation_deg"] = chosen.rotation_deg
            state.geometry_refused.append(refused)
            log_event(
                "DEBUG",
                "c3.matcher.geometry_refused",
                f"C3 candidate refused on geometry; frame={state.frame_id}; tile={tile_id}; "
                f"inliers={inliers.shape[0]}; {check.reason}",
                frame_id=state.frame_id,
                **refused,
            )
            return None
        match_set = dataclasses.replace(chosen.match_set, inlier_correspondences=inliers)
        return _Survivor(
            match_set,
            index,
            chosen.homography,
            chosen.rotation_deg,
            tile_image,
            tile,
            chosen.model,
        )

    def _refine(
        self,
        frame: NavCameraFrame,
        calibration: CameraCalibration,
        geometry: QueryGeometry,
        query_image: PreparedImage,
        survivors: list[_Survivor],
        state: _FrameState,
    ) -> None:
        """The refine pass, in place: the best-ranked survivor's query re-rendered
        through its first homography into the tile's pixel grid (same scale and orientation as
        the tile, perspective removed), extracted and matched again, then put through the same
        prior vote, RANSAC and geometry check. The matcher never sees the first homography, so
        the second pass's inliers are evidence of their own; it replaces the first only when it
        passes and ranks better (``ranking_key``). Any failure leaves the first pass standing."""
        top = min(range(len(survivors)), key=lambda i: ranking_key(survivors[i].match_set))
        first = survivors[top]
        if first.homography is None or first.tile_image is None or first.tile is None:
            return
        record: dict[str, Any] = {
            "candidate_index": first.input_index,
            "inliers_before": first.match_set.inlier_count,
            "inliers_after": 0,
            "kept": False,
        }
        state.refine = record
        timings = state.per_candidate_ms[first.input_index]
        try:
            with _timed(timings, "refine"):
                refined = self._pre.refined_geometry(
                    geometry, first.homography, first.tile_image.working_size
                )
                if refined is None:
                    record["reason"] = "the first homography leaves no footprint on the tile"
                    return
                image = self._pre.render_query(frame, calibration, refined)
                features = self._backend.extract(image)
                raw = self._backend.match(features, first.tile)
                correspondences = _correspondences(
                    image, features, first.tile_image, first.tile, raw
                )
                outcome = self._verify(
                    first.match_set.tile_id, first.rotation_deg, correspondences, state
                )
        except Exception as exc:  # the first pass stands; the failure is on record
            record["reason"] = f"{type(exc).__name__}: {exc}"
            log_event(
                "WARNING",
                "c3.matcher.refine_failed",
                f"C3 refine pass failed, first pass kept; frame={state.frame_id}; {exc}",
                frame_id=state.frame_id,
                tile_id=first.match_set.tile_id,
            )
            return
        record["inliers_after"] = outcome.match_set.inlier_count
        if outcome.check is not None and not outcome.check.ok:
            record["reason"] = f"refused on geometry: {outcome.check.reason}"
            return
        if outcome.match_set.inlier_count == 0 or ranking_key(outcome.match_set) >= ranking_key(
            first.match_set
        ):
            record["reason"] = "ranks no better than the first pass"
            return
        record["kept"] = True
        match_set = dataclasses.replace(
            outcome.match_set,
            inlier_correspondences=_in_original_px(
                query_image, outcome.match_set.inlier_correspondences
            ),
        )
        survivors[top] = dataclasses.replace(
            first, match_set=match_set, homography=outcome.homography, model=outcome.model
        )

    def _verify(
        self,
        tile_id: Any,
        rotation_deg: int,
        correspondences: NDArray[np.float32],
        state: _FrameState,
    ) -> _TurnOutcome:
        """The prior's translation vote (if any), RANSAC, and the prior's geometry check (if
        any) of one query view's correspondences (WORKING px of the unturned query)."""
        prefiltered = 0
        if state.prior is not None:  # before RANSAC: the translation vote
            keep = state.prior.consistent(correspondences)
            prefiltered = int(correspondences.shape[0] - keep.sum())
            correspondences = np.ascontiguousarray(correspondences[keep])
        threshold = self._settings.ransac_threshold_px
        ransac = self._ransac.filter(correspondences, threshold)
        inliers = ransac.inlier_correspondences
        outliers = ransac.ransac_outlier_count
        residual = ransac.per_candidate_residual_px
        homography = ransac.homography
        check = None
        model = "homography"
        if state.prior is not None and homography is not None and len(inliers):
            check = state.prior.verify(homography)  # after RANSAC: geometry
            if not check.ok:  # the model the prior implies, before refusing the candidate
                fit = state.prior.similarity_ransac(correspondences, threshold)
                if fit is not None and int(fit[1].sum()) >= MIN_CORRESPONDENCES:
                    similarity, mask = fit
                    constrained = state.prior.verify(similarity)
                    if constrained.ok:
                        inliers = np.ascontiguousarray(correspondences[mask])
                        outliers = int(correspondences.shape[0] - inliers.shape[0])
                        residual = float(np.median(homography_residuals(similarity, inliers)))
                        homography, check, model = similarity, constrained, "similarity"
        match_set = CandidateMatchSet(
            tile_id=tile_id,
            inlier_count=int(inliers.shape[0]),
            inlier_correspondences=inliers,
            ransac_outlier_count=outliers + prefiltered,
            per_candidate_residual_px=residual,
        )
        return _TurnOutcome(rotation_deg, match_set, homography, check, 0, model)

    def _stored(
        self, candidate: RerankCandidate, state: _FrameState
    ) -> tuple[PreparedImage, Features] | None:
        """The candidate's precomputed map features, or None (extract): a handle without
        ``stored_features``, no or stale stored features, a window the rule would resize. A
        failure here never drops the candidate: it falls back to extraction; the store raises
        once per outage (locked sidecar) or corrupt row, so the WARNING (and its FDR record)
        comes once, not every frame."""
        serve = getattr(candidate.tile_pixels_handle, "stored_features", None)
        if not callable(serve) or self._feature_request is None:
            return None
        try:
            features = serve(self._feature_request)
            if not isinstance(features, Features):
                return None
            geometry = self._pre.tile_geometry(*features.image_size)
        except Exception as exc:
            log_event(
                "WARNING",
                "c3.matcher.stored_features_failed",
                f"C3 stored features unusable; frame={state.frame_id}; "
                f"tile={candidate.tile_id}; extracting instead: {type(exc).__name__}: {exc}",
                frame_id=state.frame_id,
                tile_id=candidate.tile_id,
            )
            return None
        return None if geometry is None else (geometry, features)

    def _query_failed(self, state: _FrameState, exc: Exception) -> NoReturn:
        """The nav frame itself could not be decoded or extracted: health (0, backbone error),
        a ``query_extract`` backbone-error record, ``MatcherBackboneError``."""
        self._update_health(state, 0, force_backbone_error=True)
        self._record_backbone_error(state, None, "query_extract", exc)
        raise MatcherBackboneError("query_extract", None, exc) from exc

    def _insufficient(
        self,
        state: _FrameState,
        best_count: int,
        survivors: list[_Survivor],
        *,
        stale_rerank_frame_id: Any = None,
    ) -> NoReturn:
        """No fix for this frame: health 0, log, FDR record, ``InsufficientInliersError``. With
        ``stale_rerank_frame_id`` every candidate was dropped unmatched: the re-rank was made
        for that other frame, so its tiles say where the vehicle was, not where it is."""
        threshold = self._settings.min_inliers_threshold
        label = self._backend.label
        stale = {} if stale_rerank_frame_id is None else {"stale_rerank": stale_rerank_frame_id}
        self._update_health(state, 0)  # best_inlier_count=0
        log_event(
            "ERROR",
            "c3.matcher.insufficient_inliers",
            f"C3 insufficient inliers on all candidates; frame={state.frame_id}; "
            f"backbone={label}; best={best_count} < {threshold}"
            + ("" if not stale else f"; re-rank is for frame {stale_rerank_frame_id}"),
            frame_id=state.frame_id,
            backbone=label,
            best_inlier_count=best_count,
            threshold=threshold,
            candidates_input=state.candidates_input,
            candidates_dropped=state.dropped,
            **stale,
        )
        self._record(
            "matcher.insufficient_inliers",
            {
                "frame_id": state.frame_id,
                **stale,
                "candidates_input": state.candidates_input,
                "candidates_dropped": state.dropped,
                "best_inlier_count": best_count,
                "threshold": threshold,
                "per_candidate": _per_candidate_records(state, survivors),
                "candidate_features": list(state.feature_sources),
                "geometry_refused": list(state.geometry_refused),
                **_rotation_record(state),
                **_refine_record(state),
                **self._backend.provenance(),
            },
        )
        raise InsufficientInliersError(
            state.frame_id, best_count, threshold, state.candidates_input, state.dropped, label
        )

    # -- helpers ----------------------------------------------------------------------------
    def _prior(self, query: PreparedImage) -> GeometricPrior | None:
        """The geometric prior of a query rectified with attitude AND scaled with height to the
        tile GSD; None without one of them, or when ``geometric_prior`` is off."""
        if not self._settings.geometric_prior:
            return None
        if query.nadir_working_px is None or query.working_gsd_m is None:
            return None
        w, h = query.working_size
        canvas = np.array([[0.0, 0.0], [w, 0.0], [w, h], [0.0, h]])
        return GeometricPrior(self._settings.prior_tolerances, query.nadir_working_px, canvas)

    def _update_health(
        self, state: _FrameState, best_inlier_count: int, *, force_backbone_error: bool = False
    ) -> None:
        if state.health_updated:  # exactly once per match call
            return
        state.health_updated = True
        self._health.update(
            self._clock.monotonic_ns(),
            best_inlier_count=best_inlier_count,
            had_backbone_error=force_backbone_error or state.backbone_errors > 0,
        )

    def _record(self, kind: str, payload: Mapping[str, Any]) -> None:
        """Write an FDR record; a recorder failure is logged, never fails the frame (the durable
        recorder keeps the record pending and writes it with the next one)."""
        try:
            self._fdr.record(kind, payload)
        except Exception as exc:
            log_event(
                "ERROR",
                "c3.fdr.write_failed",
                f"FDR write failed for {kind}: {exc}",
                record_kind=kind,
                error=f"{type(exc).__name__}: {exc}",
            )

    def _record_backbone_error(
        self,
        state: _FrameState,
        tile_id: Any,
        phase: str,
        exc: BaseException,
        candidate_index: int | None = None,
    ) -> None:
        error = f"{type(exc).__name__}: {exc}"
        log_event(
            "ERROR",
            "c3.matcher.backbone_error",
            f"C3 backbone error; frame={state.frame_id}; tile={tile_id}; phase={phase}; "
            f"backbone={self._backend.label}; {error}",
            frame_id=state.frame_id,
            tile_id=tile_id,
            phase=phase,
            error=error,
            backbone=self._backend.label,
        )
        self._record(
            "matcher.backbone_error",
            {
                "frame_id": state.frame_id,
                "tile_id": tile_id,
                "candidate_index": candidate_index,
                "phase": phase,
                "error": error,
                "backbone": self._backend.label,
            },
        )


def _source_of(state: _FrameState, index: int) -> str:
    return state.feature_sources[index] if index < len(state.feature_sources) else "none"


def _per_candidate_records(state: _FrameState, survivors: list[_Survivor]) -> list[dict[str, Any]]:
    """The survivors as FDR rows; ``rotation_deg`` (the kept turn) only under rotation search
    and ``model`` only for a candidate kept on the prior's similarity, so other records are as
    they were."""
    rows: list[dict[str, Any]] = []
    for s in survivors:
        row: dict[str, Any] = {
            "tile_id": s.match_set.tile_id,
            "inlier_count": s.match_set.inlier_count,
            "residual_px": s.match_set.per_candidate_residual_px,
            "features": _source_of(state, s.input_index),
        }
        if state.rotation_search:
            row["rotation_deg"] = s.rotation_deg
        if s.model != "homography":
            row["model"] = s.model
        rows.append(row)
    return rows


def _rotation_record(state: _FrameState) -> dict[str, Any]:
    """``rotation_search`` and the turns tried, in a terminal FDR record of a frame that ran
    the search; nothing otherwise."""
    if not state.rotation_search:
        return {}
    return {"rotation_search": True, "rotations_deg": list(QUERY_ROTATIONS_DEG)}


def _refine_record(state: _FrameState) -> dict[str, Any]:
    """The refine pass's record for the terminal FDR record: only when it ran."""
    return {"refine": dict(state.refine)} if state.refine is not None else {}


def _turn_rank(outcome: _TurnOutcome) -> tuple[bool, tuple[int, float]]:
    """Which turn of the query a candidate keeps: one the prior's geometry check does not
    refuse first (there is no prior without attitude, so in practice never in play), then the
    pipeline's own ranking rule (inliers descending, residual ascending)."""
    refused = outcome.check is not None and not outcome.check.ok
    return refused, ranking_key(outcome.match_set)


def rotation_from_turned(rotation_deg: int, width: int, height: int) -> NDArray[np.float64]:
    """3x3 map of ENGINE px of an image turned ``rotation_deg`` (a multiple of 90)
    counter-clockwise with ``np.rot90`` back to ENGINE px of the ``width`` x ``height`` image
    (pixel centres at integers)."""
    if rotation_deg % 90:
        raise ValueError(f"rotation_deg must be a multiple of 90, got {rotation_deg}")
    out = np.eye(3)
    w, h = width, height
    for _ in range((rotation_deg // 90) % 4):
        # one np.rot90 of a w-wide image: turned (x', y') reads unturned (w - 1 - y', x')
        out = out @ np.array([[0.0, -1.0, w - 1.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
        w, h = h, w
    return out


def _turned(image: PreparedImage, rotation_deg: int) -> PreparedImage:
    """``image`` turned ``rotation_deg`` counter-clockwise (pixels and valid mask), with the
    turn composed into ``working_from_engine``; ``image`` itself for 0."""
    if rotation_deg == 0:
        return image
    k = rotation_deg // 90
    w, h = image.engine_size
    return dataclasses.replace(
        image,
        image=np.ascontiguousarray(np.rot90(image.image, k)),
        valid=np.ascontiguousarray(np.rot90(image.valid, k)),
        working_from_engine=image.working_from_engine @ rotation_from_turned(rotation_deg, w, h),
    )


def _feature_request(backend: FeatureBackend, pre: FramePreprocessor) -> FeatureRequest | None:
    """What to ask a tile store's precomputed features for: the backend's extractor engine
    (file sha256) and execution provider from its provenance, input rule, photometric
    normalisation and keypoint budget; None when the backend does not say (its tiles are then
    always extracted)."""
    try:
        provenance = backend.provenance()
        engines = provenance.get("engines") or {}
        sha = (engines.get("extractor") or {}).get("file_sha256")
        provider = str(provenance.get("provider") or "")
        rule = backend.input_rule
    except Exception:
        return None
    budget = getattr(backend, "max_keypoints", None)
    if budget is None:  # the current backends keep it private
        config = getattr(backend, "_config", None)
        budget = getattr(config, "max_keypoints", None) or getattr(backend, "_max_keypoints", None)
    if not isinstance(sha, str) or not sha or not isinstance(budget, int) or budget < 1:
        return None
    return FeatureRequest(
        sha,
        rule.multiple,
        rule.max_long_side,
        budget,
        pre.border_erode_px,
        pre.photometric,
        provider,
    )


def _check_inputs(frame: object, rerank: object, calibration: object) -> None:
    """Refuse wrong types (a caller's programming error). ``frame=None`` and a re-rank of
    another frame are conditions of flight, answered with the contract's errors."""
    if frame is not None and not isinstance(frame, NavCameraFrame):
        raise InvalidInputError("frame", f"expected NavCameraFrame, got {type(frame).__name__}")
    if not isinstance(rerank, RerankResult):
        raise InvalidInputError(
            "rerank_result", f"expected RerankResult, got {type(rerank).__name__}"
        )
    if not isinstance(calibration, CameraCalibration):
        raise InvalidInputError(
            "calibration", f"expected CameraCalibration, got {type(calibration).__name__}"
        )


def _tile_gsd(candidates: tuple[RerankCandidate, ...]) -> float | None:
    """The GSD the query is scaled to: the median of the candidates' (they share a zoom)."""
    values = [c.ground_sample_distance_m() for c in candidates]
    return float(np.median(values)) if values else None


def _in_original_px(query_image: PreparedImage, rows: NDArray[np.float32]) -> NDArray[np.float32]:
    """(M, 4) rows with the query point moved from WORKING to ORIGINAL frame px."""
    original = query_image.working_to_original(rows[:, 0:2].astype(np.float64))
    return np.hstack([original, rows[:, 2:4]]).astype(np.float32)


def _correspondences(
    query_image: PreparedImage,
    query: Features,
    tile_image: PreparedImage,
    tile: Features,
    raw: RawMatches,
) -> NDArray[np.float32]:
    """(M, 4) rows (x_query, y_query, x_tile, y_tile) in working px (rectified query, full tile)."""
    if len(raw) == 0:
        return np.zeros((0, 4), dtype=np.float32)
    q = query_image.to_working(query.keypoints[raw.matches[:, 0]].astype(np.float64))
    t = tile_image.to_working(tile.keypoints[raw.matches[:, 1]].astype(np.float64))
    return np.hstack([q, t]).astype(np.float32)


@contextmanager
def _timed(into: dict[str, float], name: str) -> Iterator[None]:
    start = time.perf_counter()
    try:
        yield
    finally:
        into[name] = into.get(name, 0.0) + (time.perf_counter() - start) * 1e3
