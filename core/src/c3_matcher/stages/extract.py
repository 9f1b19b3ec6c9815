"""A backend's ``extract``, its answer checked wherever the core takes it (the query, each tile,
the refine pass, the start-up probe): a :class:`Features` whose keypoints lie on the image it
was given. A backend that returns anything else, or keypoints of another scale or another
image, fails that extraction, naming what was wrong, as a NaN keypoint does: keypoints off the
image would otherwise reach RANSAC as correspondences nowhere on either image, and a
consistent mistake (a scale forgotten past some image size) gives a confident, wrong fix."""

from __future__ import annotations

import numpy as np

from c3_matcher.errors import InvalidInputError
from c3_matcher.features import Features
from c3_matcher.prepared import PreparedImage
from c3_matcher.protocols import FeatureBackend

__all__ = ["KEYPOINT_MARGIN_PX", "checked_features", "extract_checked"]

KEYPOINT_MARGIN_PX = 1.0
"""How far (px) past the image's edge (pixel centres 0..w-1, the image -0.5..w-0.5) a keypoint
may lie: sub-pixel refinement at the border steps a fraction of a pixel out; further out, the
keypoint is not of this image."""


def checked_features(features: object, size: tuple[int, int], image: str = "image") -> Features:
    """``features`` as the extraction of a ``size`` (w, h) px ``image``; ``InvalidInputError``
    when it is not :class:`Features` or has keypoints off the image (more than
    :data:`KEYPOINT_MARGIN_PX` past its edge)."""
    if not isinstance(features, Features):
        raise InvalidInputError(
            "features", f"extract returned {type(features).__name__}, not Features"
        )
    w, h = size
    low = -0.5 - KEYPOINT_MARGIN_PX
    kp = features.keypoints.astype(np.float64)
    on = (kp >= low) & (kp <= np.array([w, h], np.float64) - 0.5 + KEYPOINT_MARGIN_PX)
    off = ~on.all(axis=1)
    if off.any():
        lo, hi = kp[off].min(axis=0), kp[off].max(axis=0)
        raise InvalidInputError(
            "features.keypoints",
            f"{int(off.sum())} keypoint(s) outside the {w}x{h} px {image} (x {lo[0]:.0f}.."
            f"{hi[0]:.0f}, y {lo[1]:.0f}..{hi[1]:.0f}): keypoints are in the pixels of the "
            "image extract was given",
        )
    return features


def extract_checked(backend: FeatureBackend, image: PreparedImage) -> Features:
    """``backend.extract(image)``, checked (:func:`checked_features`) on the engine image the
    backend was given."""
    return checked_features(backend.extract(image), image.engine_size)
