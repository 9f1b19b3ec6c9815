"""A strategy's ``create`` written from a few facts: ``strategy_factory`` for an
``ExtractorMatcher`` subclass and its config, ``backend_strategy_factory`` for any
``FeatureBackend``."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from pydantic import BaseModel

from c3_matcher.config import C3Settings
from c3_matcher.health import RollingHealthWindow
from c3_matcher.pipeline import FeatureBackend, PipelineMatcher, PipelineSettings
from c3_matcher.plugins.types import StrategyFactory
from c3_matcher.protocols import (
    Clock,
    CrossDomainMatcher,
    FdrClient,
    InferenceRuntime,
    LightGlueRuntime,
    RansacFilter,
)
from c3_matcher.strategy.config import ExtractorStrategyConfig
from c3_matcher.strategy.matcher import ExtractorMatcher


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
