"""A backend's ``extract``, its answer checked wherever the core takes it (the query, each tile,
the refine pass, the start-up probe): a :class:`Features` whose keypoints lie on the image it
was given. A backend that returns anything else, or keypoints of another scale or another
image, fails that extraction, naming what was wrong, as a NaN keypoint does: keypoints off the
image would otherwise reach RANSAC as correspondences nowhere on either image, and a
consistent mistake (a scale forgotten past some image size) gives a confident, wrong fix. In
flight (the query, each tile, the refine pass) an extraction with more keypoints than the
backend's budget (:func:`extraction_budget`) fails too: a million keypoints would take one
frame tens of seconds and hundreds of MB."""

from __future__ import annotations

import numpy as np

from c3_matcher.errors import InvalidInputError
from c3_matcher.features import Features
from c3_matcher.prepared import PreparedImage
from c3_matcher.protocols import FeatureBackend, KeypointBudgetBackend

__all__ = [
    "KEYPOINT_CEILING",
    "KEYPOINT_MARGIN_PX",
    "checked_features",
    "extract_checked",
    "extraction_budget",
]

KEYPOINT_MARGIN_PX = 1.0
"""How far (px) past the image's edge (pixel centres 0..w-1, the image -0.5..w-0.5) a keypoint
may lie: sub-pixel refinement at the border steps a fraction of a pixel out; further out, the
keypoint is not of this image."""

KEYPOINT_CEILING = 32768
"""The most keypoints per image the core takes from a backend that declares no keypoint budget
(no ``max_keypoints``: ``KeypointBudgetBackend``): above every budget a setting asks
(``[matcher] max_keypoints`` <= 8192; the example ORB plugin's option <= 20000), far below the
counts that make one frame take seconds and hundreds of MB."""


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


def extraction_budget(backend: FeatureBackend) -> tuple[int, str]:
    """The most keypoints one extraction of ``backend`` may hold, and that limit in words: the
    budget it declares (``max_keypoints``, a positive int), else :data:`KEYPOINT_CEILING`."""
    if isinstance(backend, KeypointBudgetBackend):
        declared = backend.max_keypoints
        if isinstance(declared, int) and not isinstance(declared, bool) and declared >= 1:
            return declared, f"the {declared} backbone {backend.label} declares (max_keypoints)"
    return KEYPOINT_CEILING, (
        f"the core's ceiling of {KEYPOINT_CEILING} for a backbone that declares no keypoint "
        f"budget ({backend.label} declares no max_keypoints)"
    )


def extract_checked(backend: FeatureBackend, image: PreparedImage) -> Features:
    """``backend.extract(image)``, checked (:func:`checked_features`) on the engine image the
    backend was given; ``InvalidInputError`` naming the count and the budget when it holds more
    keypoints than :func:`extraction_budget` allows (refused, not cut: which keypoints to keep
    is the backend's choice, and one over its own budget is broken)."""
    features = backend.extract(image)
    if isinstance(features, Features):
        budget, limit = extraction_budget(backend)
        if len(features) > budget:
            w, h = image.engine_size
            raise InvalidInputError(
                "features.keypoints",
                f"{len(features)} keypoints on the {w}x{h} px image, more than {limit}",
            )
    return checked_features(features, image.engine_size)
