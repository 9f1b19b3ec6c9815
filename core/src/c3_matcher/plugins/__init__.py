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

from c3_matcher.plugins.hookspecs import PROJECT_NAME, hookimpl, hookspec
from c3_matcher.plugins.manager import ENTRY_POINT_GROUP, LoadedPlugin, PluginHost
from c3_matcher.plugins.types import StrategyFactory, StrategySpec

__all__ = [
    "ENTRY_POINT_GROUP",
    "PROJECT_NAME",
    "LoadedPlugin",
    "PluginHost",
    "StrategyFactory",
    "StrategySpec",
    "hookimpl",
    "hookspec",
]
