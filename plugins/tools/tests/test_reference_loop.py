"""bench's PyTorch reference runs in the per-frame loop the engines fly in, with the same
settings: the thresholds and switches of ``[matcher]`` and its tile cache. The reference was
built without the tile cache, so it extracted every tile again on every frame the engine case
served from the cache, and the two latency columns did not time the same work."""

from __future__ import annotations

import contextlib

import pytest

from c3_matcher.compose import build_plugin_host, strategy_settings
from c3_matcher.config import C3Settings
from c3_matcher.errors import C3Error
from c3_matcher.fdr import InMemoryFdr
from c3_matcher.pipeline import PipelineMatcher, PipelineSettings
from c3_matcher.testing import FakeBackend, FakeClock, FakeInferenceRuntime, FakeLightGlueRuntime
from c3_matcher.testing.fakes import ScriptedCandidate, make_frame, make_rerank
from c3_matcher_tools.run.matcher import compose_matcher


@pytest.mark.parametrize("cache", [0, 4])
def test_the_reference_keeps_the_configured_tile_cache_and_thresholds(
    cache: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    script = [ScriptedCandidate(), ScriptedCandidate()]
    inference = FakeInferenceRuntime(script)
    backend = FakeBackend(inference, FakeLightGlueRuntime(script))
    host = build_plugin_host()
    monkeypatch.setattr(host, "reference_backend", lambda strategy, settings: backend)
    settings = C3Settings(
        matcher={"tile_cache_size": cache, "min_inliers_threshold": 70, "refine": True}
    )
    composed = compose_matcher(
        settings, fdr=InMemoryFdr(), clock=FakeClock(), plugin_host=host, reference=True
    )
    matcher = composed.matcher
    assert isinstance(matcher, PipelineMatcher) and matcher.backend is backend
    resolved = strategy_settings(settings, "disk_lightglue", host).matcher
    assert matcher.settings == PipelineSettings.from_settings(resolved)
    frame, calibration = make_frame()
    rerank = make_rerank(frame.frame_id, script)
    tiles_extracted = []
    for _ in range(2):  # the same candidates on two frames
        before = len(inference.calls)
        with contextlib.suppress(C3Error):  # the fakes' few matches: no fix, all the same
            matcher.match(frame, rerank, calibration)
        tiles_extracted.append(len(inference.calls) - before - 1)  # one is the query's
    assert tiles_extracted == [2, 2 if cache == 0 else 0]
