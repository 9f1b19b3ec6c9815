"""The interfaces of C3 and of the helpers it consumes (the matcher specification).

Everything here is a ``typing.Protocol``: concrete classes live elsewhere in the core, in the
strategy plugins, or in a caller's own code (test doubles included).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from c3_matcher.dto import (
    CameraCalibration,
    MatcherHealth,
    MatchResult,
    NavCameraFrame,
    RansacResult,
    RerankResult,
    TilePixelsHandle,
)
from c3_matcher.features import PairSide, RawMatches

if TYPE_CHECKING:
    from c3_matcher.engines.manifest import EngineManifest
    from c3_matcher.features import Features
    from c3_matcher.prepared import InputRule, PreparedImage
    from c3_matcher.tilestore.features import FeatureRequest

__all__ = [
    "Clock",
    "ClosableMatcher",
    "CrossDomainMatcher",
    "DigestedTileHandle",
    "EarlyExitLightGlueRuntime",
    "EarlyStopping",
    "FdrClient",
    "FeatureBackend",
    "InferenceRuntime",
    "KeypointBudgetBackend",
    "LightGlueRuntime",
    "LoadableLightGlueRuntime",
    "ManifestRuntime",
    "RansacFilter",
    "StoredFeaturesBackend",
    "StoredFeaturesHandle",
    "TilePixelsHandle",
]


@runtime_checkable
class CrossDomainMatcher(Protocol):
    """C3's strategy interface. One frame at a time (the shared pipeline serialises calls from
    several threads)."""

    def match(
        self, frame: NavCameraFrame, rerank_result: RerankResult, calibration: CameraCalibration
    ) -> MatchResult:
        """Match ``frame`` against every candidate; raise ``MatcherBackboneError`` (query frame
        failed) or ``InsufficientInliersError`` (no candidate reached the threshold)."""
        ...

    def health_snapshot(self) -> MatcherHealth: ...


@runtime_checkable
class ClosableMatcher(CrossDomainMatcher, Protocol):
    """A ``CrossDomainMatcher`` that can be closed (the shared pipeline's is): a later ``match``
    raises ``MatcherClosedError``, and a frame in progress finishes first. Optional: a
    strategy's own matcher may have no ``close``. ``ComposedRoot.close()`` closes it before it
    releases the recorder and the log sinks."""

    def close(self) -> None: ...


@runtime_checkable
class FeatureBackend(Protocol):
    """A strategy's model I/O, the one thing a strategy adds to the per-frame pipeline.
    Exceptions raised here (its own ``BaseException`` and ``sys.exit()`` too) become
    per-candidate drops (or, for the query frame, a ``MatcherBackboneError``); only a stop goes
    on to ``match``'s caller: Ctrl-C, a ``SystemExit`` one of the host's signal handlers raised,
    a closing generator (``stages.interrupts``)."""

    @property
    def label(self) -> str:
        """``matcher_label`` of the results, e.g. ``"disk_lightglue"``."""
        ...

    @property
    def input_rule(self) -> InputRule: ...

    @property
    def extract_phase(self) -> str:
        """Phase name of an extraction failure, e.g. ``"disk_forward"``."""
        ...

    @property
    def match_phase(self) -> str:
        """Phase name of a matching failure, e.g. ``"lightglue_match"``."""
        ...

    def extract(self, image: PreparedImage) -> Features: ...

    def match(self, query: Features, tile: Features) -> RawMatches: ...

    def provenance(self) -> Mapping[str, Any]:
        """What an investigator needs after a flight: execution provider, engines' sha256
        (``{"provider": ..., "engines": {"extractor": {"file_sha256": ...}, ...}}``)."""
        ...


@runtime_checkable
class KeypointBudgetBackend(FeatureBackend, Protocol):
    """A ``FeatureBackend`` that declares its keypoint budget ``max_keypoints``: at most this
    many keypoints per image (the strategy's default where no setting names one, cut to its
    extractor engine's top-K), a positive integer read once when the matcher is composed and
    fixed for the backend's life. Start-up checks ``[matcher] min_inliers_threshold`` against it
    and runs record it. An extraction over it keeps its best keypoints by score, said once per
    matcher (the contract kit fails it). Optional: a backend without one is held to the core's
    ceiling (``stages.extract.KEYPOINT_CEILING``) the same way."""

    @property
    def max_keypoints(self) -> int: ...


@runtime_checkable
class StoredFeaturesBackend(KeypointBudgetBackend, Protocol):
    """A ``KeypointBudgetBackend`` whose tile features a store may hold precomputed (``features
    build``): the stored features are cut to its budget and were extracted by the engine
    ``extractor_sha256`` names. Optional: the pipeline extracts every tile of any other backend
    (one that declares no extractor engine, like OpenCV SIFT)."""

    @property
    def extractor_sha256(self) -> str | None:
        """The ``file_sha256`` of its extractor engine (the one ``provenance()["engines"]
        ["extractor"]`` names): a store serves it only the sets that engine built. None when
        the engine cannot be named (its manifest unreadable): its tiles are then extracted."""
        ...


@runtime_checkable
class StoredFeaturesHandle(TilePixelsHandle, Protocol):
    """A tile handle whose store may hold precomputed map features (``features build``; the
    MBTiles handles do): ``stored_features(request)`` returns this tile's features in its own px
    for the backend ``request`` describes, or ``None`` when the store has none that fit.
    Optional: the pipeline extracts from the pixels of any other handle."""

    def stored_features(self, request: FeatureRequest) -> Features | None: ...


@runtime_checkable
class DigestedTileHandle(TilePixelsHandle, Protocol):
    """A tile handle that names its pixels' content without encoding them: ``content_digest()``
    digests the bytes they are decoded from, read anew at each call, and changes whenever the
    pixels do. The tile cache keys such a handle by it, any other by a digest of ``encoded()``.
    Optional: a mosaic of stored tiles declares it (its ``encoded()`` is a PNG made on demand,
    which costs more than extracting the tile on a GPU)."""

    def content_digest(self) -> str: ...


@runtime_checkable
class Clock(Protocol):
    """Monotonic time source (injected so tests control time)."""

    def monotonic_ns(self) -> int: ...


@runtime_checkable
class FdrClient(Protocol):
    """C13 flight-data recorder: ``record`` returns only once the record is durable."""

    def record(self, kind: str, payload: Mapping[str, Any]) -> None: ...


@runtime_checkable
class RansacFilter(Protocol):
    """RANSAC homography + median residual over (M, 4) correspondences."""

    def filter(self, correspondences: NDArray[np.float32], threshold_px: float) -> RansacResult: ...


@runtime_checkable
class InferenceRuntime(Protocol):
    """C7: loads engines at start-up and runs them."""

    @property
    def provider(self) -> str: ...

    def load_engine(self, path: Any) -> str: ...

    def run(self, engine_id: str, feeds: Mapping[str, NDArray[Any]]) -> dict[str, NDArray[Any]]: ...


@runtime_checkable
class ManifestRuntime(InferenceRuntime, Protocol):
    """An ``InferenceRuntime`` that also tells the manifest of a loaded engine (the ONNX Runtime
    one does): its feature type, size rule and options. Optional: a runtime without it runs
    engines whose manifests are not consulted."""

    def manifest(self, engine_id: str) -> EngineManifest: ...


@runtime_checkable
class LightGlueRuntime(Protocol):
    """The shared LightGlue handle, one engine per feature type.

    Keypoints are (x, y) px of images of ``size`` (width, height); LightGlue normalises them by
    those sizes exactly as the PyTorch model does.
    """

    def match_pair(self, side0: PairSide, side1: PairSide, *, feature_type: str) -> RawMatches: ...


@runtime_checkable
class LoadableLightGlueRuntime(LightGlueRuntime, Protocol):
    """A ``LightGlueRuntime`` that loads its engines at start-up (``OnnxLightGlueRuntime``):
    ``load(feature_type, engine_path)`` is idempotent for the same file and returns the file
    that will match ``feature_type`` (another than ``engine_path`` when one is loaded in its
    place, as a steps engine in adaptive mode), or None when it does not say. Optional: a
    strategy given a runtime without it expects the runtime to hold its engines already."""

    def load(self, feature_type: str, engine_path: Path) -> Path | None: ...


@runtime_checkable
class EarlyExitLightGlueRuntime(LightGlueRuntime, Protocol):
    """A ``LightGlueRuntime`` with the unmatchable-pair exit (``OnnxLightGlueRuntime``): in
    ``mode`` ``"adaptive"`` a pair with fewer than ``exit_matches`` confident mutual matches
    after its second layer stops with none (0: off); ``last_run`` says what the last
    ``match_pair`` did (``"unmatchable"``: stopped so, ``"matched"``: the count it had)."""

    @property
    def mode(self) -> str: ...
    @property
    def exit_matches(self) -> int: ...
    @property
    def last_run(self) -> Mapping[str, Any]: ...


@runtime_checkable
class EarlyStopping(Protocol):
    """A pair matcher, or a backend through its pair matcher, that a setting can make stop a
    pair early (LightGlue's unmatchable-pair exit). ``required_matches()``: ``(setting, n)``
    when a pair with fewer than ``n`` matches stops with none; ``early_stop()``: ``(setting,
    why)`` when the last match stopped so. None otherwise. The start-up probe asks, to tell a
    setting from an engine fault."""

    def required_matches(self) -> tuple[str, int] | None: ...
    def early_stop(self) -> tuple[str, str] | None: ...
