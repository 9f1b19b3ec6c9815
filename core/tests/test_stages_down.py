"""Following a frame through ``match`` goes down the stages and never back up: no stage calls
into the pipeline (each query's verifier is built by ``stages.scales`` from the frame's
``VerifierSettings``, not asked of the pipeline), and the pipeline does no coordinate work of
its own (a candidate's inliers come back from ``stages.verify`` in ORIGINAL frame px, the
diagnostics' ``query_to_tile`` from ``stages.scales``). The real demo frame, its real tiles,
an ORB backend and real RANSAC, traced call by call."""

from __future__ import annotations

import collections
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from types import FrameType
from typing import Any

import cv2
import numpy as np

from c3_matcher.demo import demo_inputs
from c3_matcher.fdr import InMemoryFdr
from c3_matcher.health import RollingHealthWindow
from c3_matcher.pipeline import PipelineMatcher, PipelineSettings
from c3_matcher.preprocess import FramePreprocessor
from c3_matcher.prior import PriorTolerances
from c3_matcher.ransac import OpenCvRansacFilter
from c3_matcher.stages.extract import Extraction
from c3_matcher.stages.outcomes import TileFeatures
from c3_matcher.stages.scales import prepare_scales
from c3_matcher.stages.verify import VerifierSettings, best_turn, candidate_verdict
from c3_matcher.testing import FakeClock

from .test_contract_kit import OpenCvBackend

DEMO = Path(__file__).resolve().parents[2] / "data" / "demo"
TRUE = 1  # the demo frame's true tile: the second candidate
PIPELINE = "c3_matcher.pipeline"
COORDINATES = ("c3_matcher.prepared", "c3_matcher.camera", "c3_matcher.query_geometry")


def _orb() -> OpenCvBackend:
    return OpenCvBackend(cv2.ORB_create(2000), cv2.NORM_HAMMING, "orb")


def _module(frame: FrameType | None) -> str | None:
    """The ``c3_matcher`` module ``frame`` runs in, else None."""
    name = frame.f_globals.get("__name__", "") if frame is not None else ""
    return name if name.startswith("c3_matcher.") else None


@contextmanager
def _call_edges() -> Iterator[collections.Counter[tuple[str, str]]]:
    """Every call from one ``c3_matcher`` module into another while the block runs (the
    caller: the nearest ``c3_matcher`` frame up the stack), counted."""
    edges: collections.Counter[tuple[str, str]] = collections.Counter()

    def profile(frame: FrameType, event: str, arg: Any) -> None:
        if event != "call" or (callee := _module(frame)) is None:
            return
        caller = frame.f_back
        while caller is not None and _module(caller) is None:
            caller = caller.f_back
        if (name := _module(caller)) is not None and name != callee:
            edges[(name, callee)] += 1

    sys.setprofile(profile)
    try:
        yield edges
    finally:
        sys.setprofile(None)


def test_a_real_frame_goes_down_the_stages_and_never_back_up() -> None:
    frame, rerank, calibration = demo_inputs(DEMO)
    clock = FakeClock()
    settings = PipelineSettings(refine=True, tile_cache_size=3)  # the refine pass verifies too
    health = RollingHealthWindow(clock, settings.min_inliers_threshold)
    matcher = PipelineMatcher(_orb(), OpenCvRansacFilter(), InMemoryFdr(), health, clock, settings)
    with _call_edges() as edges:
        result = matcher.match(frame, rerank, calibration)
    assert result.per_candidate[0].tile_id == rerank.candidates[TRUE].tile_id
    assert result.diagnostics["geometric_prior"] is True
    assert result.diagnostics["refine"] is not None
    assert (PIPELINE, "c3_matcher.stages.scales") in edges  # the trace sees the stages
    assert (PIPELINE, "c3_matcher.stages.verify") in edges
    back_up = {e: n for e, n in edges.items() if e[0].startswith("c3_matcher.stages.")}
    assert {e: n for e, n in back_up.items() if e[1] == PIPELINE} == {}
    coordinate_work = {e: n for e, n in edges.items() if e[0] == PIPELINE}
    assert {e: n for e, n in coordinate_work.items() if e[1] in COORDINATES} == {}


def test_a_candidate_verdict_comes_back_in_original_frame_px() -> None:
    """The stage that verifies a candidate hands its inliers over in ORIGINAL frame px: the
    demo frame is rectified with its attitude, so they differ from the WORKING px RANSAC saw."""
    frame, rerank, calibration = demo_inputs(DEMO)
    backend = _orb()
    pre = FramePreprocessor(backend.input_rule)
    verification = VerifierSettings(OpenCvRansacFilter(), 3.0, True, PriorTolerances())
    scales = prepare_scales(
        pre,
        Extraction(backend),
        frame,
        calibration,
        rerank.candidates,
        rotation_search=False,
        verification=verification,
        timings={},
    )
    assert scales.geometric_prior  # the demo frame has attitude and height
    scale, candidate = scales.of(TRUE), rerank.candidates[TRUE]
    image = pre.prepare_tile(candidate.tile_pixels_handle.decode())
    tile = TileFeatures("extracted", image, backend.extract(image))
    args = (backend, scale.verifier, scale.query, candidate.tile_id, tile, {})
    verdict = candidate_verdict(*args)
    working = best_turn(backend, scale.verifier, scale.query.views, *args[3:]).match_set
    rows = verdict.match_set.inlier_correspondences
    assert verdict.match_set.inlier_count == working.inlier_count >= 60
    assert np.array_equal(rows, scale.query.image.in_original_px(working.inlier_correspondences))
    assert not np.allclose(rows[:, :2], working.inlier_correspondences[:, :2], atol=1.0)
    assert np.array_equal(rows[:, 2:], working.inlier_correspondences[:, 2:])  # tile px as-is


def test_the_scales_build_each_verifier_from_the_settings_alone() -> None:
    """The prior off in the settings: no scale's verifier has one, though the frame could."""
    frame, rerank, calibration = demo_inputs(DEMO)
    backend = _orb()
    off = VerifierSettings(OpenCvRansacFilter(), 2.5, False, PriorTolerances())
    scales = prepare_scales(
        FramePreprocessor(backend.input_rule),
        Extraction(backend),
        frame,
        calibration,
        rerank.candidates,
        rotation_search=False,
        verification=off,
        timings={},
    )
    assert not scales.geometric_prior
    assert all(s.verifier.threshold_px == 2.5 and s.verifier.prior is None for s in scales.scales)
    assert all(s.verifier.ransac is off.ransac for s in scales.scales)
