"""The query stage: one prepared, extracted query (every quarter turn under rotation search,
only for a frame without attitude) and the GSD it is scaled to."""

from __future__ import annotations

import uuid

import pytest

from c3_matcher.dto import Attitude, NavCameraFrame
from c3_matcher.preprocess import FramePreprocessor
from c3_matcher.stages.query import QUERY_ROTATIONS_DEG, prepare_query, tile_gsd
from c3_matcher.testing import (
    FakeBackend,
    FakeInferenceRuntime,
    FakeLightGlueRuntime,
    ScriptedCandidate,
    make_frame,
    make_rerank,
)


def _run(frame: NavCameraFrame, search: bool) -> tuple[object, dict[str, float], int]:
    _, calibration = make_frame(frame.frame_id)
    inference = FakeInferenceRuntime()
    backend = FakeBackend(inference, FakeLightGlueRuntime())
    rerank = make_rerank(frame.frame_id, [ScriptedCandidate()] * 3)
    timings: dict[str, float] = {}
    query = prepare_query(
        FramePreprocessor(backend.input_rule),
        backend,
        frame,
        calibration,
        rerank.candidates,
        rotation_search=search,
        timings=timings,
    )
    return query, timings, len(inference.calls)


def test_one_view_without_the_search():
    frame, _ = make_frame(uuid.UUID(int=3))
    query, timings, extractions = _run(frame, search=False)
    assert [v.rotation_deg for v in query.views] == [0] and not query.rotation_search
    assert query.views[0].image is query.image
    assert list(timings) == ["query_preprocess", "query_extract"] and extractions == 1


def test_every_turn_for_a_frame_without_attitude_under_the_search():
    frame, _ = make_frame(uuid.UUID(int=3))
    query, _, extractions = _run(frame, search=True)
    assert [v.rotation_deg for v in query.views] == list(QUERY_ROTATIONS_DEG)
    assert query.rotation_search and extractions == 4
    assert all(v.image.working_size == query.image.working_size for v in query.views)


def test_a_frame_with_attitude_is_never_searched():
    frame, _ = make_frame(uuid.UUID(int=3))
    level = NavCameraFrame(frame.frame_id, frame.image, 1, attitude=Attitude(0.0, 0.0, 0.0))
    query, _, extractions = _run(level, search=True)
    assert not query.rotation_search and extractions == 1


def test_the_query_is_scaled_to_the_median_candidate_gsd():
    rerank = make_rerank(uuid.UUID(int=3), [ScriptedCandidate()] * 3)
    assert tile_gsd(rerank.candidates) == pytest.approx(0.3)
    assert tile_gsd(()) is None
