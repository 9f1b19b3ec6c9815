"""Building blocks for strategies, so a plugin adds only its model I/O and config.

``c3_matcher.pipeline.PipelineMatcher`` is the one ``CrossDomainMatcher`` (the per-frame loop);
``ExtractorLightGlueBackend`` is the ``FeatureBackend`` of every "extractor engine + shared
LightGlue" strategy (DISK, ALIKED): it runs the extractor engine through the ``InferenceRuntime``
and matches through the shared ``LightGlueRuntime``. ``engine_startup_probe`` is the
engine-output assertion that fires at start-up (AZ-345 Constraints).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Self

import numpy as np

from c3_matcher.config import C3Settings
from c3_matcher.engines.extract import run_extractor
from c3_matcher.engines.manifest import read_manifest
from c3_matcher.errors import EngineError
from c3_matcher.features import Features, RawMatches
from c3_matcher.health import MonotonicClock, RollingHealthWindow
from c3_matcher.pipeline import FeatureBackend, PipelineMatcher, PipelineSettings
from c3_matcher.preprocess import InputRule, PreparedImage
from c3_matcher.protocols import Clock, FdrClient, InferenceRuntime, LightGlueRuntime, RansacFilter

__all__ = [
    "ExtractorLightGlueBackend",
    "ExtractorLightGlueConfig",
    "ExtractorLightGlueMatcher",
    "engine_startup_probe",
]


DEFAULT_MAX_KEYPOINTS = 2048  # upstream LightGlue convention (DECISIONS 14)


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

    @property
    def pipeline_settings(self) -> PipelineSettings:
        return PipelineSettings(
            self.min_inliers_threshold, self.residual_warn_threshold_px, self.ransac_threshold_px
        )

    @property
    def input_rule(self) -> InputRule:
        return InputRule(max_long_side=self.max_long_side, multiple=self.size_multiple)

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
    ) -> Self:
        m = settings.matcher
        return cls(
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
        )


class ExtractorLightGlueBackend:
    """FeatureBackend: an extractor engine plus the shared LightGlue for its feature type."""

    match_phase = "lightglue_match"

    def __init__(
        self,
        runtime: InferenceRuntime,
        lightglue_runtime: LightGlueRuntime,
        config: ExtractorLightGlueConfig,
    ) -> None:
        self._runtime = runtime
        self._lightglue = lightglue_runtime
        self._config = config
        self.engine_id = runtime.load_engine(config.extractor_engine_path)
        load = getattr(lightglue_runtime, "load", None)
        if callable(load):
            load(config.feature_type, config.lightglue_engine_path)
        self._provenance = {
            "provider": runtime.provider,
            "engines": {
                "extractor": _engine_facts(runtime, self.engine_id, config.extractor_engine_path),
                "lightglue": _engine_facts(None, None, config.lightglue_engine_path),
            },
        }

    @property
    def label(self) -> str:
        return self._config.label

    @property
    def input_rule(self) -> InputRule:
        return self._config.input_rule

    @property
    def extract_phase(self) -> str:
        return self._config.extract_phase

    def extract(self, image: PreparedImage) -> Features:
        return run_extractor(
            self._runtime, self.engine_id, image.image, image.valid, self._config.max_keypoints
        )

    def match(self, query: Features, tile: Features) -> RawMatches:
        return self._lightglue.match_pair(
            query.keypoints,
            query.descriptors,
            query.image_size,
            tile.keypoints,
            tile.descriptors,
            tile.image_size,
            feature_type=self._config.feature_type,
        )

    def provenance(self) -> Mapping[str, Any]:
        return self._provenance


def _engine_facts(
    runtime: InferenceRuntime | None, engine_id: str | None, path: Path
) -> dict[str, Any]:
    manifest_of = getattr(runtime, "manifest", None)
    try:
        manifest = manifest_of(engine_id) if callable(manifest_of) else read_manifest(Path(path))
    except EngineError:
        return {"file": str(path)}
    return {
        "file": manifest.file,
        "file_sha256": manifest.file_sha256,
        "weights_sha256": manifest.weights_sha256,
    }


def engine_startup_probe(backend: FeatureBackend, size: int = 128, block: int = 6) -> None:
    """Run the backend once on a deterministic textured probe image and assert its outputs
    (the engine-output assertion that fires at start-up, not on the first frame).

    The probe is ``block`` px squares of random colour (seed 0); 6 px blocks do not line up with
    the 8x8 cells some detectors (XFeat) score, so every cell sees texture."""
    rng = np.random.default_rng(0)
    cells = -(-size // block)
    noise = rng.integers(0, 256, (cells, cells, 3), dtype=np.uint8)
    blocks = np.kron(noise, np.ones((block, block, 1), np.uint8))[:size, :size]
    image = np.ascontiguousarray(blocks)
    probe = PreparedImage(
        image=image,
        valid=np.ones((size, size), bool),
        working_from_engine=np.eye(3),
        working_size=(size, size),
    )
    try:
        features = backend.extract(probe)
        if len(features) == 0:
            raise ValueError("the extractor found no keypoint on the textured probe image")
        matches = backend.match(features, features)
        if len(matches) == 0:
            raise ValueError("matching the probe image with itself gave no match")
    except Exception as exc:
        raise EngineError(
            getattr(backend, "label", "engine"),
            f"start-up probe failed: {type(exc).__name__}: {exc}",
        ) from exc


class ExtractorLightGlueMatcher(PipelineMatcher):
    """The ``CrossDomainMatcher`` of every "extractor engine + shared LightGlue" strategy, with
    AZ-345's constructor. The engines load here (start-up), then the probe asserts their
    outputs. ``_lightglue_runtime`` is the shared helper itself (AC-11 identity)."""

    def __init__(
        self,
        runtime: InferenceRuntime,
        lightglue_runtime: LightGlueRuntime,
        ransac_filter: RansacFilter,
        fdr_client: FdrClient,
        health_window: RollingHealthWindow,
        config: ExtractorLightGlueConfig,
        clock: Clock | None = None,
    ) -> None:
        self._runtime = runtime
        self._lightglue_runtime = lightglue_runtime
        self._config = config
        backend = ExtractorLightGlueBackend(runtime, lightglue_runtime, config)
        self._extractor_engine_id = backend.engine_id
        engine_startup_probe(backend)
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
    def config(self) -> ExtractorLightGlueConfig:
        return self._config

    @property
    def extractor_engine_id(self) -> str:
        """The engine id ``InferenceRuntime.load_engine`` returned for the extractor."""
        return self._extractor_engine_id
