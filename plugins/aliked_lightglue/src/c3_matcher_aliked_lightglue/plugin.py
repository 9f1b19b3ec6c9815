"""Entry point of the ``aliked_lightglue`` plugin (group ``c3_matcher.plugins``)."""

from __future__ import annotations

from c3_matcher.config import C3Settings
from c3_matcher.engines.spec import EngineSpec
from c3_matcher.pipeline import FeatureBackend
from c3_matcher.plugins import StrategySpec, hookimpl
from c3_matcher_aliked_lightglue.matcher import STRATEGY, AlikedLightGlueOptions, create

__all__ = ["c3_matcher_engine_specs", "c3_matcher_reference_backend", "c3_matcher_strategies"]


@hookimpl
def c3_matcher_strategies() -> list[StrategySpec]:
    return [
        StrategySpec(
            name=STRATEGY,
            factory=create,
            build_flag="BUILD_MATCHER_ALIKED_LIGHTGLUE",
            options_model=AlikedLightGlueOptions,
            description="ALIKED features (n16, or n16rot by option) + LightGlue",
        )
    ]


@hookimpl
def c3_matcher_reference_backend(strategy: str, settings: C3Settings) -> FeatureBackend | None:
    if strategy != STRATEGY:
        return None
    from c3_matcher_aliked_lightglue.reference import AlikedLightGlueReference

    return AlikedLightGlueReference(settings)


@hookimpl
def c3_matcher_engine_specs() -> list[EngineSpec]:
    from c3_matcher_aliked_lightglue.engines import ENGINE_SPECS

    return list(ENGINE_SPECS)
