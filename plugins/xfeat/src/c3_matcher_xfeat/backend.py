"""``XFeatBackend``: the XFeat strategy's ``FeatureBackend`` (model I/O only).

Extraction runs the XFeat engine through the C7 ``InferenceRuntime`` (``run_extractor``: the
engine's fixed top-K, padding dropped, the ``max_keypoints`` best kept). Matching is a
``PairMatcher``: the numpy mutual nearest neighbour, or LighterGlue in the shared
``LightGlueRuntime`` (feature type ``"xfeat"``).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any, Protocol

from c3_matcher.engines.extract import run_extractor
from c3_matcher.engines.manifest import read_manifest
from c3_matcher.errors import EngineError
from c3_matcher.features import Features, RawMatches
from c3_matcher.preprocess import InputRule, PreparedImage
from c3_matcher.protocols import InferenceRuntime, LightGlueRuntime

__all__ = ["FEATURE_TYPE", "LightGluePairMatcher", "PairMatcher", "XFeatBackend"]

FEATURE_TYPE = "xfeat"


class PairMatcher(Protocol):
    """Matches the features of two images; exceptions become per-candidate drops."""

    def match(self, query: Features, tile: Features) -> RawMatches: ...


class LightGluePairMatcher:
    """A ``PairMatcher`` over the shared ``LightGlueRuntime`` (LighterGlue for ``"xfeat"``);
    loads the engine into it now (start-up) when the runtime has ``load``."""

    def __init__(
        self, runtime: LightGlueRuntime, engine_path: Path, feature_type: str = FEATURE_TYPE
    ) -> None:
        self._runtime = runtime
        self._feature_type = feature_type
        load = getattr(runtime, "load", None)
        if callable(load):
            load(feature_type, engine_path)

    def match(self, query: Features, tile: Features) -> RawMatches:
        return self._runtime.match_pair(
            query.keypoints,
            query.descriptors,
            query.image_size,
            tile.keypoints,
            tile.descriptors,
            tile.image_size,
            feature_type=self._feature_type,
        )


class XFeatBackend:
    """FeatureBackend: the XFeat extractor engine plus a ``PairMatcher``.

    ``engines`` maps a role (``"extractor"``, ``"lighterglue"``) to its engine file, for the
    provenance the FDR records; ``max_keypoints`` is the per-image budget (<= the graph's K).
    """

    def __init__(
        self,
        runtime: InferenceRuntime,
        pair_matcher: PairMatcher,
        *,
        label: str,
        extract_phase: str,
        match_phase: str,
        input_rule: InputRule,
        max_keypoints: int,
        extractor_engine_path: Path,
        engines: Mapping[str, Path] | None = None,
    ) -> None:
        self._runtime = runtime
        self._pair_matcher = pair_matcher
        self._label = label
        self._extract_phase = extract_phase
        self._match_phase = match_phase
        self._input_rule = input_rule
        self._max_keypoints = max_keypoints
        self.engine_id = runtime.load_engine(extractor_engine_path)
        facts = {"extractor": _engine_facts(runtime, self.engine_id, extractor_engine_path)}
        for role, path in (engines or {}).items():
            facts[role] = _engine_facts(None, None, path)
        self._provenance: dict[str, Any] = {"provider": runtime.provider, "engines": facts}

    @property
    def label(self) -> str:
        return self._label

    @property
    def input_rule(self) -> InputRule:
        return self._input_rule

    @property
    def extract_phase(self) -> str:
        return self._extract_phase

    @property
    def match_phase(self) -> str:
        return self._match_phase

    @property
    def pair_matcher(self) -> PairMatcher:
        return self._pair_matcher

    def extract(self, image: PreparedImage) -> Features:
        return run_extractor(
            self._runtime, self.engine_id, image.image, image.valid, self._max_keypoints
        )

    def match(self, query: Features, tile: Features) -> RawMatches:
        return self._pair_matcher.match(query, tile)

    def provenance(self) -> Mapping[str, Any]:
        return self._provenance


def _engine_facts(
    runtime: InferenceRuntime | None, engine_id: str | None, path: Path
) -> dict[str, Any]:
    """File, file sha256 and weights sha256 of an engine (from the runtime's manifest when it
    has one, else from the manifest next to the file); only the file when neither is readable."""
    manifest_of = getattr(runtime, "manifest", None)
    try:
        manifest = manifest_of(engine_id) if callable(manifest_of) else read_manifest(Path(path))
    except EngineError:
        return {"file": str(path)}
    return {
        "file": manifest.file,
        "file_sha256": manifest.file_sha256,
        "weights_sha256": manifest.weights_sha256,
    }
