"""Features are read-only: one query's features serve every candidate of a frame and a tile's
stay in the cache, so a matcher that edited them in place (RootSIFT over the descriptors, say)
made a frame's result depend on its candidates' order (90 inliers on the true tile in one
order, 34 in the reverse). It now fails at its first write."""

from __future__ import annotations

import numpy as np
import pytest

from c3_matcher.features import Features


def _features() -> Features:
    rng = np.random.default_rng(0)
    return Features(
        keypoints=rng.random((5, 2), dtype=np.float32),
        descriptors=rng.random((5, 4), dtype=np.float32),
        keypoint_scores=rng.random(5, dtype=np.float32),
        image_size=(32, 32),
    )


@pytest.mark.parametrize("name", ["keypoints", "descriptors", "keypoint_scores"])
def test_an_edit_in_place_fails_at_once(name: str) -> None:
    features = _features()
    with pytest.raises(ValueError, match="read-only"):
        getattr(features, name)[0] *= 2.0


def test_a_matcher_works_on_copies_as_before() -> None:
    features = _features()
    root = np.sqrt(features.descriptors / features.descriptors.sum(axis=1, keepdims=True))
    assert root.flags.writeable and root.shape == (5, 4)
