"""c3-matcher: the cross-domain matcher (C3) of a GPS-denied UAV navigation stack.

A nav-camera frame is matched against the top-N candidate satellite tiles with learned features,
RANSAC-filtered; the best candidate's inlier correspondences go downstream. Start at
``compose_root`` (wiring), ``CrossDomainMatcher`` (the contract) and the DTOs.
"""

from __future__ import annotations

import os
from importlib.metadata import PackageNotFoundError, version
from typing import Any

from c3_matcher._lazy import load_export

# ONNX Runtime (1.29 on) keeps a telemetry queue on every platform: a device id and an event
# database under ~/.cache, uploaded when a network is there, and a coloured non-JSON stderr line
# where HOME is read-only. A flight computer does none of that. The variable is read once, when
# ONNX Runtime first starts, so it is set here, before any c3-matcher module imports it; a user
# who sets it (to 0) keeps their choice.
os.environ.setdefault("ORT_DISABLE_TELEMETRY", "1")

try:
    __version__ = version("c3-matcher")  # the one version: buildflags/matrix.toml
except PackageNotFoundError:  # pragma: no cover - running from a source tree without install
    __version__ = "0+unknown"

# Public names, imported on first use (PEP 562): ``import c3_matcher.dto`` loads the DTOs only,
# not OpenCV, ONNX Runtime, pluggy or pydantic-settings.
_EXPORTS: dict[str, str] = {
    "AIRBORNE_REQUIRED_PRE_CONSTRUCTED_KEYS": "c3_matcher.compose",
    "AirborneBootstrapError": "c3_matcher.errors",
    "AmbiguousMatchError": "c3_matcher.errors",
    "Attitude": "c3_matcher.dto",
    "build_default_helpers": "c3_matcher.compose",
    "build_plugin_host": "c3_matcher.compose",
    "BytesTileHandle": "c3_matcher.tiles",
    "C3Error": "c3_matcher.errors",
    "C3Settings": "c3_matcher.config",
    "check_fdr": "c3_matcher.fdr",
    "CameraCalibration": "c3_matcher.dto",
    "CandidateMatchSet": "c3_matcher.dto",
    "Clock": "c3_matcher.protocols",
    "compose_root": "c3_matcher.compose",
    "ComposedRoot": "c3_matcher.compose",
    "ConfigurationError": "c3_matcher.errors",
    "CrossDomainMatcher": "c3_matcher.protocols",
    "EngineError": "c3_matcher.errors",
    "FdrClient": "c3_matcher.protocols",
    "InferenceRuntime": "c3_matcher.protocols",
    "InMemoryFdr": "c3_matcher.fdr",
    "InsufficientInliersError": "c3_matcher.errors",
    "InvalidInputError": "c3_matcher.errors",
    "JsonlFdrRecorder": "c3_matcher.fdr",
    "LightGlueRuntime": "c3_matcher.protocols",
    "load_calibration": "c3_matcher.serialize",
    "load_settings": "c3_matcher.config",
    "MatcherBackboneError": "c3_matcher.errors",
    "MatcherClosedError": "c3_matcher.errors",
    "MatcherHealth": "c3_matcher.dto",
    "MatcherSettings": "c3_matcher.config",
    "MatchResult": "c3_matcher.dto",
    "MmapTileHandle": "c3_matcher.tiles",
    "MonotonicClock": "c3_matcher.health",
    "NavCameraFrame": "c3_matcher.dto",
    "OpenCvRansacFilter": "c3_matcher.ransac",
    "RansacFilter": "c3_matcher.protocols",
    "RansacResult": "c3_matcher.dto",
    "read_fdr": "c3_matcher.fdr",
    "read_fdr_log": "c3_matcher.fdr",
    "RerankCandidate": "c3_matcher.dto",
    "RerankResult": "c3_matcher.dto",
    "RollingHealthWindow": "c3_matcher.health",
    "StrategyNotLinkedError": "c3_matcher.errors",
    "StrategyStartupError": "c3_matcher.errors",
    "TileId": "c3_matcher.dto",
    "TilePixelsHandle": "c3_matcher.protocols",
}

__all__ = [*sorted(_EXPORTS), "__version__"]


def __getattr__(name: str) -> Any:
    return load_export(__name__, _EXPORTS, globals(), name)


def __dir__() -> list[str]:
    return sorted(__all__)
