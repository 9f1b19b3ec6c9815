"""A tile handle whose library calls ``sys.exit()`` (outside every signal handler: a plugin's
failure, not a stop) is one tile's failure wherever the candidate-features stage reads it: on
the second read that guards the tile cache, the features already had are kept (only caching
is skipped); reading the store's precomputed features, the tile is extracted instead, as for
any failure there. Neither costs the frame or the candidate."""

from __future__ import annotations

import dataclasses
from typing import Any

from c3_matcher.dto import RerankResult
from c3_matcher.pipeline import PipelineMatcher
from c3_matcher.testing import FakeBackend, InMemoryFdr
from c3_matcher.testing.fakes import ScriptedCandidate, ScriptedRig


class ExitsOnRead:
    """A tile handle that raises ``SystemExit`` on its ``fail_at``-th ``encoded()``."""

    def __init__(self, inner: Any, fail_at: int) -> None:
        self.inner, self.fail_at, self.calls = inner, fail_at, 0

    def encoded(self) -> bytes:
        self.calls += 1
        if self.calls == self.fail_at:
            raise SystemExit("the handle's library quit")
        return bytes(self.inner.encoded())

    def decode(self) -> Any:
        return self.inner.decode()


class ExitsServingStored(ExitsOnRead):
    """A tile handle whose stored features' read raises ``SystemExit``."""

    def stored_features(self, request: object) -> object:
        raise SystemExit("the sidecar's binding quit")


class Stored(FakeBackend):
    """A FakeBackend whose tiles a store's precomputed features could serve."""

    max_keypoints = 2048
    extractor_sha256 = "ab" * 32


def _rig(backend: type[FakeBackend], handle: Any, **settings: Any) -> ScriptedRig:
    fdr = InMemoryFdr()
    rig = ScriptedRig([ScriptedCandidate(120), ScriptedCandidate(100)], fdr)
    rig.pipeline = PipelineMatcher(
        backend(rig.inference, rig.lightglue),
        rig.ransac,
        fdr,
        rig.health,
        rig.clock,
        dataclasses.replace(rig.settings, **settings),
    )
    first, second = rig.rerank.candidates
    second = dataclasses.replace(second, tile_pixels_handle=handle(second.tile_pixels_handle))
    rig.rerank = RerankResult(rig.rerank.frame_id, (first, second))
    return rig


def test_an_exit_reading_the_tile_again_for_the_cache_keeps_its_features_uncached() -> None:
    rig = _rig(FakeBackend, lambda inner: ExitsOnRead(inner, 2), tile_cache_size=4)
    result = rig.match()
    assert (result.candidates_dropped, len(result.per_candidate)) == (0, 2)
    assert len(rig.pipeline._tiles.cache) == 1  # the first tile's; the second's not cached


def test_an_exit_reading_the_stored_features_extracts_the_tile_instead() -> None:
    rig = _rig(Stored, lambda inner: ExitsServingStored(inner, 0), stored_features=True)
    result = rig.match()
    assert (result.candidates_dropped, len(result.per_candidate)) == (0, 2)
    sources = result.diagnostics["candidate_features"]
    assert sorted(sources) == ["extracted", "extracted"], sources
