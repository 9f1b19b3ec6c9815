"""A plugin host with one in-process strategy, the helper doubles ``compose_root`` takes, and a
strategy factory over a :class:`~c3_matcher.testing.fakes.FakeBackend` type: what a test of
composition, lifecycle or logging needs to compose a root without installing a plugin."""

from __future__ import annotations

import types
from collections.abc import Callable, Sequence
from typing import Any

from c3_matcher.pipeline import PipelineMatcher, PipelineSettings
from c3_matcher.plugins import PluginHost, StrategySpec, hookimpl
from c3_matcher.plugins.manager import PluginSource
from c3_matcher.profiles import BuildProfile
from c3_matcher.strategy import PipelineHelpers, pipeline_matcher
from c3_matcher.testing.fakes import (
    FakeBackend,
    FakeInferenceRuntime,
    FakeLightGlueRuntime,
    FakeRansacFilter,
    ScriptedCandidate,
)

__all__ = ["RESEARCH_PROFILE", "fake_helpers", "one_strategy_host", "pipeline_strategy"]

RESEARCH_PROFILE = BuildProfile.from_data(
    {"name": "research", "strict": False, "flags": {}}, "test"
)
"""The research profile with no build flags: every strategy allowed, none required."""


def one_strategy_host(
    name: str, factory: Callable[..., Any], profile: BuildProfile = RESEARCH_PROFILE
) -> PluginHost:
    """A plugin host over one plugin, distribution ``<name>-dist`` 1.0, whose only strategy is
    ``name``, built by ``factory``."""
    module = types.SimpleNamespace(
        c3_matcher_strategies=hookimpl(lambda: [StrategySpec(name, factory)])
    )
    return PluginHost(profile, [PluginSource(name, f"{name}-dist", "1.0", module=module)])


def fake_helpers(script: Sequence[ScriptedCandidate] = ()) -> dict[str, Any]:
    """The helper components ``compose_root`` takes by name, as doubles following ``script``."""
    return {
        "c3_lightglue_runtime": FakeLightGlueRuntime(script),
        "c282_ransac_filter": FakeRansacFilter(script),
        "c7_inference": FakeInferenceRuntime(script),
    }


def pipeline_strategy(backend_type: type[FakeBackend] = FakeBackend) -> Callable[..., Any]:
    """A strategy factory: a :class:`PipelineMatcher` with default settings and no tile cache
    over a ``backend_type`` built on the composed runtimes."""

    def create(**kw: Any) -> PipelineMatcher:
        backend = backend_type(kw["inference_runtime"], kw["lightglue_runtime"])
        return pipeline_matcher(backend, PipelineSettings(), PipelineHelpers.from_named(kw))

    return create
