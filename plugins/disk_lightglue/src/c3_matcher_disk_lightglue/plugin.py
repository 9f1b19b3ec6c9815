"""Entry point of the ``disk_lightglue`` plugin (group ``c3_matcher.plugins``)."""

from __future__ import annotations

from c3_matcher.plugins import StrategySpec, strategy_hooks
from c3_matcher_disk_lightglue.defaults import DEFAULTS
from c3_matcher_disk_lightglue.matcher import STRATEGY, create

__all__ = ["c3_matcher_engine_specs", "c3_matcher_reference_backend", "c3_matcher_strategies"]

c3_matcher_strategies, c3_matcher_reference_backend, c3_matcher_engine_specs = strategy_hooks(
    StrategySpec(
        name=STRATEGY,
        factory=create,
        defaults=DEFAULTS,
        build_flag="BUILD_MATCHER_DISK_LIGHTGLUE",
        description="DISK features + LightGlue (the default strategy)",
    ),
    engine_specs="c3_matcher_disk_lightglue.engines:ENGINE_SPECS",
    reference_backend="c3_matcher_disk_lightglue.export:DiskLightGlueReference",
)
