"""Steps 4c-4d: a candidate matched against the query and verified.

With a geometric prior (a query rectified with attitude AND scaled with height to the tile
GSD): the prior's translation vote before RANSAC, RANSAC through the shared ``RansacFilter``,
then the prior's geometry check of the homography; a homography the check refuses is replaced
by the similarity the prior implies when that one passes (``model`` ``"similarity"``), else
the candidate is refused on geometry. Without a prior: RANSAC alone. Under rotation search the
candidate keeps the query turn whose result ranks best (first turn on a tie). Each candidate is
matched against the query scaled to its own GSD and verified with that query's prior
(:mod:`~c3_matcher.stages.scales`, which builds each query's :class:`Verifier` from the
frame's :class:`VerifierSettings`); its inliers come back in ORIGINAL frame px
(:func:`candidate_verdict`)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from c3_matcher.arrays import F32
from c3_matcher.dto import CandidateMatchSet, ranking_key
from c3_matcher.prepared import PreparedImage, correspondences
from c3_matcher.prior import GeometricPrior, HomographyCheck, PriorTolerances
from c3_matcher.protocols import FeatureBackend, RansacFilter
from c3_matcher.ransac import (
    MIN_CORRESPONDENCES,
    MIN_SPREAD_RATIO,
    homography_residuals,
    spread_ratio,
)
from c3_matcher.stages.failure import CandidateStepError, failing_as, timed
from c3_matcher.stages.matching import check_descriptors_fit, match_checked
from c3_matcher.stages.outcomes import GeometryRefusal, TileFeatures
from c3_matcher.stages.query import Query, QueryView

__all__ = [
    "SpreadCheck",
    "Verdict",
    "Verifier",
    "VerifierSettings",
    "best_turn",
    "candidate_verdict",
    "frame_prior",
]


@dataclass(frozen=True)
class Verdict:
    """A candidate matched against one query view: what RANSAC (and the prior) made of it.
    ``match_set`` query points are WORKING px of the unturned query (ORIGINAL frame px once
    :meth:`in_original_px`); ``homography`` maps WORKING px to tile px (the prior's similarity
    when ``model`` is ``"similarity"``); ``check`` is the prior's geometry check (None without
    a prior); ``raw_matches`` the matches before RANSAC."""

    rotation_deg: int
    match_set: CandidateMatchSet
    homography: NDArray[np.float64] | None
    check: HomographyCheck | SpreadCheck | None
    raw_matches: int = 0
    model: str = "homography"

    @property
    def refused(self) -> bool:
        """Refused on geometry by the prior, whatever its inliers."""
        return self.check is not None and not self.check.ok

    def turn_rank(self) -> tuple[bool, tuple[int, float]]:
        """Which turn of the query a candidate keeps: one the prior's geometry check does not
        refuse first (there is no prior without attitude, so in practice never in play), then
        the pipeline's own ranking rule (inliers descending, residual ascending)."""
        return self.refused, ranking_key(self.match_set)

    def in_original_px(self, query: PreparedImage) -> Verdict:
        """This verdict with its inliers' query points moved from WORKING px of ``query`` (the
        image it was matched against) to ORIGINAL frame px, as a ``Survivor`` holds them."""
        rows = query.in_original_px(self.match_set.inlier_correspondences)
        return replace(self, match_set=replace(self.match_set, inlier_correspondences=rows))

    def refusal(self, candidate_index: int, rotation_search: bool) -> GeometryRefusal:
        """The refusal on geometry of a refused verdict, as the records name it (its turn only
        under rotation search)."""
        assert self.check is not None
        turn = self.rotation_deg if rotation_search else None
        inliers = self.match_set.inlier_count
        return GeometryRefusal(
            self.match_set.tile_id, candidate_index, inliers, self.check.reason, turn
        )


@dataclass(frozen=True)
class SpreadCheck:
    """The check of a homography no geometric prior verifies (a frame without attitude or
    height): its inliers must spread across both directions on both sides
    (:data:`~c3_matcher.ransac.MIN_SPREAD_RATIO`). Points on or near one line (a road, a field
    edge) fix a homography only along that line; the prior's own check and its similarity
    fallback pin the rest where there is one, so only a frame without one is refused so."""

    spread: float
    reason: str = ""

    @property
    def ok(self) -> bool:
        return not self.reason

    @classmethod
    def of(cls, inliers: F32) -> SpreadCheck:
        """The check of ``inliers`` (rows x_q, y_q, x_t, y_t): the smaller side's spread."""
        spread = min(spread_ratio(inliers[:, 0:2]), spread_ratio(inliers[:, 2:4]))
        if spread >= MIN_SPREAD_RATIO or len(inliers) < MIN_CORRESPONDENCES:  # no homography
            return cls(spread)
        return cls(
            spread,
            f"inliers on one line (spread {spread:.2f} under {MIN_SPREAD_RATIO}): a homography "
            "fixed only along it",
        )


@dataclass(frozen=True)
class _Fit:
    inliers: F32
    outliers: int
    residual_px: float
    model_matrix: NDArray[np.float64] | None
    check: HomographyCheck | SpreadCheck | None = None
    model: str = "homography"


def frame_prior(
    query: PreparedImage, enabled: bool, tolerances: PriorTolerances
) -> GeometricPrior | None:
    """The geometric prior of a query rectified with attitude AND scaled with height to the
    tile GSD; None without one of them, or when the prior is not ``enabled``."""
    if not enabled:
        return None
    if query.nadir_working_px is None or query.working_gsd_m is None:
        return None
    w, h = query.working_size
    canvas = np.array([[0.0, 0.0], [w, 0.0], [w, h], [0.0, h]])
    return GeometricPrior(tolerances, query.nadir_working_px, canvas)


@dataclass(frozen=True)
class VerifierSettings:
    """What each query's :class:`Verifier` is built from (the pipeline's, fixed for its life):
    the shared ``ransac`` filter at ``threshold_px``, and whether the geometric prior is on
    (``geometric_prior``) with its ``prior_tolerances``."""

    ransac: RansacFilter
    threshold_px: float
    geometric_prior: bool
    prior_tolerances: PriorTolerances

    def verifier(self, query: PreparedImage) -> Verifier:
        """RANSAC and ``query``'s geometric prior (None without one: ``frame_prior``)."""
        prior = frame_prior(query, self.geometric_prior, self.prior_tolerances)
        return Verifier(self.ransac, self.threshold_px, prior)


@dataclass(frozen=True)
class Verifier:
    """The verification of one frame's candidates: RANSAC at ``threshold_px`` through
    ``ransac`` and the frame's geometric ``prior`` (None: none)."""

    ransac: RansacFilter
    threshold_px: float
    prior: GeometricPrior | None

    def verify(self, tile_id: Any, rotation_deg: int, rows: F32, raw_matches: int = 0) -> Verdict:
        """The prior's translation vote (if any), RANSAC, and the prior's geometry check (if
        any) of one query view's correspondence ``rows`` (WORKING px of the unturned query)."""
        prefiltered = 0
        if self.prior is not None:  # before RANSAC: the translation vote
            keep = self.prior.consistent(rows)
            prefiltered = int(rows.shape[0] - keep.sum())
            rows = np.ascontiguousarray(rows[keep])
        ransac = self.ransac.filter(rows, self.threshold_px)
        fit = _Fit(
            ransac.inlier_correspondences,
            ransac.ransac_outlier_count,
            ransac.per_candidate_residual_px,
            ransac.homography,
        )
        if fit.model_matrix is not None and len(fit.inliers):  # after RANSAC: geometry
            if self.prior is not None:
                fit = self._checked(self.prior, fit, rows)
            else:  # nothing pins what its inliers leave free: their spread must
                fit = replace(fit, check=SpreadCheck.of(fit.inliers))
        match_set = CandidateMatchSet(
            tile_id=tile_id,
            inlier_count=int(fit.inliers.shape[0]),
            inlier_correspondences=fit.inliers,
            ransac_outlier_count=fit.outliers + prefiltered,
            per_candidate_residual_px=fit.residual_px,
        )
        return Verdict(rotation_deg, match_set, fit.model_matrix, fit.check, raw_matches, fit.model)

    def _checked(self, prior: GeometricPrior, fit: _Fit, rows: F32) -> _Fit:
        """``fit`` with the prior's geometry check; a refused homography gives way to the
        similarity the prior implies when that one has enough inliers and passes."""
        assert fit.model_matrix is not None
        check = prior.verify(fit.model_matrix)
        if check.ok:
            return replace(fit, check=check)
        similarity_fit = prior.similarity_ransac(rows, self.threshold_px)
        if similarity_fit is None or int(similarity_fit[1].sum()) < MIN_CORRESPONDENCES:
            return replace(fit, check=check)
        similarity, mask = similarity_fit
        constrained = prior.verify(similarity)
        if not constrained.ok:
            return replace(fit, check=check)
        inliers = np.ascontiguousarray(rows[mask])
        residual = float(np.median(homography_residuals(similarity, inliers)))
        outliers = int(rows.shape[0] - inliers.shape[0])
        return _Fit(inliers, outliers, residual, similarity, constrained, "similarity")


def best_turn(
    backend: FeatureBackend,
    verifier: Verifier,
    views: Sequence[QueryView],
    tile_id: Any,
    tile: TileFeatures,
    timings: dict[str, float],
) -> Verdict:
    """The candidate matched against every query view (:func:`_matched_rows`: the backend's
    extract or match phase) and verified (``ransac``); the verdict of the best-ranked view
    (``Verdict.turn_rank``, the first on a tie). Raises ``CandidateStepError`` naming the failed
    phase."""
    chosen: Verdict | None = None
    for view in views:  # one view, or every turn (rotation search)
        rows, raw_matches = _matched_rows(backend, view, tile, timings)
        with failing_as("ransac", tile.source), timed(timings, "ransac"):
            verdict = verifier.verify(tile_id, view.rotation_deg, rows, raw_matches)
        if chosen is None or verdict.turn_rank() < chosen.turn_rank():  # first on ties
            chosen = verdict
    assert chosen is not None  # views is never empty
    return chosen


def _matched_rows(
    backend: FeatureBackend, view: QueryView, tile: TileFeatures, timings: dict[str, float]
) -> tuple[F32, int]:
    """The correspondence rows of ``view`` matched with ``tile`` and the count of raw matches.
    Descriptors that do not fit the query's fail the backend's extract phase
    (:func:`~c3_matcher.stages.matching.check_descriptors_fit`); a match that raises, returns
    no ``RawMatches``, or pairs an index of no keypoint or one keypoint twice, its match phase
    (``CandidateStepError``). Either way the tile leaves the tile cache (``tile.forget``): the
    next frame extracts it anew, so a backend that recovers recovers its tiles too."""
    try:
        with failing_as(backend.extract_phase, tile.source):
            check_descriptors_fit(view.features, tile.features, backend.label)
        with failing_as(backend.match_phase, tile.source), timed(timings, "match"):
            raw = match_checked(backend, view.features, tile.features)
            rows = correspondences(view.image, view.features, tile.image, tile.features, raw)
    except CandidateStepError:
        tile.forget()
        raise
    return rows, len(raw)


def candidate_verdict(
    backend: FeatureBackend,
    verifier: Verifier,
    query: Query,
    tile_id: Any,
    tile: TileFeatures,
    timings: dict[str, float],
) -> Verdict:
    """The candidate's verdict against ``query`` (:func:`best_turn` over its views) with its
    inliers' query points in ORIGINAL frame px; a point the lens model cannot map back fails
    the ``ransac`` phase (``CandidateStepError``), as RANSAC failing does."""
    verdict = best_turn(backend, verifier, query.views, tile_id, tile, timings)
    if verdict.match_set.inlier_count == 0:  # no point to move
        return verdict
    with failing_as("ransac", tile.source), timed(timings, "ransac"):
        return verdict.in_original_px(query.image)
