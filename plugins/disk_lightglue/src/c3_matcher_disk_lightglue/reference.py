"""The PyTorch reference of DISK + LightGlue for benchmarks (engine-build environment only:
imports torch and kornia). It does the work the way a user of the upstream models would: kornia's
DISK on every image (tiles re-extracted every frame) and kornia's LightGlue with its upstream
adaptive depth and width ON (depth_confidence 0.95, width_confidence 0.99), the same weights as
the engines. Plugged into the core's pipeline so preprocessing and RANSAC are identical."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from c3_matcher.config import C3Settings
from c3_matcher.engines.extract import image_to_feeds
from c3_matcher.features import Features, RawMatches
from c3_matcher.preprocess import InputRule, PreparedImage
from c3_matcher.strategy import DEFAULT_MAX_KEYPOINTS
from c3_matcher_disk_lightglue.engines import DISK_SPEC, LIGHTGLUE_DISK_SPEC
from c3_matcher_disk_lightglue.export import load_disk_reference

__all__ = ["DiskLightGlueReference"]

UPSTREAM_DEPTH_CONFIDENCE = 0.95
UPSTREAM_WIDTH_CONFIDENCE = 0.99


class DiskLightGlueReference:
    """FeatureBackend over kornia's DISK and LightGlue (PyTorch, CPU)."""

    label = "disk_lightglue[pytorch]"
    extract_phase = "disk_forward"
    match_phase = "lightglue_match"

    def __init__(self, settings: C3Settings) -> None:
        import torch

        from c3_matcher_tools.engines.export.lightglue import load_lightglue_reference

        self._torch = torch
        self.input_rule = InputRule(settings.matcher.max_long_side, 16)
        self._max_keypoints = settings.matcher.max_keypoints or DEFAULT_MAX_KEYPOINTS
        self._disk = load_disk_reference(DISK_SPEC.weights.resolve())
        self._lightglue = load_lightglue_reference(
            LIGHTGLUE_DISK_SPEC.weights.resolve(), input_dim=128
        )
        self._lightglue.conf.depth_confidence = UPSTREAM_DEPTH_CONFIDENCE
        self._lightglue.conf.width_confidence = UPSTREAM_WIDTH_CONFIDENCE

    def extract(self, image: PreparedImage) -> Features:
        feeds = image_to_feeds(image.image, image.valid)
        with self._torch.no_grad():
            out = self._disk(self._torch.from_numpy(feeds["image"]), n=self._max_keypoints)[0]
        return Features(
            np.ascontiguousarray(out.keypoints.numpy(), np.float32),
            np.ascontiguousarray(out.descriptors.numpy(), np.float32),
            np.ascontiguousarray(out.detection_scores.numpy(), np.float32),
            image.engine_size,
        )

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
