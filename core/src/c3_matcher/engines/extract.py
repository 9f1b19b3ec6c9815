"""Run an extractor engine on one image: feeds in, ``Features`` out. No PyTorch.

Extractor graph I/O (DISK now; ALIKED and XFeat follow the same pattern):
inputs ``image`` float32 (1, 3, H, W) RGB in [0, 1] and ``mask`` float32 (1, 1, H, W)
(1 = valid pixel, 0 = invalid: the heat map is multiplied by it before NMS, so no keypoint comes
from a masked pixel); outputs a fixed top-K: ``keypoints`` float32 (K, 2) (x, y) px with the
origin at the centre of the top-left pixel, ``keypoint_scores`` float32 (K,) sorted descending
(ties in raster order), ``descriptors`` float32 (K, D) L2-normalised. Rows with score <= 0 are
padding.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from c3_matcher.features import Features
from c3_matcher.protocols import InferenceRuntime, ManifestRuntime

__all__ = ["enlarged", "from_enlarged", "image_to_feeds", "run_extractor", "select_keypoints"]


def image_to_feeds(
    image_rgb_uint8: NDArray[np.uint8], valid_mask_bool: NDArray[np.bool_]
) -> dict[str, NDArray[np.float32]]:
    """The extractor feeds: ``image`` = RGB / 255 as float32 (1, 3, H, W), ``mask`` float32
    (1, 1, H, W). The build-time verification uses this same function."""
    if not (
        isinstance(image_rgb_uint8, np.ndarray)
        and image_rgb_uint8.dtype == np.uint8
        and image_rgb_uint8.ndim == 3
        and image_rgb_uint8.shape[2] == 3
    ):
        raise ValueError(
            "image must be uint8 (H, W, 3) RGB, got "
            f"{getattr(image_rgb_uint8, 'dtype', type(image_rgb_uint8))} "
            f"{getattr(image_rgb_uint8, 'shape', '')}"
        )
    height, width = image_rgb_uint8.shape[:2]
    if not (
        isinstance(valid_mask_bool, np.ndarray)
        and valid_mask_bool.dtype == np.bool_
        and valid_mask_bool.shape == (height, width)
    ):
        raise ValueError(
            f"valid mask must be bool ({height}, {width}), got "
            f"{getattr(valid_mask_bool, 'dtype', type(valid_mask_bool))} "
            f"{getattr(valid_mask_bool, 'shape', '')}"
        )
    image = np.ascontiguousarray(image_rgb_uint8.transpose(2, 0, 1)[None], dtype=np.float32)
    image /= np.float32(255.0)
    mask = np.ascontiguousarray(valid_mask_bool[None, None], dtype=np.float32)
    return {"image": image, "mask": mask}


def select_keypoints(
    keypoints: NDArray[np.float32],
    scores: NDArray[np.float32],
    descriptors: NDArray[np.float32],
    max_keypoints: int,
) -> tuple[NDArray[np.float32], NDArray[np.float32], NDArray[np.float32]]:
    """Drop padding (score <= 0) and keep the ``max_keypoints`` best by score, in descending
    score order with ties kept in the graph's order (a stable sort: deterministic)."""
    keep = np.flatnonzero(scores > 0)
    order = keep[np.argsort(-scores[keep], kind="stable")][:max_keypoints]
    return (
        np.ascontiguousarray(keypoints[order], dtype=np.float32),
        np.ascontiguousarray(scores[order], dtype=np.float32),
        np.ascontiguousarray(descriptors[order], dtype=np.float32),
    )


def run_extractor(
    runtime: InferenceRuntime,
    engine_id: str,
    image_rgb_uint8: NDArray[np.uint8],
    valid_mask_bool: NDArray[np.bool_],
    max_keypoints: int,
    upscale: int = 1,
) -> Features:
    """Extract features from an image whose H and W already satisfy the engine's input rule.

    ``image_rgb_uint8`` uint8 (H, W, 3) RGB; ``valid_mask_bool`` bool (H, W), True = valid pixel.
    Returns at most ``max_keypoints`` features, (x, y) px in this image, best score first;
    ``image_size`` is (W, H). ``upscale`` > 1: the engine is run on the image enlarged by that
    whole factor (bilinear; the mask nearest), its keypoints brought back to this image's px
    (``x = (x_up + 0.5) / upscale - 0.5``, ``cv2.resize``'s area-aligned convention).
    ``ValueError`` for bad inputs or an image breaking the size rule recorded in the engine's
    manifest.
    """
    if isinstance(max_keypoints, bool) or not isinstance(max_keypoints, int) or max_keypoints < 1:
        raise ValueError(f"max_keypoints must be an int >= 1, got {max_keypoints!r}")
    height, width = image_rgb_uint8.shape[:2]
    if upscale != 1:
        image_rgb_uint8, valid_mask_bool = enlarged(image_rgb_uint8, valid_mask_bool, upscale)
    feeds = image_to_feeds(image_rgb_uint8, valid_mask_bool)
    if isinstance(runtime, ManifestRuntime):
        multiple = runtime.manifest(engine_id).size_multiple
        if multiple and (height % multiple or width % multiple):
            raise ValueError(
                f"engine {engine_id} needs H and W multiples of {multiple}, got {width}x{height}"
            )
    out = runtime.run(engine_id, feeds)
    keypoints, scores, descriptors = select_keypoints(
        out["keypoints"], out["keypoint_scores"], out["descriptors"], max_keypoints
    )
    if upscale != 1:
        keypoints = from_enlarged(keypoints, upscale)
    return Features(
        keypoints=keypoints,
        descriptors=descriptors,
        keypoint_scores=scores,
        image_size=(int(width), int(height)),
    )


def enlarged(
    image: NDArray[np.uint8], valid: NDArray[np.bool_], upscale: int
) -> tuple[NDArray[np.uint8], NDArray[np.bool_]]:
    """``image`` (bilinear) and its ``valid`` mask (nearest), ``upscale`` times larger: what an
    extractor of an ``InputRule.upscale`` is run on."""
    size = (image.shape[1] * upscale, image.shape[0] * upscale)
    larger = cv2.resize(np.ascontiguousarray(image), size, interpolation=cv2.INTER_LINEAR)
    mask = cv2.resize(valid.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST)
    return np.asarray(larger, np.uint8), np.asarray(mask > 0)


def from_enlarged(keypoints: NDArray[np.float32], upscale: int) -> NDArray[np.float32]:
    """(x, y) px in an image :func:`enlarged` ``upscale`` times, back in the image's own px
    (``x = (x_up + 0.5) / upscale - 0.5``, ``cv2.resize``'s area-aligned convention)."""
    return ((keypoints + 0.5) / np.float32(upscale) - 0.5).astype(np.float32)
