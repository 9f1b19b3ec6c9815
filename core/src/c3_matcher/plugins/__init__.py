"""c3-matcher plugins: the plugin author's guide and the one module a plugin imports from.

A matcher strategy is a separately installable distribution. It is found through an entry point
in the group ``c3_matcher.plugins`` whose value is a module holding pluggy hook implementations::

    # pyproject.toml of your distribution
    [project.entry-points."c3_matcher.plugins"]
    my_matcher = "my_matcher_pkg.plugin"

    # my_matcher_pkg/plugin.py
    from c3_matcher import plugins as c3

    create = c3.strategy_factory(c3.ExtractorMatcher, make_config, MyOptions)

    @c3.hookimpl
    def c3_matcher_strategies() -> list[c3.StrategySpec]:
        return [c3.StrategySpec(name="my_matcher", factory=create, options_model=MyOptions,
                                description="...")]

Everything a plugin needs is importable from here (names load lazily, PEP 562: importing the
record types in ``c3_matcher.plugins.types`` loads no pluggy, OpenCV or ONNX Runtime).

``factory`` is called once at start-up by ``compose_root`` with keyword arguments ``config``
(``C3Settings``), ``options`` (your validated ``options_model`` or None) and the shared helpers
(``StrategyHelpers``: ``inference_runtime``, ``lightglue_runtime``, ``ransac_filter``,
``health_window``, ``fdr_client``, ``clock``) and returns a ``CrossDomainMatcher``; load your
engines there (start-up, not first frame).
There is one matcher class, ``PipelineMatcher``: it runs the per-frame loop and implements the
whole matcher contract; a strategy supplies its ``FeatureBackend`` (extract + match). An
"extractor engine + pair matcher" strategy writes no class at all: its config
(``ExtractorLightGlueConfig``, or its own ``ExtractorStrategyConfig``) and
``strategy_factory(ExtractorMatcher, make_config, options_model)`` give the ``create``
(``ExtractorBackend`` runs the extractor engine, ``LightGluePairMatcher`` the shared LightGlue).
``compose_root`` runs ``engine_startup_probe`` on the created matcher's ``backend``, for every
strategy: a broken engine fails at start-up. Networks that must be exported to ONNX are declared
with ``c3_matcher_engine_specs`` (``EngineSpec``, ``TensorSpec``, ``WeightsRef``) in a torch-free
run-time module; the exporter they name lives in a build-time module. A one-strategy plugin gets
its three hooks from ``strategy_hooks`` (``c3_matcher.plugins.strategy_hooks``).

Any other ``FeatureBackend`` (OpenCV ORB/SIFT/AKAZE, a PyTorch model, hand-written code: no
ONNX, no runtime) gets its ``create`` from ``backend_strategy_factory(make_backend,
options_model)``; descriptors may be float32 or packed binary uint8 (Hamming distance, never
cast). ``make_backend(config, options)`` applies the keypoint budget itself:
``config.matcher.max_keypoints`` is what ``--max-keypoints`` and ``[matcher] max_keypoints`` set
(None: your own default). ``StrategySpec(..., defaults=StrategyDefaults(photometric="clahe"))``
declares your own values for the settings a configuration leaves unset.
``tests/example_orb_plugin`` in the repository is such a plugin in 50 lines.

The hook specifications, each documented, are in ``c3_matcher.plugins.hookspecs``; the contract
test kit for your own tests is ``c3_matcher.testing.contract``: ``BackendContract`` (implement
``make_backend``; any backend) or ``MatcherContract`` (implement ``make_matcher`` over the
runtime doubles). Under the
airborne profile only the plugins its build allows are loaded; a third-party plugin runs under
research and replay-cli. ``tests/example_plugin`` in the repository is a complete plugin.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from c3_matcher._lazy import load_export

if TYPE_CHECKING:
    from c3_matcher.config import C3Settings
    from c3_matcher.engines.spec import EngineSpec, TensorSpec, WeightsRef, lightglue_io
    from c3_matcher.engines.store import EngineStore
    from c3_matcher.errors import EngineError
    from c3_matcher.features import Features, RawMatches
    from c3_matcher.health import RollingHealthWindow
    from c3_matcher.pipeline import FeatureBackend, PipelineMatcher, PipelineSettings
    from c3_matcher.plugins.hookspecs import PROJECT_NAME, hookimpl, hookspec
    from c3_matcher.plugins.manager import ENTRY_POINT_GROUP, LoadedPlugin, PluginHost
    from c3_matcher.plugins.strategy_hooks import strategy_hooks
    from c3_matcher.plugins.types import (
        StrategyDefaults,
        StrategyFactory,
        StrategyHelpers,
        StrategySpec,
    )
    from c3_matcher.prepared import InputRule, PreparedImage
    from c3_matcher.protocols import (
        Clock,
        CrossDomainMatcher,
        FdrClient,
        InferenceRuntime,
        LightGlueRuntime,
        RansacFilter,
    )
    from c3_matcher.strategy import (
        DEFAULT_MAX_KEYPOINTS,
        ExtractorBackend,
        ExtractorLightGlueConfig,
        ExtractorMatcher,
        ExtractorStrategyConfig,
        LightGluePairMatcher,
        PairMatcher,
        backend_strategy_factory,
        engine_startup_probe,
        strategy_factory,
    )

_EXPORTS: dict[str, str] = {
    "ENTRY_POINT_GROUP": "c3_matcher.plugins.manager",
    "LoadedPlugin": "c3_matcher.plugins.manager",
    "PluginHost": "c3_matcher.plugins.manager",
    "PROJECT_NAME": "c3_matcher.plugins.hookspecs",
    "hookimpl": "c3_matcher.plugins.hookspecs",
    "hookspec": "c3_matcher.plugins.hookspecs",
    "strategy_hooks": "c3_matcher.plugins.strategy_hooks",
    "StrategyDefaults": "c3_matcher.plugins.types",
    "StrategyFactory": "c3_matcher.plugins.types",
    "StrategyHelpers": "c3_matcher.plugins.types",
    "StrategySpec": "c3_matcher.plugins.types",
    "EngineSpec": "c3_matcher.engines.spec",
    "TensorSpec": "c3_matcher.engines.spec",
    "WeightsRef": "c3_matcher.engines.spec",
    "lightglue_io": "c3_matcher.engines.spec",
    "EngineStore": "c3_matcher.engines.store",
    "C3Settings": "c3_matcher.config",
    "EngineError": "c3_matcher.errors",
    "Features": "c3_matcher.features",
    "RawMatches": "c3_matcher.features",
    "RollingHealthWindow": "c3_matcher.health",
    "InputRule": "c3_matcher.preprocess",
    "PreparedImage": "c3_matcher.preprocess",
    "FeatureBackend": "c3_matcher.pipeline",
    "PipelineMatcher": "c3_matcher.pipeline",
    "PipelineSettings": "c3_matcher.pipeline",
    "Clock": "c3_matcher.protocols",
    "CrossDomainMatcher": "c3_matcher.protocols",
    "FdrClient": "c3_matcher.protocols",
    "InferenceRuntime": "c3_matcher.protocols",
    "LightGlueRuntime": "c3_matcher.protocols",
    "RansacFilter": "c3_matcher.protocols",
    "DEFAULT_MAX_KEYPOINTS": "c3_matcher.strategy",
    "ExtractorBackend": "c3_matcher.strategy",
    "ExtractorLightGlueConfig": "c3_matcher.strategy",
    "ExtractorMatcher": "c3_matcher.strategy",
    "ExtractorStrategyConfig": "c3_matcher.strategy",
    "LightGluePairMatcher": "c3_matcher.strategy",
    "PairMatcher": "c3_matcher.strategy",
    "backend_strategy_factory": "c3_matcher.strategy",
    "engine_startup_probe": "c3_matcher.strategy",
    "strategy_factory": "c3_matcher.strategy",
}

__all__ = [
    "DEFAULT_MAX_KEYPOINTS",
    "ENTRY_POINT_GROUP",
    "PROJECT_NAME",
    "C3Settings",
    "Clock",
    "CrossDomainMatcher",
    "EngineError",
    "EngineSpec",
    "EngineStore",
    "ExtractorBackend",
    "ExtractorLightGlueConfig",
    "ExtractorMatcher",
    "ExtractorStrategyConfig",
    "FdrClient",
    "FeatureBackend",
    "Features",
    "InferenceRuntime",
    "InputRule",
    "LightGluePairMatcher",
    "LightGlueRuntime",
    "LoadedPlugin",
    "PairMatcher",
    "PipelineMatcher",
    "PipelineSettings",
    "PluginHost",
    "PreparedImage",
    "RansacFilter",
    "RawMatches",
    "RollingHealthWindow",
    "StrategyDefaults",
    "StrategyFactory",
    "StrategyHelpers",
    "StrategySpec",
    "TensorSpec",
    "WeightsRef",
    "backend_strategy_factory",
    "engine_startup_probe",
    "hookimpl",
    "hookspec",
    "lightglue_io",
    "strategy_factory",
    "strategy_hooks",
]


def __getattr__(name: str) -> Any:  # PEP 562: the record types load without pluggy
    return load_export(__name__, _EXPORTS, globals(), name)


def __dir__() -> list[str]:  # PEP 562: the lazily loaded names show in dir() and completion
    return sorted({*globals(), *__all__})
