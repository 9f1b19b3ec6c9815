"""Two checks of the contract kit (``BackendContract``) that are stricter than flight, so a plugin
author learns in the kit what flight would quietly put right: the keypoint budget kept, and an
empty extraction's descriptors as wide as the backend's others.

In flight an extraction over the budget is cut to it (its best keypoints by score, said once),
and an image without keypoints is matched with nothing whatever its descriptors' width; an
extractor that overshoots (OpenCV's detectors keep the keypoints tied with the N-th: N + 1) or
answers ``(0, 0)`` for no keypoint is still a mistake the kit names."""

from __future__ import annotations

from collections.abc import Sequence

from c3_matcher.features import Features
from c3_matcher.prepared import PreparedImage
from c3_matcher.protocols import FeatureBackend
from c3_matcher.stages.extract import checked_features, extraction_budget

__all__ = ["assert_empty_fits", "assert_within_budget"]


def assert_within_budget(backend: FeatureBackend, images: Sequence[PreparedImage]) -> None:
    """``AssertionError`` naming the image, the count and the budget unless ``backend``
    extracts at most its keypoint budget (``extraction_budget``: its ``max_keypoints``, else the
    core's ceiling) from each of ``images``."""
    budget, limit = extraction_budget(backend)
    for image in images:
        w, h = image.engine_size
        count = len(checked_features(backend.extract(image), (w, h)))
        assert count <= budget, (
            f"{count} keypoints on the kit's {w}x{h} px image, more than {limit}: flight keeps "
            f"the {budget} of highest score; keep to the budget in extract (OpenCV's detectors "
            "keep the keypoints tied with the N-th: ask for fewer, or cut by score)"
        )


def assert_empty_fits(blank: Features, textured: Features) -> None:
    """``AssertionError`` naming both unless ``blank``'s descriptors (an image without
    keypoints) have ``textured``'s width and dtype: every image's descriptors are of one
    width and dtype, an empty ``Features``'s too (``(0, D)``)."""
    b, t = blank.descriptors, textured.descriptors
    assert b.dtype == t.dtype and b.shape[1] == t.shape[1], (
        f"a blank image's descriptors are {tuple(b.shape)} {b.dtype}, a textured one's "
        f"{tuple(t.shape)} {t.dtype}: give an image without keypoints descriptors "
        f"(0, {t.shape[1]}) {t.dtype} (OpenCV returns None descriptors there)"
    )
