"""``strategy_hooks``: the three hook implementations of a one-strategy plugin, built from its
description (no plugin writes them by hand).

A strategy plugin's entry module binds them at module level, where pluggy finds them::

    c3_matcher_strategies, c3_matcher_reference_backend, c3_matcher_engine_specs = (
        strategy_hooks(
            StrategySpec(name=STRATEGY, factory=create, build_flag="BUILD_MATCHER_MINE"),
            engine_specs="my_pkg.engines:ENGINE_SPECS",
            reference_backend="my_pkg.export:MyReference",
        )
    )

``engine_specs`` names the run-time (torch-free) module's tuple of ``EngineSpec``;
``reference_backend`` the build-time module's PyTorch ``FeatureBackend`` class, called with the
settings. Both are ``"module:attribute"`` strings imported when the hook runs, so loading the
plugin imports neither.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from c3_matcher.plugins.hookspecs import hookimpl

if TYPE_CHECKING:
    from c3_matcher.config import C3Settings
    from c3_matcher.engines.spec import EngineSpec
    from c3_matcher.pipeline import FeatureBackend
    from c3_matcher.plugins.types import StrategySpec

__all__ = ["StrategyHooks", "strategy_hooks"]

StrategyHooks = tuple[
    Callable[[], "list[StrategySpec]"],
    Callable[["str", "C3Settings"], "FeatureBackend | None"],
    Callable[[], "list[EngineSpec]"],
]
"""``(c3_matcher_strategies, c3_matcher_reference_backend, c3_matcher_engine_specs)``."""


def _resolve(target: str) -> Any:
    module, _, attribute = target.partition(":")
    if not module or not attribute:
        raise ValueError(f"{target!r} must be 'module:attribute'")
    return getattr(importlib.import_module(module), attribute)


def strategy_hooks(
    strategy: StrategySpec, *, engine_specs: str, reference_backend: str
) -> StrategyHooks:
    """The hook implementations of a plugin offering ``strategy`` (see the module docstring)."""
    offered = strategy.name

    @hookimpl
    def c3_matcher_strategies() -> list[StrategySpec]:
        return [strategy]

    @hookimpl
    def c3_matcher_reference_backend(strategy: str, settings: C3Settings) -> FeatureBackend | None:
        if strategy != offered:
            return None
        backend: FeatureBackend = _resolve(reference_backend)(settings)
        return backend

    @hookimpl
    def c3_matcher_engine_specs() -> list[EngineSpec]:
        return list(_resolve(engine_specs))

    return c3_matcher_strategies, c3_matcher_reference_backend, c3_matcher_engine_specs
