"""The whole plugin: an options model, a factory and one hook implementation.

It reuses the engines the DISK plugin declares (``disk/depth`` and ``lightglue/disk``), so it
declares none of its own; a plugin with its own networks would add ``c3_matcher_engine_specs``.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from c3_matcher.config import C3Settings
from c3_matcher.engines.store import EngineStore
from c3_matcher.health import RollingHealthWindow
from c3_matcher.pipeline import PipelineMatcher
from c3_matcher.plugins import StrategySpec, hookimpl
from c3_matcher.protocols import (
    Clock,
    CrossDomainMatcher,
    FdrClient,
    InferenceRuntime,
    LightGlueRuntime,
    RansacFilter,
)
from c3_matcher.strategy import ExtractorLightGlueBackend, ExtractorLightGlueConfig

NAME = "example_fast_disk"


class Options(BaseModel):
    """``[matcher.options.example_fast_disk]``."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    max_keypoints: int = Field(512, ge=64, le=4096)
    max_long_side: int = Field(640, ge=128, le=2048)


def create(
    config: C3Settings,
    *,
    options: Options | None,
    inference_runtime: InferenceRuntime,
    lightglue_runtime: LightGlueRuntime,
    ransac_filter: RansacFilter,
    health_window: RollingHealthWindow,
    fdr_client: FdrClient,
    clock: Clock,
    **_: Any,
) -> CrossDomainMatcher:
    opts = options or Options()
    store = EngineStore(config.engines.directory)
    base = ExtractorLightGlueConfig.from_settings(
        config,
        label=NAME,
        feature_type="disk",
        extract_phase="disk_forward",
        extractor_engine_path=store.require("disk", "depth"),
        lightglue_engine_path=store.require("lightglue", "disk"),
        size_multiple=16,
    )
    cfg = dataclasses.replace(
        base, max_keypoints=opts.max_keypoints, max_long_side=opts.max_long_side
    )
    backend = ExtractorLightGlueBackend(inference_runtime, lightglue_runtime, cfg)
    return PipelineMatcher(
        backend,
        ransac_filter,
        fdr_client,
        health_window,
        clock,
        cfg.pipeline_settings,
        tile_cache_size=cfg.tile_cache_size,
    )


@hookimpl
def c3_matcher_strategies() -> list[StrategySpec]:
    return [
        StrategySpec(
            name=NAME,
            factory=create,
            options_model=Options,
            description="example third-party plugin: fast DISK + LightGlue",
        )
    ]
