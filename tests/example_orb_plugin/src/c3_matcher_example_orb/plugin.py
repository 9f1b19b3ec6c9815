"""A whole strategy without ONNX: OpenCV ORB keypoints, binary descriptors, brute-force Hamming."""

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from c3_matcher import plugins as c3


class Options(BaseModel):
    """``[matcher.options.example_orb]``."""  # an unknown key is refused at start-up

    model_config = ConfigDict(extra="forbid", frozen=True)
    max_keypoints: int | None = Field(None, ge=64, le=20000)  # None: [matcher]'s, else 2000

    def matches_with_lightglue(self) -> bool:  # its own matcher: [lightglue] set is warned unread
        return False


class OrbBackend:
    """ORB on the prepared image (uint8 RGB, masked); descriptors stay uint8 (32 bytes)."""

    label, extract_phase, match_phase = "example_orb", "orb_detect", "bf_hamming"
    input_rule = c3.InputRule(max_long_side=1024, multiple=1)

    def __init__(self, max_keypoints: int = 2000) -> None:
        self._orb, self._bf = cv2.ORB_create(max_keypoints), cv2.BFMatcher(cv2.NORM_HAMMING, True)

    def extract(self, image: c3.PreparedImage) -> c3.Features:
        grey = cv2.cvtColor(image.image, cv2.COLOR_RGB2GRAY)
        kps, desc = self._orb.detectAndCompute(grey, image.valid.astype(np.uint8) * 255)
        xy = np.array([k.pt for k in kps], np.float32).reshape(-1, 2)
        desc = np.zeros((0, 32), np.uint8) if desc is None else desc  # None: no keypoint
        scores = np.array([k.response for k in kps], np.float32)
        return c3.Features(xy, desc, scores, (grey.shape[1], grey.shape[0]))

    def match(self, query: c3.Features, tile: c3.Features) -> c3.RawMatches:
        both = len(query) and len(tile)
        found = self._bf.match(query.descriptors, tile.descriptors) if both else []
        pairs = np.array([(m.queryIdx, m.trainIdx) for m in found], np.int64).reshape(-1, 2)
        scores = np.array([1.0 - m.distance / 256.0 for m in found], np.float32)
        return c3.RawMatches(pairs, scores)

    def provenance(self) -> dict[str, object]:
        return {"provider": f"opencv {cv2.__version__}", "engines": {}}


create = c3.backend_strategy_factory(  # the option, else [matcher] max_keypoints, else 2000
    lambda s, o: OrbBackend(o.max_keypoints or s.matcher.max_keypoints or 2000), Options
)


@c3.hookimpl
def c3_matcher_strategies() -> list[c3.StrategySpec]:
    return [c3.StrategySpec("example_orb", create, options_model=Options, description="ORB")]
