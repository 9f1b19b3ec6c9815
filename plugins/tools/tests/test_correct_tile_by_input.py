"""A frame's pick is judged correct by the input position of the candidate it picked (the
result's ``diagnostics["input_index"]``), not by its place in the result, which is always 0
(``per_candidate`` is sorted best first). On the demo flight's first two frames (true tile at
input 0, then at input 2) a matcher that always picks input 2 is right on the second frame only."""

from __future__ import annotations

import uuid
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from c3_matcher import camera as cam
from c3_matcher.dto import CandidateMatchSet, MatcherHealth, MatchResult
from c3_matcher_tools.dataset.format import FlightDataset, FrameRecord, load_dataset
from c3_matcher_tools.run import summarize
from c3_matcher_tools.run.acceptance import Verdict, metrics, verdict
from c3_matcher_tools.run.flight import run_flight
from c3_matcher_tools.run.records import FrameStatus

REPO = Path(__file__).resolve().parents[3]
DEMO = REPO / "data" / "flights" / "naip_demo"
PICK = 2


class _PicksInputTwo:
    """A matcher whose best candidate is always the one at input position ``PICK``, its inliers
    where that candidate's ground truth puts them (a 5 x 5 grid over the tile)."""

    def __init__(self, dataset: FlightDataset) -> None:
        self._dataset = dataset
        self._frames: dict[uuid.UUID, FrameRecord] = {f.frame_id: f for f in dataset.frames}

    def match(self, nav: Any, rerank: Any, calibration: Any) -> MatchResult:
        picked = self._frames[nav.frame_id].candidates[PICK]
        assert picked.h_tile_to_undistorted is not None
        grid = np.linspace(60.0, self._dataset.candidate_size_px - 60.0, 5)
        tile = np.array([[x, y] for x in grid for y in grid])
        und = cam.apply_homography(picked.h_tile_to_undistorted, tile)
        corr = np.hstack([cam.distort_points(und, calibration), tile]).astype(np.float32)
        given = len(rerank.candidates)
        best = CandidateMatchSet(rerank.candidates[PICK].tile_id, len(corr), corr, 0, 0.5)
        diagnostics = {"input_index": [PICK]}
        return MatchResult(nav.frame_id, (best,), 0, 0.5, 1, "pick", given, given - 1, diagnostics)

    def health_snapshot(self) -> MatcherHealth:
        return MatcherHealth(0, 0.0)


def test_the_correct_tile_is_judged_by_the_input_position_picked() -> None:
    dataset = load_dataset(DEMO)
    dataset = replace(dataset, frames=dataset.frames[:2])
    assert [f.true_index for f in dataset.frames] == [0, PICK]
    outcomes = run_flight(_PicksInputTwo(dataset), dataset)
    assert [o.status for o in outcomes] == [FrameStatus.OK, FrameStatus.OK]
    assert [o.best_input_index for o in outcomes] == [PICK, PICK]
    assert [o.correct for o in outcomes] == [False, True]
    assert [verdict(o) for o in outcomes] == [Verdict.OTHER_TILE, Verdict.TRUE_TILE]
    it04 = metrics(outcomes, outcomes).correct_tile
    assert (it04.correct, it04.frames, it04.correct_rate) == (1, 2, 0.5)
    assert summarize(outcomes).correct_candidate == 1
