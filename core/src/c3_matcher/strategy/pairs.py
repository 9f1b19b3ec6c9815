"""Pair matchers: how a strategy matches the features of two images."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Protocol, runtime_checkable

from c3_matcher.features import Features, RawMatches
from c3_matcher.protocols import (
    EarlyExitLightGlueRuntime,
    LightGlueRuntime,
    LoadableLightGlueRuntime,
)


class PairMatcher(Protocol):
    """Matches the features of two images; an exception becomes a per-candidate drop."""

    def match(self, query: Features, tile: Features) -> RawMatches: ...


@runtime_checkable
class EnginePairMatcher(PairMatcher, Protocol):
    """A ``PairMatcher`` that runs engine files and says which (the FDR names them)."""

    def engine_files(self) -> Mapping[str, Path]:
        """The engine files that match, by provenance role (``"lightglue"``)."""
        ...


class LightGluePairMatcher:
    """A ``PairMatcher`` over the shared ``LightGlueRuntime`` for one feature type; loads the
    engine into it now (start-up) when the runtime has ``load``. ``role`` names the engine in
    the provenance: the file the runtime says it runs (a steps engine loaded in place of the
    full one), else ``engine_path``."""

    def __init__(
        self,
        runtime: LightGlueRuntime,
        engine_path: Path,
        feature_type: str,
        *,
        role: str = "lightglue",
    ) -> None:
        self._runtime = runtime
        self._feature_type = feature_type
        served = None
        if isinstance(runtime, LoadableLightGlueRuntime):
            served = runtime.load(feature_type, engine_path)
        self._engine_files = {role: Path(served or engine_path)}

    def engine_files(self) -> Mapping[str, Path]:
        return dict(self._engine_files)

    def match(self, query: Features, tile: Features) -> RawMatches:
        return match_features(self._runtime, query, tile, self._feature_type)

    def required_matches(self) -> tuple[str, int] | None:
        """``("lightglue.exit_matches", n)`` when the runtime runs adaptive with the
        unmatchable-pair exit on: a pair with fewer than ``n`` confident mutual matches after
        its second layer stops with none; None otherwise."""
        runtime = self._runtime
        if not isinstance(runtime, EarlyExitLightGlueRuntime) or runtime.mode != "adaptive":
            return None
        count = runtime.exit_matches
        return ("lightglue.exit_matches", count) if count > 0 else None

    def early_stop(self) -> tuple[str, str] | None:
        """``("lightglue.exit_matches", why)`` when the runtime's last match (``last_run``, of
        whichever thread matched last: for the start-up probe) stopped the pair at the
        unmatchable-pair exit, a setting rather than a fault; None otherwise."""
        runtime = self._runtime
        if not isinstance(runtime, EarlyExitLightGlueRuntime):
            return None
        run = runtime.last_run
        if not run.get("unmatchable"):
            return None
        return (
            "lightglue.exit_matches",
            f"{runtime.exit_matches} stopped the pair after its second layer "
            f"({run.get('matched')} mutual matches of confidence above 0.3)",
        )


def match_features(
    runtime: LightGlueRuntime, query: Features, tile: Features, feature_type: str
) -> RawMatches:
    """``runtime.match_pair`` on two images' features (``feature_type``: the loaded engine's)."""
    return runtime.match_pair(query.pair_side, tile.pair_side, feature_type=feature_type)
