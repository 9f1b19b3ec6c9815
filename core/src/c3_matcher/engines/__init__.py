"""Engines: ONNX graphs built offline from pretrained weights, run with ONNX Runtime.

Run time (no PyTorch): ``EngineStore`` finds engine files, ``OnnxInferenceRuntime`` loads and
runs them, ``OnnxLightGlueRuntime`` matches keypoint sets, ``run_extractor`` turns an image into
``Features``. Build time (``c3-matcher engines build``, extra ``engine-build``): ``compiler``
exports the engines that plugins declare as ``EngineSpec`` and verifies them against PyTorch.
"""

from __future__ import annotations

from c3_matcher.engines.manifest import EngineManifest
from c3_matcher.engines.naming import EngineName
from c3_matcher.engines.spec import EngineSpec, TensorSpec, WeightsRef
from c3_matcher.engines.store import (
    BUILD_COMMAND,
    EngineRecord,
    EngineStore,
    default_engine_dir,
)

__all__ = [
    "BUILD_COMMAND",
    "EngineManifest",
    "EngineName",
    "EngineRecord",
    "EngineSpec",
    "EngineStore",
    "TensorSpec",
    "WeightsRef",
    "default_engine_dir",
]
