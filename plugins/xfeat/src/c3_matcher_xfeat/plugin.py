"""Entry point of the ``xfeat`` plugin (group ``c3_matcher.plugins``)."""

from __future__ import annotations

from c3_matcher.plugins import StrategySpec, strategy_hooks
from c3_matcher_xfeat.defaults import DEFAULTS
from c3_matcher_xfeat.matcher import STRATEGY, create
from c3_matcher_xfeat.options import XFeatOptions

__all__ = ["c3_matcher_engine_specs", "c3_matcher_reference_backend", "c3_matcher_strategies"]

c3_matcher_strategies, c3_matcher_reference_backend, c3_matcher_engine_specs = strategy_hooks(
    StrategySpec(
        name=STRATEGY,
        factory=create,
        defaults=DEFAULTS,
        build_flag="BUILD_MATCHER_XFEAT",
        options_model=XFeatOptions,
        description="XFeat features + mutual NN or LighterGlue (light, CPU-only builds)",
    ),
    engine_specs="c3_matcher_xfeat.engines:ENGINE_SPECS",
    reference_backend="c3_matcher_xfeat.export:XFeatReference",
)
