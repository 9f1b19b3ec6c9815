"""What an "extractor engine + pair matcher" strategy is configured with: the config protocol
``ExtractorMatcher`` reads (``ExtractorStrategyConfig``) and the config of every extractor +
LightGlue strategy (``ExtractorLightGlueConfig``). Engine paths are files in the engine
directory; image and keypoint rules are in px."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol, Self

from c3_matcher.config import C3Settings, matcher_default
from c3_matcher.pipeline import PipelineSettings
from c3_matcher.prepared import InputRule
from c3_matcher.protocols import LightGlueRuntime
from c3_matcher.strategy.pairs import LightGluePairMatcher, PairMatcher

DEFAULT_MAX_KEYPOINTS = 2048  # upstream LightGlue convention


@dataclass(frozen=True, slots=True)
class ExtractorLightGlueConfig:
    """What an extractor + LightGlue strategy needs (built from ``C3Settings`` by ``create``).

    Engine paths are files in the engine directory; image and keypoint rules are in px;
    ``pipeline`` is what the per-frame loop takes from ``[matcher]``.
    """

    label: str
    feature_type: str
    extract_phase: str
    extractor_engine_path: Path
    lightglue_engine_path: Path
    size_multiple: int
    max_long_side: int = matcher_default("max_long_side")
    max_keypoints: int = DEFAULT_MAX_KEYPOINTS
    pipeline: PipelineSettings = field(default_factory=PipelineSettings)  # from [matcher]

    match_phase = "lightglue_match"

    @property
    def input_rule(self) -> InputRule:
        return InputRule(max_long_side=self.max_long_side, multiple=self.size_multiple)

    def matcher_engines(self) -> Mapping[str, Path]:
        return {"lightglue": self.lightglue_engine_path}

    def pair_matcher(self, lightglue_runtime: LightGlueRuntime) -> PairMatcher:
        return LightGluePairMatcher(
            lightglue_runtime, self.lightglue_engine_path, self.feature_type
        )

    @classmethod
    def from_settings(
        cls,
        settings: C3Settings,
        *,
        label: str,
        feature_type: str,
        extract_phase: str,
        extractor_engine_path: Path,
        lightglue_engine_path: Path,
        size_multiple: int,
        **overrides: Any,
    ) -> Self:
        """From ``settings`` as composed for the strategy: image rule, keypoint budget and the
        loop's settings from ``[matcher]``; ``overrides`` (e.g. a plugin's ``max_keypoints``)
        replace fields."""
        m = settings.matcher
        config = cls(
            label=label,
            feature_type=feature_type,
            extract_phase=extract_phase,
            extractor_engine_path=extractor_engine_path,
            lightglue_engine_path=lightglue_engine_path,
            size_multiple=size_multiple,
            max_long_side=m.max_long_side,
            max_keypoints=m.max_keypoints or DEFAULT_MAX_KEYPOINTS,
            pipeline=PipelineSettings.from_settings(m),
        )
        return dataclasses.replace(config, **overrides) if overrides else config


class ExtractorStrategyConfig(Protocol):
    """What ``ExtractorMatcher`` needs from a strategy's config (``ExtractorLightGlueConfig``,
    XFeat's config): labels, image rule, keypoint budget, engine files and what the per-frame
    loop takes from ``[matcher]`` (``pipeline``: thresholds, stored features, the prior, the
    tile cache)."""

    @property
    def label(self) -> str: ...
    @property
    def extract_phase(self) -> str: ...
    @property
    def match_phase(self) -> str: ...
    @property
    def input_rule(self) -> InputRule: ...
    @property
    def max_keypoints(self) -> int: ...
    @property
    def extractor_engine_path(self) -> Path: ...
    @property
    def pipeline(self) -> PipelineSettings: ...
    def matcher_engines(self) -> Mapping[str, Path]:
        """Role -> file of the engines besides the extractor (provenance)."""
        ...

    def pair_matcher(self, lightglue_runtime: LightGlueRuntime) -> PairMatcher: ...
