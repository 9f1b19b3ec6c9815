"""``DiskLightGlueMatcher`` and ``create`` as the matcher specification defines them.

DISK keypoints and descriptors come from the DISK engine run by the C7 ``InferenceRuntime``;
LightGlue (DISK weights) runs in the shared ``LightGlueRuntime``; RANSAC in the shared
``RansacFilter``. Engines load in the constructor, called by ``create`` at start-up.
"""

from __future__ import annotations

from dataclasses import dataclass

from c3_matcher.config import C3Settings
from c3_matcher.engines.store import EngineStore
from c3_matcher.strategy import ExtractorLightGlueConfig, ExtractorMatcher, strategy_factory
from c3_matcher_disk_lightglue.engines import DISK_SIZE_MULTIPLE, DISK_SPEC, LIGHTGLUE_DISK_SPEC

__all__ = [
    "DISK_SIZE_MULTIPLE",
    "STRATEGY",
    "DiskLightGlueConfig",
    "DiskLightGlueMatcher",
    "create",
]

STRATEGY = "disk_lightglue"


@dataclass(frozen=True, slots=True)
class DiskLightGlueConfig(ExtractorLightGlueConfig):
    """``MatcherConfig`` for DISK + LightGlue."""

    @classmethod
    def from_c3_settings(cls, settings: C3Settings, engines: EngineStore) -> DiskLightGlueConfig:
        """Engine paths from ``engines`` (``EngineError`` naming the build command if one is
        missing), image rules and the loop's settings from ``settings`` as composed for the
        strategy (``ExtractorLightGlueConfig.from_settings``)."""
        return cls.from_settings(
            settings,
            label=STRATEGY,
            feature_type=str(LIGHTGLUE_DISK_SPEC.feature_type),
            extract_phase="disk_forward",
            extractor_engine_path=engines.require_spec(DISK_SPEC),
            lightglue_engine_path=engines.require_spec(LIGHTGLUE_DISK_SPEC),
            size_multiple=DISK_SIZE_MULTIPLE,
        )


class DiskLightGlueMatcher(ExtractorMatcher):
    """The production-default ``CrossDomainMatcher`` (specified constructor, the core's per-frame
    pipeline). Single-threaded."""


create = strategy_factory(
    DiskLightGlueMatcher,
    lambda settings, _options, engines: DiskLightGlueConfig.from_c3_settings(settings, engines),
)
"""``create(config, *, lightglue_runtime, ransac_filter, inference_runtime, health_window,
fdr_client, clock, options)``: resolve the DISK and LightGlue engines, load them now (start-up)
and return the wired ``DiskLightGlueMatcher``."""
