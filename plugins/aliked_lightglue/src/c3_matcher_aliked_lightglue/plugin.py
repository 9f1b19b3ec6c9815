"""Entry point of the ``aliked_lightglue`` plugin (group ``c3_matcher.plugins``)."""

from __future__ import annotations

from c3_matcher.plugins import StrategySpec, strategy_hooks
from c3_matcher_aliked_lightglue.defaults import DEFAULTS
from c3_matcher_aliked_lightglue.matcher import STRATEGY, AlikedLightGlueOptions, create

__all__ = ["c3_matcher_engine_specs", "c3_matcher_reference_backend", "c3_matcher_strategies"]

c3_matcher_strategies, c3_matcher_reference_backend, c3_matcher_engine_specs = strategy_hooks(
    StrategySpec(
        name=STRATEGY,
        factory=create,
        defaults=DEFAULTS,
        build_flag="BUILD_MATCHER_ALIKED_LIGHTGLUE",
        options_model=AlikedLightGlueOptions,
        description="ALIKED features (n16, or n16rot by option) + LightGlue",
    ),
    engine_specs="c3_matcher_aliked_lightglue.engines:ENGINE_SPECS",
    reference_backend="c3_matcher_aliked_lightglue.export:AlikedLightGlueReference",
)
