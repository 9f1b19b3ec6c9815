"""``ExtractorMatcher``: the pipeline with the constructor every "extractor engine + pair
matcher" strategy is built with."""

from __future__ import annotations

from typing import Final

from c3_matcher.health import MonotonicClock, RollingHealthWindow
from c3_matcher.pipeline import PipelineMatcher
from c3_matcher.protocols import Clock, FdrClient, InferenceRuntime, LightGlueRuntime, RansacFilter
from c3_matcher.strategy.backend import ExtractorBackend
from c3_matcher.strategy.config import ExtractorStrategyConfig
from c3_matcher.strategy.pairs import PairMatcher


class ExtractorMatcher(PipelineMatcher):
    """``PipelineMatcher`` with the specified constructor, for each "extractor engine + pair
    matcher" strategy (``DiskLightGlueMatcher`` and its siblings subclass it only to keep
    their names). The engines load here (start-up); ``compose_root`` then runs the start-up probe.
    ``_lightglue_runtime`` is the shared helper itself (by identity); ``pair_matcher``
    replaces the configured one (tests)."""

    def __init__(
        self,
        runtime: InferenceRuntime,
        lightglue_runtime: LightGlueRuntime,
        ransac_filter: RansacFilter,
        fdr_client: FdrClient,
        health_window: RollingHealthWindow,
        config: ExtractorStrategyConfig,
        clock: Clock | None = None,
        *,
        pair_matcher: PairMatcher | None = None,
    ) -> None:
        self._runtime = runtime
        self._lightglue_runtime = lightglue_runtime
        self.config: Final = config
        pairs = pair_matcher if pair_matcher is not None else config.pair_matcher(lightglue_runtime)
        backend = ExtractorBackend(runtime, pairs, config)
        self.extractor_engine_id: Final = backend.engine_id
        """The engine id ``InferenceRuntime.load_engine`` returned for the extractor."""
        super().__init__(
            backend,
            ransac_filter,
            fdr_client,
            health_window,
            clock or MonotonicClock(),
            config.pipeline,
            tile_cache_size=config.tile_cache_size,
        )
