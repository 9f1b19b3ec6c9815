"""Building blocks for strategies, so a plugin adds only its model I/O and config.

``c3_matcher.pipeline.PipelineMatcher`` is the one ``CrossDomainMatcher`` (the per-frame loop);
``ExtractorBackend`` is the ``FeatureBackend`` of every "extractor engine + pair matcher" strategy
(DISK, ALIKED, XFeat): it runs the extractor engine through the ``InferenceRuntime`` and matches
through a ``PairMatcher`` (``LightGluePairMatcher``: the shared ``LightGlueRuntime``).
``ExtractorMatcher`` gives the pipeline the specified constructor and ``strategy_factory`` writes a
strategy's ``create`` from its matcher class and config. ``engine_startup_probe`` is the
engine-output assertion that fires at start-up; ``compose_root`` runs it on
every strategy's backend.

``pipeline_matcher`` is the one way a builder makes the per-frame loop, from a backend, what the
loop takes from ``[matcher]`` (``PipelineSettings``) and the shared helpers (``PipelineHelpers``).

The pieces live in ``config`` (the configs and the thresholds they carry), ``pairs`` (pair
matchers), ``backend`` (``ExtractorBackend``), ``matcher`` (``pipeline_matcher``,
``ExtractorMatcher``) and ``factories`` (the strategies' ``create``); import them from here.
"""

from __future__ import annotations

from c3_matcher.probe import engine_startup_probe, textured_probe
from c3_matcher.strategy.backend import ExtractorBackend
from c3_matcher.strategy.config import (
    DEFAULT_MAX_KEYPOINTS,
    ExtractorLightGlueConfig,
    ExtractorStrategyConfig,
)
from c3_matcher.strategy.factories import backend_strategy_factory, strategy_factory
from c3_matcher.strategy.matcher import ExtractorMatcher, PipelineHelpers, pipeline_matcher
from c3_matcher.strategy.pairs import LightGluePairMatcher, PairMatcher, match_features

__all__ = [
    "DEFAULT_MAX_KEYPOINTS",
    "ExtractorBackend",
    "ExtractorLightGlueConfig",
    "ExtractorMatcher",
    "ExtractorStrategyConfig",
    "LightGluePairMatcher",
    "PairMatcher",
    "PipelineHelpers",
    "backend_strategy_factory",
    "engine_startup_probe",
    "match_features",
    "pipeline_matcher",
    "strategy_factory",
    "textured_probe",
]
