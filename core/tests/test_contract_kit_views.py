"""The contract kit gives a backend images its input rule allows and checks its matches against a
known offset: a correct backend whose network takes multiples of 14 passes every backend check;
a backend whose pairs are (tile, query), that ignores the tile, or pairs one query keypoint twice
fails them, in the backend checks and in every scripted pipeline run; ``ExtractorMatcherContract``
passes a strategy whose pair matcher is not LightGlue, set up as its docstring says."""

from __future__ import annotations

import contextlib
import dataclasses
import uuid
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from c3_matcher.errors import InsufficientInliersError
from c3_matcher.fdr import InMemoryFdr
from c3_matcher.features import Features, RawMatches
from c3_matcher.pipeline import FeatureBackend, PipelineSettings
from c3_matcher.prepared import PreparedImage
from c3_matcher.strategy import ExtractorLightGlueConfig, ExtractorMatcher, PairMatcher
from c3_matcher.testing.contract import BackendContract
from c3_matcher.testing.fakes import (
    FakeInferenceRuntime,
    ScriptedCandidate,
    make_frame,
    make_rerank,
    scripted_pipeline,
)
from c3_matcher.testing.scripted import MarkedRansac, ScriptedBackend
from c3_matcher.testing.strategy_kit import ExtractorMatcherContract

from .test_probe_moved_copy import IgnoresTile, Orb, SwappedOrb, TileSideNearest

BACKEND_CHECKS = sorted(name for name in dir(BackendContract) if name.startswith("test_backend_"))


def _kit(make: Any) -> BackendContract:
    class Kit(BackendContract):
        def make_backend(self) -> FeatureBackend:
            backend: FeatureBackend = make()
            return backend

    return Kit()


@pytest.mark.parametrize("check", BACKEND_CHECKS)
def test_a_backend_whose_network_takes_multiples_of_14_passes_every_backend_check(check):
    """6 of them failed: their 256 px images broke its input rule."""
    seen: list[tuple[int, int]] = []

    class Patch14(Orb):
        def extract(self, image: PreparedImage) -> Features:
            seen.append(image.engine_size)
            return super().extract(image)

    getattr(_kit(lambda: Patch14(multiple=14, max_long_side=1022)), check)()
    assert all(w % 14 == 0 and h % 14 == 0 for w, h in seen)


BROKEN = [SwappedOrb, IgnoresTile, TileSideNearest]


@pytest.mark.parametrize("broken", BROKEN)
def test_a_match_that_breaks_the_query_tile_contract_fails_the_backend_check(broken):
    """Each passed the kit, which matched an image only with itself."""
    with pytest.raises(AssertionError):
        _kit(broken).test_backend_matches_a_view_that_holds_the_image_in_query_tile_order()
    _kit(Orb).test_backend_matches_a_view_that_holds_the_image_in_query_tile_order()


def _scripted_run(backend: FeatureBackend) -> ScriptedBackend:
    script = [ScriptedCandidate(120), ScriptedCandidate(80)]
    scripted = ScriptedBackend(backend, script)
    matcher = scripted_pipeline(
        scripted, MarkedRansac(script, scripted), InMemoryFdr(), PipelineSettings()
    )
    frame, calibration = make_frame(uuid.UUID(int=3), 256)
    with contextlib.suppress(InsufficientInliersError):  # dropped: the breach is what counts
        matcher.match(frame, make_rerank(frame.frame_id, script, 256), calibration)
    return scripted


@pytest.mark.parametrize("broken", BROKEN)
def test_every_scripted_run_checks_the_query_tile_contract(broken):
    """The query and every tile were the same stand-in: any pairing looked right."""
    with pytest.raises(AssertionError, match=r"match\(query, tile 0\)"):
        _scripted_run(broken()).assert_no_breach()
    correct = _scripted_run(Orb())
    assert correct.breaches == [] and correct.shift == 16


class CosineMutualNearest:
    """A pair matcher that is not LightGlue: mutual nearest neighbours of unit descriptors
    whose cosine similarity is above 0.8 (zero descriptors match nothing)."""

    def match(self, query: Features, tile: Features) -> RawMatches:
        sim = query.descriptors @ tile.descriptors.T
        if sim.size == 0:
            return RawMatches(np.zeros((0, 2), np.int64), np.zeros(0, np.float32))
        best = sim.argmax(axis=1)
        index = np.arange(len(best))
        keep = (sim.argmax(axis=0)[best] == index) & (sim[index, best] > 0.8)
        pairs = np.stack([index[keep], best[keep]], axis=1).astype(np.int64)
        return RawMatches(pairs, sim[index, best][keep].astype(np.float32))


@dataclasses.dataclass(frozen=True)
class MutualNearestConfig(ExtractorLightGlueConfig):
    """A config whose pair matcher is ``CosineMutualNearest`` and runs no matcher engine."""

    def matcher_engines(self) -> Mapping[str, Path]:
        return {}

    def pair_matcher(self, lightglue_runtime: Any) -> PairMatcher:
        return CosineMutualNearest()


class TestMutualNearestStrategyAsDocumented(ExtractorMatcherContract):
    """The kit's docstring: the matcher class and the config, nothing else. 8 of its tests
    failed: the fake extractor's descriptors were zeros and only LightGlue honoured
    ``fail_match``."""

    matcher_class = ExtractorMatcher
    config = MutualNearestConfig(
        label="mnn",
        feature_type="none",
        extract_phase="mine_forward",
        extractor_engine_path=Path("mine.onnx"),
        lightglue_engine_path=Path("unused.onnx"),
        size_multiple=16,
        max_long_side=64,
    )


def test_the_fake_extractor_gives_distinct_unit_descriptors():
    out = FakeInferenceRuntime().run("e", {"image": np.full((64, 64, 3), 3, np.uint8)})
    desc = out["descriptors"]
    assert np.allclose(np.linalg.norm(desc, axis=1), 1.0)
    assert len(np.unique(desc, axis=0)) == len(desc) == len(out["keypoints"])
