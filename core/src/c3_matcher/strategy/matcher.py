"""The one way the core builds the per-frame loop (``pipeline_matcher``, from a backend, the
loop's settings and the shared helpers) and ``ExtractorMatcher``: that loop with the constructor
every "extractor engine + pair matcher" strategy is built with."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Final

from c3_matcher.health import MonotonicClock, RollingHealthWindow
from c3_matcher.pipeline import FeatureBackend, PipelineMatcher, PipelineSettings
from c3_matcher.protocols import Clock, FdrClient, InferenceRuntime, LightGlueRuntime, RansacFilter
from c3_matcher.strategy.backend import ExtractorBackend
from c3_matcher.strategy.config import ExtractorStrategyConfig
from c3_matcher.strategy.pairs import PairMatcher


@dataclass(frozen=True, slots=True)
class PipelineHelpers:
    """The shared helpers the per-frame loop verifies, records and times with."""

    ransac_filter: RansacFilter
    fdr_client: FdrClient
    health_window: RollingHealthWindow
    clock: Clock

    @classmethod
    def from_named(cls, named: Mapping[str, Any]) -> PipelineHelpers:
        """From helpers by name, as a strategy's ``create`` takes them (others are ignored)."""
        return cls(
            named["ransac_filter"], named["fdr_client"], named["health_window"], named["clock"]
        )


def pipeline_matcher(
    backend: FeatureBackend, settings: PipelineSettings, helpers: PipelineHelpers
) -> PipelineMatcher:
    """The per-frame loop over ``backend`` with ``settings`` (``PipelineSettings.from_settings``
    of the strategy's ``[matcher]``: its thresholds and its tile cache alike) and ``helpers``."""
    h = helpers
    return PipelineMatcher(
        backend, h.ransac_filter, h.fdr_client, h.health_window, h.clock, settings
    )


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
        self._lightglue_runtime = lightglue_runtime
        self.config: Final = config
        pairs = pair_matcher if pair_matcher is not None else config.pair_matcher(lightglue_runtime)
        backend = ExtractorBackend(runtime, pairs, config)
        self.extractor_engine_id: Final = backend.engine_id
        """The engine id ``InferenceRuntime.load_engine`` returned for the extractor."""
        clock = clock or MonotonicClock()
        super().__init__(backend, ransac_filter, fdr_client, health_window, clock, config.pipeline)
