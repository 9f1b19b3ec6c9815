"""Image resampling shared by the query and tile preparation and the flight simulator: area
downscaling before a shrinking warp, one bilinear remap, and the pixel-array check."""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from c3_matcher.errors import InvalidInputError

__all__ = ["area_downscale", "check_pixels", "remap_linear"]


def area_downscale(
    image: NDArray[np.uint8], factor: float
) -> tuple[NDArray[np.uint8], tuple[float, float]]:
    """``image`` shrunk ``factor`` times by area averaging (anti-aliasing before a warp that
    shrinks it), at least 2x2 px; and the (x, y) scale from its pixels to the result's."""
    h, w = image.shape[:2]
    sw, sh = max(2, round(w / factor)), max(2, round(h / factor))
    small = np.asarray(cv2.resize(image, (sw, sh), interpolation=cv2.INTER_AREA), dtype=np.uint8)
    return small, (sw / w, sh / h)


def remap_linear(
    src: NDArray[np.uint8], map1: NDArray[Any], map2: NDArray[Any]
) -> NDArray[np.uint8]:
    """``cv2.remap`` of ``src`` by ``map1``/``map2`` (either OpenCV map form), bilinear, black
    (all channels 0) where a map points outside ``src``."""
    return np.asarray(
        cv2.remap(
            src,
            map1,
            map2,
            cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=(0, 0, 0, 0),
        ),
        dtype=np.uint8,
    )


def check_pixels(image: object, field_name: str) -> NDArray[np.uint8]:
    """``image`` when it is uint8 (H, W) or (H, W, 3) of at least 2x2 px; else
    ``InvalidInputError`` naming ``field_name``."""
    if not isinstance(image, np.ndarray):
        raise InvalidInputError(field_name, f"expected numpy.ndarray, got {type(image).__name__}")
    if image.dtype != np.uint8:
        raise InvalidInputError(field_name, f"expected dtype uint8, got {image.dtype}")
    if not (image.ndim == 2 or (image.ndim == 3 and image.shape[2] == 3)):
        raise InvalidInputError(field_name, f"expected (H, W) or (H, W, 3), got {image.shape}")
    if image.shape[0] < 2 or image.shape[1] < 2:
        raise InvalidInputError(field_name, f"image too small: {image.shape}")
    return image
