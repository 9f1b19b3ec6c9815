"""Building blocks for strategies, so a plugin adds only its model I/O and config.

``c3_matcher.pipeline.PipelineMatcher`` is the one ``CrossDomainMatcher`` (the per-frame loop);
``ExtractorBackend`` is the ``FeatureBackend`` of every "extractor engine + pair matcher" strategy
(DISK, ALIKED, XFeat): it runs the extractor engine through the ``InferenceRuntime`` and matches
through a ``PairMatcher`` (``LightGluePairMatcher``: the shared ``LightGlueRuntime``).
``ExtractorMatcher`` gives the pipeline the specified constructor and ``strategy_factory`` writes a
strategy's ``create`` from its matcher class and config. ``engine_startup_probe`` is the
engine-output assertion that fires at start-up; ``compose_root`` runs it on
every strategy's backend.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, Self

from pydantic import BaseModel

from c3_matcher.config import C3Settings
from c3_matcher.engines.extract import run_extractor
from c3_matcher.engines.manifest import read_manifest
from c3_matcher.errors import EngineError
from c3_matcher.features import Features, RawMatches
from c3_matcher.health import MonotonicClock, RollingHealthWindow
from c3_matcher.pipeline import FeatureBackend, PipelineMatcher, PipelineSettings
from c3_matcher.plugins.types import StrategyFactory
from c3_matcher.preprocess import InputRule, PreparedImage
from c3_matcher.probe import engine_startup_probe, textured_probe
from c3_matcher.protocols import (
    Clock,
    CrossDomainMatcher,
    FdrClient,
    InferenceRuntime,
    LightGlueRuntime,
    LoadableLightGlueRuntime,
    ManifestRuntime,
    RansacFilter,
)

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
    "strategy_factory",
    "textured_probe",
]


DEFAULT_MAX_KEYPOINTS = 2048  # upstream LightGlue convention


@dataclass(frozen=True, slots=True)
class ExtractorLightGlueConfig:
    """What an extractor + LightGlue strategy needs (built from ``C3Settings`` by ``create``).

    Engine paths are files in the engine directory; image and keypoint rules are in px.
    """

    label: str
    feature_type: str
    extract_phase: str
    extractor_engine_path: Path
    lightglue_engine_path: Path
    size_multiple: int
    max_long_side: int = 1024
    max_keypoints: int = DEFAULT_MAX_KEYPOINTS
    min_inliers_threshold: int = 60
    residual_warn_threshold_px: float = 2.5
    ransac_threshold_px: float = 3.0
    tile_cache_size: int = 16
    pipeline: PipelineSettings | None = None  # [matcher]'s stored features and prior

    match_phase = "lightglue_match"

    @property
    def pipeline_settings(self) -> PipelineSettings:
        """``[matcher]``'s pipeline settings (``pipeline``) with this config's thresholds."""
        return (self.pipeline or PipelineSettings()).with_thresholds(
            self.min_inliers_threshold, self.residual_warn_threshold_px, self.ransac_threshold_px
        )

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
        """From ``[matcher]``; ``overrides`` (e.g. a plugin's ``max_keypoints``) replace fields."""
        m = settings.matcher
        config = cls(
            label,
            feature_type,
            extract_phase,
            extractor_engine_path,
            lightglue_engine_path,
            size_multiple,
            m.max_long_side,
            m.max_keypoints or DEFAULT_MAX_KEYPOINTS,
            m.min_inliers_threshold,
            m.residual_warn_threshold_px,
            m.ransac_threshold_px,
            m.tile_cache_size,
            PipelineSettings.from_settings(m),
        )
        return dataclasses.replace(config, **overrides) if overrides else config


class PairMatcher(Protocol):
    """Matches the features of two images; an exception becomes a per-candidate drop."""

    def match(self, query: Features, tile: Features) -> RawMatches: ...


class LightGluePairMatcher:
    """A ``PairMatcher`` over the shared ``LightGlueRuntime`` for one feature type; loads the
    engine into it now (start-up) when the runtime has ``load``."""

    def __init__(self, runtime: LightGlueRuntime, engine_path: Path, feature_type: str) -> None:
        self._runtime = runtime
        self._feature_type = feature_type
        if isinstance(runtime, LoadableLightGlueRuntime):
            runtime.load(feature_type, engine_path)

    def match(self, query: Features, tile: Features) -> RawMatches:
        return self._runtime.match_pair(
            query.keypoints,
            query.descriptors,
            query.image_size,
            tile.keypoints,
            tile.descriptors,
            tile.image_size,
            feature_type=self._feature_type,
        )


class ExtractorStrategyConfig(Protocol):
    """What ``ExtractorMatcher`` needs from a strategy's config (``ExtractorLightGlueConfig``,
    XFeat's config): labels, image rule, keypoint budget, engine files and thresholds."""

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
    def pipeline_settings(self) -> PipelineSettings: ...
    @property
    def tile_cache_size(self) -> int: ...
    def matcher_engines(self) -> Mapping[str, Path]:
        """Role -> file of the engines besides the extractor (provenance)."""
        ...

    def pair_matcher(self, lightglue_runtime: LightGlueRuntime) -> PairMatcher: ...


class ExtractorBackend:
    """FeatureBackend of every "extractor engine + pair matcher" strategy: the extractor engine
    through the ``InferenceRuntime`` (``run_extractor``: fixed top-K, padding dropped, the
    ``max_keypoints`` best kept), matching through a ``PairMatcher``."""

    def __init__(
        self,
        runtime: InferenceRuntime,
        pair_matcher: PairMatcher,
        config: ExtractorStrategyConfig,
    ) -> None:
        self._runtime = runtime
        self._pair_matcher = pair_matcher
        self._config = config
        self.engine_id = runtime.load_engine(config.extractor_engine_path)
        facts = {"extractor": _engine_facts(runtime, self.engine_id, config.extractor_engine_path)}
        for role, path in config.matcher_engines().items():
            facts[role] = _engine_facts(None, None, path)
        self._provenance: dict[str, Any] = {"provider": runtime.provider, "engines": facts}

    @property
    def label(self) -> str:
        return self._config.label

    @property
    def input_rule(self) -> InputRule:
        return self._config.input_rule

    @property
    def extract_phase(self) -> str:
        return self._config.extract_phase

    @property
    def match_phase(self) -> str:
        return self._config.match_phase

    @property
    def pair_matcher(self) -> PairMatcher:
        return self._pair_matcher

    def extract(self, image: PreparedImage) -> Features:
        return run_extractor(
            self._runtime, self.engine_id, image.image, image.valid, self._config.max_keypoints
        )

    def match(self, query: Features, tile: Features) -> RawMatches:
        return self._pair_matcher.match(query, tile)

    @property
    def max_keypoints(self) -> int:
        """The keypoint budget (``StoredFeaturesBackend``): at most this many per image."""
        return self._config.max_keypoints

    def provenance(self) -> Mapping[str, Any]:
        return self._provenance


def _engine_facts(
    runtime: InferenceRuntime | None, engine_id: str | None, path: Path
) -> dict[str, Any]:
    try:
        if isinstance(runtime, ManifestRuntime) and engine_id is not None:
            manifest = runtime.manifest(engine_id)
        else:
            manifest = read_manifest(Path(path))
    except EngineError:
        return {"file": str(path)}
    return {
        "file": manifest.file,
        "file_sha256": manifest.file_sha256,
        "weights_sha256": manifest.weights_sha256,
    }


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
