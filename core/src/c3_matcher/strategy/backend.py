"""``ExtractorBackend``: the ``FeatureBackend`` of every "extractor engine + pair matcher"
strategy, and the provenance facts of its engines."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Final

from loguru import logger

from c3_matcher.engines.extract import run_extractor
from c3_matcher.engines.manifest import read_manifest
from c3_matcher.errors import EngineError
from c3_matcher.features import Features, RawMatches
from c3_matcher.keypoint_budget import check_exit_reachable
from c3_matcher.prepared import PreparedImage
from c3_matcher.protocols import EarlyStopping, InferenceRuntime, ManifestRuntime
from c3_matcher.strategy.config import ExtractorStrategyConfig
from c3_matcher.strategy.pairs import EnginePairMatcher, PairMatcher


class ExtractorBackend:
    """FeatureBackend of every "extractor engine + pair matcher" strategy: the extractor engine
    through the ``InferenceRuntime`` (``run_extractor``: fixed top-K, padding dropped, the
    ``max_keypoints`` best kept), matching through a ``PairMatcher``."""

    def __init__(
        self,
        runtime: InferenceRuntime,
        pair_matcher: PairMatcher,
        config: ExtractorStrategyConfig,
    ) -> None:
        self._runtime = runtime
        self.label: Final = config.label
        self.input_rule: Final = config.input_rule
        self.extract_phase: Final = config.extract_phase
        self.match_phase: Final = config.match_phase
        self.pair_matcher: Final = pair_matcher
        self.engine_id = runtime.load_engine(config.extractor_engine_path)
        _check_size_multiple(runtime, self.engine_id, config)
        self.max_keypoints: Final = _budget(runtime, self.engine_id, config)
        """The keypoint budget (``KeypointBudgetBackend``): at most this many per image."""
        _check_reachable(pair_matcher, self.max_keypoints, config.label)
        facts = {"extractor": _engine_facts(runtime, self.engine_id, config.extractor_engine_path)}
        self.extractor_sha256: Final[str | None] = facts["extractor"].get("file_sha256")
        """Its extractor engine's file sha256 (``StoredFeaturesBackend``), as its provenance
        names it: the sets a store serves it were built by that engine."""
        served = (
            pair_matcher.engine_files()
            if isinstance(pair_matcher, EnginePairMatcher)
            else config.matcher_engines()
        )  # what matches: a steps engine loaded in place of the configured full one
        for role, path in served.items():
            facts[role] = _engine_facts(None, None, path)
        self._provenance: dict[str, Any] = {
            "provider": runtime.provider,
            "engines": facts,
            "input_rule": dataclasses.asdict(config.input_rule),  # upscale among it
        }

    def extract(self, image: PreparedImage) -> Features:
        return run_extractor(
            self._runtime,
            self.engine_id,
            image.image,
            image.valid,
            self.max_keypoints,
            self.input_rule.upscale,
        )

    def match(self, query: Features, tile: Features) -> RawMatches:
        return self.pair_matcher.match(query, tile)

    def required_matches(self) -> tuple[str, int] | None:
        """The pair matcher's, where a setting can stop its pairs early (``EarlyStopping``)."""
        matcher = self.pair_matcher
        return matcher.required_matches() if isinstance(matcher, EarlyStopping) else None

    def early_stop(self) -> tuple[str, str] | None:
        """The pair matcher's, where a setting can stop its pairs early (``EarlyStopping``):
        ``(setting, why)`` when one stopped the last match (the start-up probe asks)."""
        matcher = self.pair_matcher
        return matcher.early_stop() if isinstance(matcher, EarlyStopping) else None

    def provenance(self) -> Mapping[str, Any]:
        return self._provenance


def _budget(runtime: InferenceRuntime, engine_id: str, config: ExtractorStrategyConfig) -> int:
    """``config.max_keypoints``, at most the extractor engine's fixed top-K (its manifest's
    ``top_k``: a larger budget would keep no more and only be reported), said once when cut."""
    top_k = None
    if isinstance(runtime, ManifestRuntime):
        top_k = runtime.manifest(engine_id).options.get("top_k")
    if not isinstance(top_k, int) or config.max_keypoints <= top_k:
        return config.max_keypoints
    logger.bind(kind="c3.matcher.keypoints_capped", strategy=config.label).warning(
        "{}: {} keypoints per image asked, the extractor engine gives at most {}: {} kept",
        config.label,
        config.max_keypoints,
        top_k,
        top_k,
    )
    return top_k


def _check_reachable(pair_matcher: PairMatcher, budget: int, label: str) -> None:
    """``check_exit_reachable`` of the pair matcher's required matches (``required_matches``:
    LightGlue's unmatchable-pair exit) against the keypoint budget."""
    required = pair_matcher.required_matches() if isinstance(pair_matcher, EarlyStopping) else None
    check_exit_reachable(required, budget, label)


def _check_size_multiple(
    runtime: InferenceRuntime, engine_id: str, config: ExtractorStrategyConfig
) -> None:
    """``EngineError`` (no build advice: the strategy's rule is what is wrong) when the input
    rule's ``multiple`` is not a multiple of the sides the extractor engine's manifest takes:
    images prepared by that rule would be refused by the engine."""
    if not isinstance(runtime, ManifestRuntime):
        return
    needs = runtime.manifest(engine_id).size_multiple
    multiple = config.input_rule.multiple
    if needs and multiple % needs:
        raise EngineError(
            config.extractor_engine_path,
            f"it takes H and W multiples of {needs}, but the strategy {config.label}'s input "
            f"rule makes them multiples of {multiple} (its size multiple must be a multiple "
            f"of {needs})",
            command=None,
        )


def _engine_facts(
    runtime: InferenceRuntime | None, engine_id: str | None, path: Path
) -> dict[str, Any]:
    try:
        if isinstance(runtime, ManifestRuntime) and engine_id is not None:
            manifest = runtime.manifest(engine_id)
        else:
            manifest = read_manifest(Path(path))
    except EngineError:
        return {"file": str(path)}
    return {
        "file": manifest.file,
        "file_sha256": manifest.file_sha256,
        "weights_sha256": manifest.weights_sha256,
    }
