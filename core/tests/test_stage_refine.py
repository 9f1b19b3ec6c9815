"""The refine pass as a stage: kept only when the second pass ranks better; a failure, a
homography with no footprint on the tile, or no homography leave the first pass standing."""

from __future__ import annotations

import uuid
from dataclasses import replace
from typing import Any

import numpy as np
import pytest

from c3_matcher.dto import CandidateMatchSet, TileId
from c3_matcher.preprocess import FramePreprocessor
from c3_matcher.stages.extract import Extraction
from c3_matcher.stages.outcomes import Survivor, TileFeatures
from c3_matcher.stages.query import Query, gsd_groups, prepare_query
from c3_matcher.stages.refine import NO_FOOTPRINT, RefinePass
from c3_matcher.stages.scales import FrameScales, QueryScale
from c3_matcher.stages.verify import Verifier
from c3_matcher.testing import (
    FakeBackend,
    FakeInferenceRuntime,
    FakeLightGlueRuntime,
    ScriptedCandidate,
    SequenceRansacFilter,
    make_frame,
    make_rerank,
)

from .host_exit import ctrl_c, host_exit, host_handler

FRAME, CALIBRATION = make_frame(uuid.UUID(int=5))


class Reports:
    frame_id = FRAME.frame_id

    def __init__(self) -> None:
        self.failed: list[str] = []

    def refine_failed(self, tile_id: Any, exc: BaseException) -> None:
        self.failed.append(str(exc))


def _setup(
    fail_extract: bool = False, raised: BaseException | None = None
) -> tuple[FakeBackend, FramePreprocessor, Query]:
    backend = FakeBackend(FakeInferenceRuntime(), FakeLightGlueRuntime())
    pre = FramePreprocessor(backend.input_rule)
    rerank = make_rerank(FRAME.frame_id, [ScriptedCandidate()])
    gsd = gsd_groups(rerank.candidates)[0].gsd_m
    query = prepare_query(
        pre, Extraction(backend), FRAME, CALIBRATION, gsd, rotation_search=False, timings={}
    )
    if fail_extract:

        def broken(image: Any) -> Any:
            raise raised or RuntimeError("extractor down")

        backend.extract = broken  # type: ignore[method-assign]
    return backend, pre, query


def _first(backend: FakeBackend, pre: FramePreprocessor, homography: Any) -> Survivor:
    tile_image = pre.prepare_tile(np.full((64, 64, 3), 1, np.uint8))
    tile = TileFeatures("extracted", tile_image, backend.extract(tile_image))
    rows = np.zeros((80, 4), np.float32)
    match_set = CandidateMatchSet(TileId(18, 47.0, 8.5), 80, rows, 5, 1.0)
    return Survivor(match_set, 0, homography, 0, tile, timings={"match": 1.0})


def _run(
    backend, pre, query, first, ransac=((90, 0.5),), reports=None
) -> tuple[list[Survivor], Any, Reports]:
    reports = reports or Reports()
    verifier = Verifier(SequenceRansacFilter(list(ransac)), 3.0, None)
    survivors, record = RefinePass(pre, Extraction(backend)).run(
        FRAME,
        CALIBRATION,
        FrameScales((QueryScale(query, verifier, (0,)),)),
        [first],
        reports,  # type: ignore[arg-type]
    )
    return survivors, record, reports


def test_a_second_pass_that_ranks_better_replaces_the_first():
    backend, pre, query = _setup()
    first = _first(backend, pre, np.eye(3))
    survivors, record, _ = _run(backend, pre, query, first)
    assert record.as_record() == {
        "candidate_index": 0,
        "inliers_before": 80,
        "inliers_after": 90,
        "kept": True,
    }
    assert survivors[0].match_set.inlier_count == 90 and survivors[0].tile is first.tile
    assert "refine" in first.timings


def test_a_second_pass_that_ranks_no_better_is_dropped():
    backend, pre, query = _setup()
    first = _first(backend, pre, np.eye(3))
    survivors, record, _ = _run(backend, pre, query, first, ransac=((80, 1.0),))
    assert survivors == [first] and not record.kept
    assert record.reason == "ranks no better than the first pass" and record.inliers_after == 80


def test_a_failure_or_no_footprint_leaves_the_first_pass():
    backend, pre, query = _setup(fail_extract=True)
    working = FakeBackend(FakeInferenceRuntime(), FakeLightGlueRuntime())
    first = _first(working, pre, np.eye(3))
    survivors, record, reports = _run(backend, pre, query, first)
    assert survivors == [first] and record.reason == "RuntimeError: extractor down"
    assert reports.failed == ["extractor down"] and "refine" in first.timings
    away = np.array([[1.0, 0.0, 1e6], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    _, record, _ = _run(*_setup(), _first(working, pre, away))
    assert record.reason == NO_FOOTPRINT and record.inliers_after == 0


class Abort(BaseException):
    """A plugin's own ``BaseException``."""


@pytest.mark.parametrize(
    "raised", [Abort("backend gave up"), SystemExit("plugin quit")], ids=["own", "sys.exit"]
)
def test_a_plugins_own_base_exception_or_exit_leaves_the_first_pass(raised):
    """The pass is a plugin's step like any other: its own ``BaseException`` fails the pass,
    not the frame, and so does its own ``sys.exit()`` (no signal handler's)."""
    working = FakeBackend(FakeInferenceRuntime(), FakeLightGlueRuntime())
    backend, pre, query = _setup(fail_extract=True, raised=raised)
    first = _first(working, pre, np.eye(3))
    survivors, record, reports = _run(backend, pre, query, first)
    assert survivors == [first] and record.reason == f"{type(raised).__name__}: {raised}"
    assert reports.failed == [str(raised)]


@pytest.mark.parametrize(
    ("stop", "stopped"),
    [(ctrl_c, KeyboardInterrupt), (host_exit, SystemExit)],
    ids=["Ctrl-C", "the host's handler's sys.exit"],
)
def test_a_stop_in_the_pass_goes_on(stop, stopped):
    """A stop (Ctrl-C, the host's ``sys.exit`` from its signal handler) reaches the caller, no
    failure of the pass said."""
    working = FakeBackend(FakeInferenceRuntime(), FakeLightGlueRuntime())
    backend, pre, query = _setup()
    first = _first(working, pre, np.eye(3))
    backend.extract = lambda image: stop()  # type: ignore[method-assign]
    reports = Reports()
    with host_handler(), pytest.raises(stopped):
        _run(backend, pre, query, first, reports=reports)
    assert reports.failed == []


def test_without_a_homography_there_is_no_pass():
    backend, pre, query = _setup()
    first = _first(backend, pre, None)
    survivors, record, _ = _run(backend, pre, query, first)
    assert survivors == [first] and record is None


def test_the_pass_uses_the_query_and_verifier_the_best_was_matched_against():
    """Candidates of two GSDs are matched against two queries: the best one's second pass
    goes through its own query and is verified by its own verifier."""
    backend, pre, query = _setup()
    first = replace(_first(backend, pre, np.eye(3)), input_index=1)
    other = Verifier(SequenceRansacFilter([(80, 1.0)]), 3.0, None)  # would rank no better
    own = Verifier(SequenceRansacFilter([(90, 0.5)]), 3.0, None)
    scales = FrameScales((QueryScale(query, other, (0,)), QueryScale(query, own, (1,))))
    survivors, record = RefinePass(pre, Extraction(backend)).run(
        FRAME,
        CALIBRATION,
        scales,
        [first],
        Reports(),  # type: ignore[arg-type]
    )
    assert record is not None and record.kept and survivors[0].match_set.inlier_count == 90
    assert survivors[0].input_index == 1
