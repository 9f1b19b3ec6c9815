"""The PyTorch reference of ALIKED + LightGlue for benchmarks (engine-build environment only:
imports torch and kornia). It does the work the way a user of the upstream models would: kornia's
ALIKED (top-K mode, ``max_keypoints``, the valid mask multiplied into the score map through
``forward_laf``) on every image (tiles re-extracted every frame) and kornia's LightGlue with its
upstream adaptive depth and width ON (depth_confidence 0.95, width_confidence 0.99), the same
weights as the engines. Plugged into the core's pipeline so preprocessing and RANSAC are
identical."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from c3_matcher.config import C3Settings
from c3_matcher.features import Features, RawMatches
from c3_matcher.preprocess import InputRule, PreparedImage
from c3_matcher_aliked_lightglue.engines import (
    ALIKED_DESCRIPTOR_DIM,
    ALIKED_SIZE_MULTIPLE,
    ALIKED_SPECS,
    ALIKED_TOP_K,
    LIGHTGLUE_ALIKED_SPEC,
)
from c3_matcher_aliked_lightglue.export import aliked_reference_features, load_aliked_reference
from c3_matcher_aliked_lightglue.matcher import EXTRACT_PHASE, AlikedLightGlueOptions

__all__ = ["AlikedLightGlueReference"]

UPSTREAM_DEPTH_CONFIDENCE = 0.95
UPSTREAM_WIDTH_CONFIDENCE = 0.99


class AlikedLightGlueReference:
    """FeatureBackend over kornia's ALIKED and LightGlue (PyTorch, CPU)."""

    label = "aliked_lightglue[pytorch]"
    extract_phase = EXTRACT_PHASE
    match_phase = "lightglue_match"

    def __init__(self, settings: C3Settings) -> None:
        import torch

        from c3_matcher_tools.engines.export.lightglue import load_lightglue_reference

        raw = settings.matcher.options.get("aliked_lightglue", {})
        variant = AlikedLightGlueOptions.model_validate(raw).variant
        self._torch = torch
        self.input_rule = InputRule(settings.matcher.max_long_side, ALIKED_SIZE_MULTIPLE)
        self._aliked = load_aliked_reference(
            ALIKED_SPECS[variant].weights.resolve(),
            f"aliked-{variant}",
            settings.matcher.max_keypoints or ALIKED_TOP_K,  # None: the strategy's default
        )
        self._lightglue = load_lightglue_reference(
            LIGHTGLUE_ALIKED_SPEC.weights.resolve(), input_dim=ALIKED_DESCRIPTOR_DIM
        )
        self._lightglue.conf.depth_confidence = UPSTREAM_DEPTH_CONFIDENCE
        self._lightglue.conf.width_confidence = UPSTREAM_WIDTH_CONFIDENCE

    def extract(self, image: PreparedImage) -> Features:
        kp, scores, desc = aliked_reference_features(self._aliked, image.image, image.valid)
        order = np.argsort(-scores, kind="stable")
        return Features(kp[order], desc[order], scores[order], image.engine_size)

    def match(self, query: Features, tile: Features) -> RawMatches:
        t = self._torch

        def side(f: Features) -> dict[str, Any]:
            return {
                "keypoints": t.from_numpy(f.keypoints)[None],
                "descriptors": t.from_numpy(f.descriptors)[None],
                "image_size": t.tensor([f.image_size], dtype=t.float32),
            }

        with t.no_grad():
            out = self._lightglue({"image0": side(query), "image1": side(tile)})
        return RawMatches(
            out["matches"][0].numpy().astype(np.int64), out["scores"][0].numpy().astype(np.float32)
        )

    def provenance(self) -> Mapping[str, Any]:
        return {"provider": f"pytorch {self._torch.__version__} (CPU)", "engines": {}}
