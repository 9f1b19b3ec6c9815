"""The start-up engine-output assertion for XFeat (AZ-345 Constraints).

The core's ``engine_startup_probe`` uses 8x8 px blocks of random colour aligned to the image
grid; XFeat scores keypoints per 8x8 cell of that same grid, every cell is flat and no keypoint
passes the detection threshold. This probe is the same check on 6x6 px blocks (335 keypoints on
the XFeat engine at 128x128).
"""

from __future__ import annotations

import numpy as np

from c3_matcher.errors import EngineError
from c3_matcher.pipeline import FeatureBackend
from c3_matcher.preprocess import PreparedImage

__all__ = ["probe_image", "xfeat_startup_probe"]


def probe_image(size: int = 128, block: int = 6) -> PreparedImage:
    """A deterministic textured image: ``block`` px squares of random colour (seed 0), all valid.
    ``size`` px square (a multiple of 32 for XFeat)."""
    rng = np.random.default_rng(0)
    cells = -(-size // block)
    noise = rng.integers(0, 256, (cells, cells, 3), dtype=np.uint8)
    image = np.ascontiguousarray(np.kron(noise, np.ones((block, block, 1), np.uint8))[:size, :size])
    return PreparedImage(
        image=image,
        valid=np.ones((size, size), bool),
        working_from_engine=np.eye(3),
        working_size=(size, size),
    )


def xfeat_startup_probe(backend: FeatureBackend, size: int = 128) -> None:
    """Extract features of ``probe_image`` and match them with themselves; ``EngineError``
    (naming the build command) if either gives nothing or raises."""
    try:
        features = backend.extract(probe_image(size))
        if len(features) == 0:
            raise ValueError("the extractor found no keypoint on the textured probe image")
        matches = backend.match(features, features)
        if len(matches) == 0:
            raise ValueError("matching the probe image with itself gave no match")
    except Exception as exc:
        raise EngineError(
            getattr(backend, "label", "engine"),
            f"start-up probe failed: {type(exc).__name__}: {exc}",
        ) from exc
