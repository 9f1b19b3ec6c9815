"""c3-matcher: the cross-domain matcher (C3) of a GPS-denied UAV navigation stack.

A nav-camera frame is matched against the top-N candidate satellite tiles with learned features,
RANSAC-filtered; the best candidate's inlier correspondences go downstream. Start at
``compose_root`` (wiring), ``CrossDomainMatcher`` (the contract) and the DTOs.
"""

from __future__ import annotations

from c3_matcher.compose import (
    AIRBORNE_REQUIRED_PRE_CONSTRUCTED_KEYS,
    ComposedRoot,
    build_default_helpers,
    build_plugin_host,
    compose_root,
)
from c3_matcher.config import C3Settings, MatcherSettings, load_settings
from c3_matcher.dto import (
    Attitude,
    CameraCalibration,
    CandidateMatchSet,
    MatcherHealth,
    MatchResult,
    NavCameraFrame,
    RansacResult,
    RerankCandidate,
    RerankResult,
    TileId,
)
from c3_matcher.errors import (
    AirborneBootstrapError,
    C3Error,
    ConfigurationError,
    EngineError,
    InsufficientInliersError,
    InvalidInputError,
    MatcherBackboneError,
    StrategyNotLinkedError,
)
from c3_matcher.fdr import InMemoryFdr, JsonlFdrRecorder, read_fdr
from c3_matcher.health import MonotonicClock, RollingHealthWindow
from c3_matcher.protocols import (
    Clock,
    CrossDomainMatcher,
    FdrClient,
    InferenceRuntime,
    LightGlueRuntime,
    RansacFilter,
    TilePixelsHandle,
)
from c3_matcher.ransac import OpenCvRansacFilter
from c3_matcher.tiles import BytesTileHandle, MmapTileHandle

__version__ = "0.1.0"

__all__ = [
    "AIRBORNE_REQUIRED_PRE_CONSTRUCTED_KEYS",
    "AirborneBootstrapError",
    "Attitude",
    "BytesTileHandle",
    "C3Error",
    "C3Settings",
    "CameraCalibration",
    "CandidateMatchSet",
    "Clock",
    "ComposedRoot",
    "ConfigurationError",
    "CrossDomainMatcher",
    "EngineError",
    "FdrClient",
    "InMemoryFdr",
    "InferenceRuntime",
    "InsufficientInliersError",
    "InvalidInputError",
    "JsonlFdrRecorder",
    "LightGlueRuntime",
    "MatchResult",
    "MatcherBackboneError",
    "MatcherHealth",
    "MatcherSettings",
    "MmapTileHandle",
    "MonotonicClock",
    "NavCameraFrame",
    "OpenCvRansacFilter",
    "RansacFilter",
    "RansacResult",
    "RerankCandidate",
    "RerankResult",
    "RollingHealthWindow",
    "StrategyNotLinkedError",
    "TileId",
    "TilePixelsHandle",
    "build_default_helpers",
    "build_plugin_host",
    "compose_root",
    "load_settings",
    "read_fdr",
]
