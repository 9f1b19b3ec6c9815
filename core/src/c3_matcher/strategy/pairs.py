"""Pair matchers: how a strategy matches the features of two images."""

from __future__ import annotations

from pathlib import Path
from typing import Protocol

from c3_matcher.features import Features, RawMatches
from c3_matcher.protocols import LightGlueRuntime, LoadableLightGlueRuntime


class PairMatcher(Protocol):
    """Matches the features of two images; an exception becomes a per-candidate drop."""

    def match(self, query: Features, tile: Features) -> RawMatches: ...


class LightGluePairMatcher:
    """A ``PairMatcher`` over the shared ``LightGlueRuntime`` for one feature type; loads the
    engine into it now (start-up) when the runtime has ``load``."""

    def __init__(self, runtime: LightGlueRuntime, engine_path: Path, feature_type: str) -> None:
        self._runtime = runtime
        self._feature_type = feature_type
        if isinstance(runtime, LoadableLightGlueRuntime):
            runtime.load(feature_type, engine_path)

    def match(self, query: Features, tile: Features) -> RawMatches:
        return match_features(self._runtime, query, tile, self._feature_type)


def match_features(
    runtime: LightGlueRuntime, query: Features, tile: Features, feature_type: str
) -> RawMatches:
    """``runtime.match_pair`` on two images' features (``feature_type``: the loaded engine's)."""
    return runtime.match_pair(query.pair_side, tile.pair_side, feature_type=feature_type)
