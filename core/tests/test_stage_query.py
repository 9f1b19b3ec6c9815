"""The query stage: one prepared, extracted query per GSD of the candidates (every quarter
turn under rotation search, only for a frame without attitude) and how the candidates are
grouped by GSD."""

from __future__ import annotations

import uuid

import numpy as np
import pytest

from c3_matcher.dto import Attitude, NavCameraFrame, RerankCandidate, TileId
from c3_matcher.preprocess import FramePreprocessor
from c3_matcher.stages.extract import Extraction
from c3_matcher.stages.query import QUERY_ROTATIONS_DEG, GsdGroup, gsd_groups, prepare_query
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
        Extraction(backend),
        frame,
        calibration,
        gsd_groups(rerank.candidates)[0].gsd_m,
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
    assert gsd_groups(rerank.candidates) == (GsdGroup((0, 1, 2), pytest.approx(0.3)),)
    assert gsd_groups(()) == ()


def _candidate(zoom: int, lat: float, gsd: float | None = None) -> RerankCandidate:
    handle = make_rerank(uuid.UUID(int=3), [ScriptedCandidate()]).candidates[0].tile_pixels_handle
    return RerankCandidate(TileId(zoom, lat, -99.15), 1.0, handle, gsd_m_per_px=gsd)


def test_one_zoom_at_several_latitudes_is_one_group_at_the_median_gsd():
    """Tiles of one zoom km apart differ in GSD by ~1e-4: they share one query, scaled to the
    median of their GSDs (a frame whose candidates share a zoom is prepared as it always was)."""
    candidates = [_candidate(15, lat) for lat in (47.03, 46.90, 47.20, 47.01)]
    gsds = [c.ground_sample_distance_m() for c in candidates]
    assert len(set(gsds)) == 4
    (group,) = gsd_groups(candidates)
    assert group == GsdGroup((0, 1, 2, 3), float(np.median(gsds)))


def test_two_zooms_are_two_groups_in_the_order_of_their_first_candidate():
    candidates = [_candidate(14, 47.01), _candidate(15, 47.03), _candidate(15, 47.02)]
    candidates.append(_candidate(14, 47.00))
    fine, coarse = sorted(gsd_groups(candidates), key=lambda g: g.gsd_m)
    assert gsd_groups(candidates) == (coarse, fine)  # zoom 14 comes first in the input
    assert coarse.members == (0, 3) and fine.members == (1, 2)
    assert coarse.gsd_m == pytest.approx(2 * fine.gsd_m, rel=1e-3)
    assert fine.gsd_m == float(
        np.median([candidates[i].ground_sample_distance_m() for i in (1, 2)])
    )


def test_a_candidates_own_gsd_is_honoured_and_groups_within_two_percent():
    candidates = [
        _candidate(15, 47.0, gsd=0.30),
        _candidate(15, 47.0, gsd=0.305),  # within 1.02 of 0.30: the same group
        _candidate(15, 47.0, gsd=0.31),  # over 1.02 of 0.30: a group of its own
        _candidate(15, 47.0),  # its zoom's, ~3.3 m/px
    ]
    groups = gsd_groups(candidates)
    assert [g.members for g in groups] == [(0, 1), (2,), (3,)]
    assert [g.gsd_m for g in groups[:2]] == [pytest.approx(0.3025), 0.31]
    assert groups[2].gsd_m == candidates[3].tile_id.web_mercator_gsd_m()
