"""Building blocks for strategies, so a plugin adds only its model I/O and config.

``c3_matcher.pipeline.PipelineMatcher`` is the one ``CrossDomainMatcher`` (the per-frame loop);
``ExtractorBackend`` is the ``FeatureBackend`` of every "extractor engine + pair matcher" strategy
(DISK, ALIKED, XFeat): it runs the extractor engine through the ``InferenceRuntime`` and matches
through a ``PairMatcher`` (``LightGluePairMatcher``: the shared ``LightGlueRuntime``).
``ExtractorMatcher`` gives the pipeline the specified constructor and ``strategy_factory`` writes a
strategy's ``create`` from its matcher class and config. ``engine_startup_probe`` is the
engine-output assertion that fires at start-up; ``compose_root`` runs it on
every strategy's backend.

The pieces live in ``config`` (the configs and the thresholds they carry), ``pairs`` (pair
matchers) and ``backend`` (``ExtractorBackend``); import them from here.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from pydantic import BaseModel

from c3_matcher.config import C3Settings
from c3_matcher.health import MonotonicClock, RollingHealthWindow
from c3_matcher.pipeline import FeatureBackend, PipelineMatcher, PipelineSettings
from c3_matcher.plugins.types import StrategyFactory
from c3_matcher.probe import engine_startup_probe, textured_probe
from c3_matcher.protocols import (
    Clock,
    CrossDomainMatcher,
    FdrClient,
    InferenceRuntime,
    LightGlueRuntime,
    RansacFilter,
)
from c3_matcher.strategy.backend import ExtractorBackend
from c3_matcher.strategy.config import (
    DEFAULT_MAX_KEYPOINTS,
    ExtractorLightGlueConfig,
    ExtractorStrategyConfig,
    pipeline_with_thresholds,
)
from c3_matcher.strategy.pairs import LightGluePairMatcher, PairMatcher

__all__ = [
    "DEFAULT_MAX_KEYPOINTS",
    "ExtractorBackend",
    "ExtractorLightGlueConfig",
    "ExtractorMatcher",
    "ExtractorStrategyConfig",
    "LightGluePairMatcher",
    "PairMatcher",
    "backend_strategy_factory",
    "engine_startup_probe",
    "pipeline_with_thresholds",
    "strategy_factory",
    "textured_probe",
]


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
        self._config = config
        pairs = pair_matcher if pair_matcher is not None else config.pair_matcher(lightglue_runtime)
        backend = ExtractorBackend(runtime, pairs, config)
        self._extractor_engine_id = backend.engine_id
        super().__init__(
            backend,
            ransac_filter,
            fdr_client,
            health_window,
            clock or MonotonicClock(),
            config.pipeline_settings,
            tile_cache_size=config.tile_cache_size,
        )

    @property
    def config(self) -> Any:
        return self._config

    @property
    def extractor_engine_id(self) -> str:
        """The engine id ``InferenceRuntime.load_engine`` returned for the extractor."""
        return self._extractor_engine_id


def strategy_factory(
    matcher_class: type[ExtractorMatcher],
    make_config: Callable[[C3Settings, Any], ExtractorStrategyConfig],
    options_model: type[BaseModel] | None = None,
) -> StrategyFactory:
    """A strategy's ``create(config, *, lightglue_runtime, ransac_filter,
    inference_runtime, health_window, fdr_client, clock, options)`` from two facts: its matcher
    class and how its config is made from ``C3Settings`` and its validated options (a mapping is
    validated with ``options_model`` here; None means its defaults)."""

    def create(
        config: C3Settings,
        *,
        lightglue_runtime: LightGlueRuntime,
        ransac_filter: RansacFilter,
        inference_runtime: InferenceRuntime,
        health_window: RollingHealthWindow,
        fdr_client: FdrClient,
        clock: Clock,
        options: Any = None,
    ) -> CrossDomainMatcher:
        """``create``: resolve the strategy's engines, load them now (start-up) and
        return its wired matcher."""
        if options_model is not None and not isinstance(options, options_model):
            options = options_model.model_validate(options or {})
        return matcher_class(
            inference_runtime,
            lightglue_runtime,
            ransac_filter,
            fdr_client,
            health_window,
            make_config(config, options),
            clock,
        )

    return create


def backend_strategy_factory(
    make_backend: Callable[[C3Settings, Any], FeatureBackend],
    options_model: type[BaseModel] | None = None,
) -> StrategyFactory:
    """A strategy's ``create`` for ANY ``FeatureBackend`` (OpenCV ORB/SIFT/AKAZE, a PyTorch or
    hand-written matcher: no ONNX engine, no ``InferenceRuntime`` needed): ``make_backend(config,
    options)`` builds the backend at start-up (``options`` validated with ``options_model``; None
    means its defaults) and the result is the one ``PipelineMatcher`` over it with ``[matcher]``'s
    thresholds, stored-features and tile-cache settings and the shared RANSAC, FDR, health window
    and clock. The runtimes it is handed (``inference_runtime``, ``lightglue_runtime``) are not
    used. Descriptors may be float32 or packed binary uint8 (``c3_matcher.features``)."""

    def create(
        config: C3Settings,
        *,
        ransac_filter: RansacFilter,
        health_window: RollingHealthWindow,
        fdr_client: FdrClient,
        clock: Clock,
        options: Any = None,
        **_runtimes: Any,
    ) -> CrossDomainMatcher:
        if options_model is not None and not isinstance(options, options_model):
            options = options_model.model_validate(options or {})
        return PipelineMatcher(
            make_backend(config, options),
            ransac_filter,
            fdr_client,
            health_window,
            clock,
            PipelineSettings.from_settings(config.matcher),
            tile_cache_size=config.matcher.tile_cache_size,
        )

    return create
