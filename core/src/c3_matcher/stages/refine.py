"""The refine pass (``refine``; off by default): the best-ranked survivor's query (the one it
was matched against, at its GSD) re-rendered
through its first homography into the tile's pixel grid (same scale and orientation as the
tile, perspective removed), extracted and matched again, then put through the same prior vote,
RANSAC and geometry check. The matcher never sees the first homography, so the second pass's
inliers are evidence of their own; it replaces the first only when it passes and ranks better
(``ranking_key``). Any failure leaves the first pass standing."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

from c3_matcher.dto import CameraCalibration, NavCameraFrame, ranking_key
from c3_matcher.errors import describe
from c3_matcher.prepared import correspondences
from c3_matcher.preprocess import FramePreprocessor
from c3_matcher.stages.extract import Extraction
from c3_matcher.stages.failure import timed
from c3_matcher.stages.interrupts import is_stop
from c3_matcher.stages.matching import match_checked
from c3_matcher.stages.outcomes import RefineRecord, Survivor
from c3_matcher.stages.ranking import top
from c3_matcher.stages.recorder import FrameRecorder
from c3_matcher.stages.scales import FrameScales, QueryScale
from c3_matcher.stages.verify import Verdict

__all__ = ["RefinePass"]

NO_FOOTPRINT = "the first homography leaves no footprint on the tile"


class RefinePass:
    """The refine pass of one matcher: its preprocessor renders, its ``extraction`` (the
    matcher's) extracts and its backend matches."""

    def __init__(self, pre: FramePreprocessor, extraction: Extraction) -> None:
        self._pre = pre
        self._extraction = extraction

    def run(
        self,
        frame: NavCameraFrame,
        calibration: CameraCalibration,
        scales: FrameScales,
        survivors: Sequence[Survivor],
        recorder: FrameRecorder,
    ) -> tuple[list[Survivor], RefineRecord | None]:
        """``survivors`` with the best one replaced by its second pass when that one is kept,
        and the pass's record (None when the best survivor has no homography to go through).
        The best one's query and verifier are those it was matched against.
        The pass's time is the best candidate's ``refine`` timing."""
        first = top(survivors)
        if first.homography is None:
            return list(survivors), None
        scale = scales.of(first.input_index)
        record = RefineRecord(first.input_index, first.match_set.inlier_count)
        try:
            with timed(first.timings, "refine"):
                verdict = self._second_pass(frame, calibration, scale, first)
        except BaseException as exc:  # the first pass stands (a plugin's own too)
            if is_stop(exc):  # Ctrl-C, a signal handler's exit: they go on
                raise
            recorder.refine_failed(first.match_set.tile_id, exc)
            return list(survivors), replace(record, reason=describe(exc))
        if verdict is None:
            return list(survivors), replace(record, reason=NO_FOOTPRINT)
        record = replace(record, inliers_after=verdict.match_set.inlier_count)
        if verdict.refused:
            assert verdict.check is not None
            return list(survivors), replace(
                record, reason=f"refused on geometry: {verdict.check.reason}"
            )
        if verdict.match_set.inlier_count == 0 or ranking_key(verdict.match_set) >= ranking_key(
            first.match_set
        ):
            return list(survivors), replace(record, reason="ranks no better than the first pass")
        match_set = verdict.in_original_px(scale.query.image).match_set
        second = replace(
            first, match_set=match_set, homography=verdict.homography, model=verdict.model
        )
        kept = [second if s is first else s for s in survivors]
        return kept, replace(record, kept=True)

    def _second_pass(
        self,
        frame: NavCameraFrame,
        calibration: CameraCalibration,
        scale: QueryScale,
        first: Survivor,
    ) -> Verdict | None:
        """``scale``'s query re-rendered through ``first``'s homography, extracted, matched with
        its tile and verified by ``scale``'s verifier; None when the homography leaves no
        footprint on the tile."""
        assert first.homography is not None
        tile = first.tile
        refined = self._pre.refined_geometry(
            scale.query.geometry, first.homography, tile.image.working_size
        )
        if refined is None:
            return None
        image = self._pre.render_query(frame, calibration, refined)
        features = self._extraction(image)
        raw = match_checked(self._extraction.backend, features, tile.features)
        rows = correspondences(image, features, tile.image, tile.features, raw)
        return scale.verifier.verify(first.match_set.tile_id, first.rotation_deg, rows)
