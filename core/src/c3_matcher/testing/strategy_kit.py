"""Test helpers for a strategy plugin built on the extractor kit (``ExtractorMatcher``).

``ExtractorMatcherContract`` is the contract kit over the allowed doubles, set up from two facts
(the matcher class and a config)::

    from c3_matcher.testing.strategy_kit import ExtractorMatcherContract

    class TestMyMatcherContract(ExtractorMatcherContract):
        matcher_class = MyMatcher
        config = MyConfig(label="mine", ...)

On the real path, ``matcher_over_helpers`` builds the matcher over the real runtimes of
``build_default_helpers`` and ``compose_ready`` runs ``compose_root`` and returns its one
``c3.matcher.ready`` log record; ``assert_registered`` checks the strategy through the public
plugin lookup, ``installed_file_sha256`` hashes the weights its engines were built from and
``assert_features_identical`` checks two extractions bit for bit.
"""

from __future__ import annotations

import io
import json
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any, ClassVar, TypeVar

from c3_matcher.fdr import InMemoryFdr
from c3_matcher.features import Features
from c3_matcher.health import MonotonicClock, RollingHealthWindow
from c3_matcher.logs import MATCHER_READY, configure_logging
from c3_matcher.protocols import CrossDomainMatcher
from c3_matcher.strategy import ExtractorMatcher, ExtractorStrategyConfig
from c3_matcher.testing.contract import Doubles, MatcherContract
from c3_matcher.testing.fakes import ScriptedPairMatcher

if TYPE_CHECKING:
    from c3_matcher.compose import ComposedRoot
    from c3_matcher.config import C3Settings
    from c3_matcher.engines.spec import EngineSpec
    from c3_matcher.plugins import PluginHost

__all__ = [
    "ExtractorMatcherContract",
    "assert_features_identical",
    "assert_registered",
    "compose_ready",
    "installed_file_sha256",
    "matcher_over_helpers",
]

M = TypeVar("M", bound=ExtractorMatcher)
HEALTH_MIN_INLIERS = 60  # the health window's threshold in the real-path helper


class ExtractorMatcherContract(MatcherContract):
    """``MatcherContract`` for an ``ExtractorMatcher`` subclass: set ``matcher_class`` and
    ``config``; the phase names are the config's. The strategy's own pair matcher
    (``config.pair_matcher``: LightGlue, a mutual nearest neighbour, any other) runs on the fake
    extractor's distinct unit descriptors, wrapped so the script's ``fail_match`` raises
    (``ScriptedPairMatcher``)."""

    matcher_class: ClassVar[type[ExtractorMatcher]]
    config: ClassVar[ExtractorStrategyConfig]

    def _phases(self, doubles: Doubles) -> tuple[str, str]:
        if doubles.backend is not None:
            return super()._phases(doubles)
        return self.config.extract_phase, self.config.match_phase

    def make_matcher(self, doubles: Doubles) -> CrossDomainMatcher:
        return self.matcher_class(
            doubles.inference,
            doubles.lightglue,
            doubles.ransac,
            doubles.fdr,
            doubles.health,
            self.config,
            doubles.clock,
            pair_matcher=ScriptedPairMatcher(
                self.config.pair_matcher(doubles.lightglue), doubles.script
            ),
        )


def matcher_over_helpers(
    matcher_class: type[M], config: ExtractorStrategyConfig, helpers: Mapping[str, Any]
) -> M:
    """``matcher_class`` over the real inference runtime, LightGlue runtime and RANSAC of
    ``build_default_helpers``, an in-memory FDR and a 60-inlier health window."""
    return matcher_class(
        helpers["c7_inference"],
        helpers["c3_lightglue_runtime"],
        helpers["c282_ransac_filter"],
        InMemoryFdr(),
        RollingHealthWindow(MonotonicClock(), HEALTH_MIN_INLIERS),
        config,
    )


def compose_ready(
    settings: C3Settings, helpers: Mapping[str, Any], *, plugin_host: PluginHost | None = None
) -> tuple[ComposedRoot, dict[str, Any]]:
    """``compose_root(settings)`` over ``helpers`` (and ``plugin_host``, else the installed
    plugins) with an in-memory FDR, its logs captured; returns the root and its
    ``c3.matcher.ready`` record (AssertionError unless exactly one)."""
    from c3_matcher.compose import compose_root

    fdr = InMemoryFdr()
    stream = io.StringIO()
    handle = configure_logging(fdr, stream=stream)
    try:
        root = compose_root(
            settings, {**helpers, "c13_fdr": fdr}, plugin_host=plugin_host, configure_logs=False
        )
    finally:
        handle.close()
    records = [json.loads(line) for line in stream.getvalue().splitlines()]
    ready = [r for r in records if r["kind"] == MATCHER_READY]
    assert len(ready) == 1, f"{len(ready)} {MATCHER_READY} records"
    return root, ready[0]


def assert_features_identical(a: Features, b: Features) -> None:
    """Keypoints, descriptors and scores of two extractions equal bit for bit."""
    for name in ("keypoints", "descriptors", "keypoint_scores"):
        assert getattr(a, name).tobytes() == getattr(b, name).tobytes(), name


def assert_registered(
    name: str,
    *,
    build_flag: str,
    distribution: str,
    engines: set[tuple[str, str]],
    options_model: type | None = None,
) -> dict[tuple[str, str], EngineSpec]:
    """The strategy ``name`` as the public plugin lookup finds it: its build flag, options model,
    distribution and (at least) ``engines`` by (model, variant). Returns every engine spec the
    plugins declare, by (model, variant)."""
    from c3_matcher.compose import build_plugin_host

    host = build_plugin_host()
    spec = host.resolve(name)
    assert spec.build_flag == build_flag
    assert spec.options_model is options_model
    assert host.strategy_plugin(name).distribution == distribution
    by_key = {(s.model, s.variant): s for s in host.engine_specs()}
    assert engines <= set(by_key), sorted(engines - set(by_key))
    return by_key


def installed_file_sha256(distribution: str, path: str) -> str:
    """sha256 (hex) of a file an installed distribution ships, e.g. pretrained weights."""
    import importlib.metadata
    from pathlib import Path

    from c3_matcher.engines.spec import file_sha256

    located = importlib.metadata.distribution(distribution).locate_file(path)
    return file_sha256(Path(str(located)))
