"""Entry point of the ``disk_lightglue`` plugin (group ``c3_matcher.plugins``)."""

from __future__ import annotations

from c3_matcher.config import C3Settings
from c3_matcher.engines.spec import EngineSpec
from c3_matcher.pipeline import FeatureBackend
from c3_matcher.plugins import StrategySpec, hookimpl
from c3_matcher_disk_lightglue.matcher import STRATEGY, create

__all__ = ["c3_matcher_engine_specs", "c3_matcher_reference_backend", "c3_matcher_strategies"]


@hookimpl
def c3_matcher_strategies() -> list[StrategySpec]:
    return [
        StrategySpec(
            name=STRATEGY,
            factory=create,
            build_flag="BUILD_MATCHER_DISK_LIGHTGLUE",
            description="DISK features + LightGlue (default, D-C3-1 = (a))",
        )
    ]


@hookimpl
def c3_matcher_reference_backend(strategy: str, settings: C3Settings) -> FeatureBackend | None:
    if strategy != STRATEGY:
        return None
    from c3_matcher_disk_lightglue.reference import DiskLightGlueReference

    return DiskLightGlueReference(settings)


@hookimpl
def c3_matcher_engine_specs() -> list[EngineSpec]:
    from c3_matcher_disk_lightglue.engines import ENGINE_SPECS

    return list(ENGINE_SPECS)
