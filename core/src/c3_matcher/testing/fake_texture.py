"""The fake extractor's and matcher's work on a block texture (the start-up probe's): a
keypoint at each block corner described by the colours around it, and pairs of equal
descriptors, so the doubles of :mod:`c3_matcher.testing.fakes` match a texture the way a
real strategy does."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from c3_matcher.features import RawMatches

__all__ = ["FAKE_DESCRIPTOR_DIM", "equal_descriptor_pairs", "rgb_uint8", "texture_features"]

FAKE_DESCRIPTOR_DIM = 16
"""Width of the fake extractor's descriptors (unit float32 vectors)."""


def rgb_uint8(image: NDArray[Any]) -> NDArray[np.uint8]:
    """An extractor feed, uint8 (H, W, 3) or float32 (1, 3, H, W) in [0, 1], as uint8
    (H, W, 3)."""
    if image.ndim == 4:
        image = image[0].transpose(1, 2, 0)
    if image.dtype.kind == "f":
        return np.rint(image * 255).astype(np.uint8)
    return np.asarray(image, np.uint8)


def texture_features(
    pixels: NDArray[np.uint8], mask: NDArray[Any] | None = None
) -> dict[str, NDArray[Any]]:
    """The fake extractor on a block texture (``textured_probe``): a keypoint at the top-left
    pixel of every block (its colour differs from the pixels left of and above it) where the
    mask is valid, in raster order, described by the four colours around it as a unit vector,
    so the same corner of a moved copy has the same descriptor."""
    rgb = pixels.astype(np.float32)
    corner = (pixels[1:, 1:] != pixels[1:, :-1]).any(-1) & (pixels[1:, 1:] != pixels[:-1, 1:]).any(
        -1
    )
    ys, xs = np.nonzero(corner)
    ys, xs = ys + 1, xs + 1
    if mask is not None:
        keep = np.asarray(mask).reshape(pixels.shape[:2])[ys, xs] > 0.5
        ys, xs = ys[keep], xs[keep]
    around = np.concatenate(
        [rgb[ys, xs], rgb[ys - 1, xs - 1], rgb[ys - 1, xs], rgb[ys, xs - 1]], axis=1
    )
    desc = np.zeros((len(xs), FAKE_DESCRIPTOR_DIM), np.float32)
    desc[:, : around.shape[1]] = around + 1.0
    desc /= np.linalg.norm(desc, axis=1, keepdims=True)
    return {
        "keypoints": np.stack([xs, ys], axis=1).astype(np.float32).reshape(-1, 2),
        "keypoint_scores": np.ones(len(xs), np.float32),
        "descriptors": desc,
    }


def equal_descriptor_pairs(desc0: NDArray[Any], desc1: NDArray[Any]) -> RawMatches:
    """Pairs (i, j), confidence 1, of each row i of ``desc0`` with the first equal row j of
    ``desc1``, in the order of i."""
    first: dict[bytes, int] = {}
    for j, row in enumerate(np.ascontiguousarray(desc1)):
        first.setdefault(row.tobytes(), j)
    rows = np.ascontiguousarray(desc0, dtype=np.asarray(desc1).dtype)
    pairs = [(i, first[row.tobytes()]) for i, row in enumerate(rows) if row.tobytes() in first]
    matches = np.array(pairs, np.int64).reshape(-1, 2)
    return RawMatches(matches, np.ones(len(matches), np.float32))
