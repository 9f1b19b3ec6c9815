"""Photometric normalisation of engine images, the same for the query and the tiles."""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from c3_matcher.errors import InvalidInputError

__all__ = ["CLAHE_CELL_PX", "PHOTOMETRIC_MODES", "normalise_photometry", "to_rgb"]


def to_rgb(image: NDArray[np.uint8]) -> NDArray[np.uint8]:
    """``image`` as RGB: a grey (H, W) image replicated to (H, W, 3); RGB as it is."""
    if image.ndim == 2:
        return np.asarray(cv2.cvtColor(image, cv2.COLOR_GRAY2RGB), dtype=np.uint8)
    return image


PHOTOMETRIC_MODES = ("none", "grey", "clahe")
CLAHE_CELL_PX = 64  # CLAHE cells of a fixed size in WORKING px: the same ground area in both


def normalise_photometry(
    image: NDArray[np.uint8], valid: NDArray[np.uint8], mode: str, working_per_engine: float = 1.0
) -> NDArray[np.uint8]:
    """The photometric normalisation of an engine image (RGB uint8), the same for query
    and tile: ``"none"`` leaves it; ``"grey"`` keeps luminance only (replicated to three
    channels: what a season changes most is hue and saturation); ``"clahe"`` is grey plus
    contrast-limited adaptive histogram equalisation in cells of ``CLAHE_CELL_PX`` WORKING px
    (``working_per_engine`` of them to an engine px of ``image``: the same ground in the query
    and a tile; local contrast made comparable whatever the illumination, haze or the sensor's
    gain). Pixels outside ``valid`` (255 inside) stay 0."""
    if mode == "none":
        return image
    if mode not in PHOTOMETRIC_MODES:
        raise InvalidInputError("photometric", f"must be one of {PHOTOMETRIC_MODES}, got {mode!r}")
    grey = np.asarray(cv2.cvtColor(image, cv2.COLOR_RGB2GRAY), dtype=np.uint8)
    if mode == "clahe":
        h, w = grey.shape
        cell = CLAHE_CELL_PX / working_per_engine  # engine px
        cells = (max(1, round(w / cell)), max(1, round(h / cell)))
        grey = np.asarray(
            cv2.createCLAHE(clipLimit=2.0, tileGridSize=cells).apply(grey), dtype=np.uint8
        )
    grey = np.asarray(cv2.bitwise_and(grey, grey, mask=valid), dtype=np.uint8)
    return to_rgb(grey)
