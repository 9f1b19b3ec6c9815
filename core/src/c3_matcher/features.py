"""What a strategy's model I/O produces: keypoint features of one image, raw matches of a pair.

Names follow LightGlue's (``keypoints``, ``descriptors``, ``keypoint_scores``, ``matches``,
``scores``). Keypoints are (x, y) in the pixels of the image the extractor saw (the prepared,
resized image), origin at the centre of the top-left pixel.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from c3_matcher import _validate as v

__all__ = ["DESCRIPTOR_DTYPES", "Features", "PairSide", "RawMatches"]

#: descriptor dtypes a backend may return: float32 (learned descriptors, L2 distance / a learned
#: matcher) or uint8 (packed binary descriptors such as ORB's, 8 bits a byte, Hamming distance)
DESCRIPTOR_DTYPES = (np.dtype(np.float32), np.dtype(np.uint8))


class PairSide(NamedTuple):
    """One image's side of a pair to match: keypoints (K, 2) (x, y) px, descriptors (K, D) and
    the (width, height) px of the image the extractor saw."""

    keypoints: NDArray[np.float32]
    descriptors: NDArray[np.float32]
    size: tuple[int, int]


@dataclass(frozen=True, slots=True)
class Features:
    """Keypoints float32 (K, 2) (x, y) px; descriptors (K, D) float32, or uint8 for packed
    binary descriptors (D bytes = 8 D bits, matched by Hamming distance; never cast);
    keypoint_scores float32 (K,); image_size (width, height) of the image the extractor saw.
    The arrays are made read-only: one query's features serve every candidate and a tile's
    stay in the cache, so a matcher that edited them in place would make a frame's result
    depend on its candidates' order (it fails at its first write instead)."""

    keypoints: NDArray[np.float32]
    descriptors: NDArray[np.float32]
    keypoint_scores: NDArray[np.float32]
    image_size: tuple[int, int]

    def __post_init__(self) -> None:
        kp = v.array(self.keypoints, "features.keypoints", dtype=np.float32, shape=(None, 2))
        n = kp.shape[0]
        desc_dtype = getattr(self.descriptors, "dtype", None)
        v.require(
            desc_dtype is None or desc_dtype in DESCRIPTOR_DTYPES,
            "features.descriptors",
            f"expected dtype float32 or uint8 (binary), got {desc_dtype}",
        )
        v.array(self.descriptors, "features.descriptors", dtype=desc_dtype, shape=(n, None))
        v.array(self.keypoint_scores, "features.keypoint_scores", dtype=np.float32, shape=(n,))
        w, h = self.image_size
        v.require(w > 0 and h > 0, "features.image_size", f"must be > 0, got {self.image_size}")
        for array in (self.keypoints, self.descriptors, self.keypoint_scores):
            array.flags.writeable = False  # shared by every candidate and the cache: never edited

    def __len__(self) -> int:
        return int(self.keypoints.shape[0])

    @property
    def pair_side(self) -> PairSide:
        """This image's side of a ``LightGlueRuntime.match_pair`` call (set 0 or set 1)."""
        return PairSide(self.keypoints, self.descriptors, self.image_size)


@dataclass(frozen=True, slots=True)
class RawMatches:
    """Matches before RANSAC: ``matches`` int64 (M, 2) indices (query, tile) into the two
    keypoint arrays; ``scores`` float32 (M,) match confidences in [0, 1]."""

    matches: NDArray[np.int64]
    scores: NDArray[np.float32]

    def __post_init__(self) -> None:
        m = v.array(self.matches, "raw_matches.matches", dtype=np.int64, shape=(None, 2))
        v.array(self.scores, "raw_matches.scores", dtype=np.float32, shape=(m.shape[0],))

    def __len__(self) -> int:
        return int(self.matches.shape[0])
