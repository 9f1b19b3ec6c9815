"""c3-matcher plugins: the plugin author's guide.

A matcher strategy is a separately installable distribution. It is found through an entry point
in the group ``c3_matcher.plugins`` whose value is a module holding pluggy hook implementations::

    # pyproject.toml of your distribution
    [project.entry-points."c3_matcher.plugins"]
    my_matcher = "my_matcher_pkg.plugin"

    # my_matcher_pkg/plugin.py
    from c3_matcher.plugins import StrategySpec, hookimpl

    @hookimpl
    def c3_matcher_strategies() -> list[StrategySpec]:
        return [StrategySpec(name="my_matcher", build_flag=None, factory=create,
                             description="...")]

``factory`` is called once at start-up by ``compose_root`` with keyword arguments ``config``
(``C3Settings``), ``inference_runtime``, ``lightglue_runtime``, ``ransac_filter``,
``health_window``, ``fdr_client``, ``clock`` and ``options`` (your validated ``options_model`` or
None) and returns a ``CrossDomainMatcher``. Load your engines there (start-up, not first frame).
Most strategies only write a ``c3_matcher.pipeline.FeatureBackend`` (extract + match) and wrap
it in ``c3_matcher.pipeline.MatchPipeline``, which implements the whole matcher contract.
Networks that must be exported to ONNX are declared with ``c3_matcher_engine_specs``.

The hook specifications, each documented, are in ``c3_matcher.plugins.hookspecs``; the contract
test kit for your own tests is ``c3_matcher.testing``. Under the airborne profile only the
plugins its build allows are loaded; a third-party plugin runs under research and replay-cli.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS: dict[str, str] = {
    "ENTRY_POINT_GROUP": "c3_matcher.plugins.manager",
    "PROJECT_NAME": "c3_matcher.plugins.hookspecs",
    "LoadedPlugin": "c3_matcher.plugins.manager",
    "PluginHost": "c3_matcher.plugins.manager",
    "StrategyFactory": "c3_matcher.plugins.types",
    "StrategySpec": "c3_matcher.plugins.types",
    "hookimpl": "c3_matcher.plugins.hookspecs",
    "hookspec": "c3_matcher.plugins.hookspecs",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:  # PEP 562: the record types load without pluggy
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'c3_matcher.plugins' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value
