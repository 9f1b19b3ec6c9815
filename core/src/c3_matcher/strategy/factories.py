"""A strategy's ``create`` written from a few facts: ``strategy_factory`` for an
``ExtractorMatcher`` subclass and its config, ``backend_strategy_factory`` for any
``FeatureBackend``."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Unpack

from pydantic import BaseModel

from c3_matcher.config import C3Settings
from c3_matcher.pipeline import FeatureBackend, PipelineMatcher, PipelineSettings
from c3_matcher.plugins.types import StrategyFactory, StrategyHelpers
from c3_matcher.probe import check_members
from c3_matcher.protocols import CrossDomainMatcher
from c3_matcher.strategy.config import ExtractorStrategyConfig
from c3_matcher.strategy.matcher import ExtractorMatcher


def _validated(options_model: type[BaseModel] | None, options: Any) -> Any:
    """``options`` validated with ``options_model`` (a mapping, or None for its defaults);
    options already of that model, or of a strategy without one, as they are."""
    if options_model is not None and not isinstance(options, options_model):
        return options_model.model_validate(options or {})
    return options


def strategy_factory(
    matcher_class: type[ExtractorMatcher],
    make_config: Callable[[C3Settings, Any], ExtractorStrategyConfig],
    options_model: type[BaseModel] | None = None,
) -> StrategyFactory:
    """A strategy's ``create(config, *, options, **helpers)`` (``StrategyHelpers``) from two
    facts: its matcher class and how its config is made from ``C3Settings`` and its validated
    options (a mapping is validated with ``options_model`` here; None means its defaults)."""

    def create(
        config: C3Settings, *, options: Any = None, **helpers: Unpack[StrategyHelpers]
    ) -> CrossDomainMatcher:
        """``create``: resolve the strategy's engines, load them now (start-up) and
        return its wired matcher."""
        return matcher_class(
            helpers["inference_runtime"],
            helpers["lightglue_runtime"],
            helpers["ransac_filter"],
            helpers["fdr_client"],
            helpers["health_window"],
            make_config(config, _validated(options_model, options)),
            helpers["clock"],
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
        config: C3Settings, *, options: Any = None, **helpers: Unpack[StrategyHelpers]
    ) -> CrossDomainMatcher:
        backend = make_backend(config, _validated(options_model, options))
        check_members(backend)  # None or another object: said as such, before it is used
        return PipelineMatcher(
            backend,
            helpers["ransac_filter"],
            helpers["fdr_client"],
            helpers["health_window"],
            helpers["clock"],
            PipelineSettings.from_settings(config.matcher),
            tile_cache_size=config.matcher.tile_cache_size,
        )

    return create
