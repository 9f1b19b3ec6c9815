"""A backend's ``match``, what it is given and what it returns checked where a candidate is
matched: the query's and the tile's descriptors of one dtype and one width, and a
:class:`RawMatches` back. Descriptors that differ (a tile extracted 16 bytes wide against the
query's 32, float32 against uint8) are an extraction's fault, not the pair matcher's: they fail
the candidate in the backend's extract phase, naming both, rather than deep in the matcher's
library (an OpenCV assertion) or, silently, as distances between two unlike spaces. An image
without a keypoint fits any other: nothing of it is compared."""

from __future__ import annotations

from typing import Any

from numpy.typing import NDArray

from c3_matcher.errors import InvalidInputError
from c3_matcher.features import Features, RawMatches
from c3_matcher.protocols import FeatureBackend

__all__ = ["check_descriptors_fit", "match_checked"]


def check_descriptors_fit(query: Features, tile: Features, backbone: str) -> None:
    """``InvalidInputError`` naming both descriptor arrays (shape, dtype) and ``backbone``
    unless ``query``'s and ``tile``'s descriptors share one dtype and one width: a pair matcher
    compares them entry by entry, so any other pair is no match of these two images. Either
    side without a keypoint passes, whatever its shape: nothing is compared (an OpenCV
    detector's empty answer often has another width), and the pair has no match."""
    q, t = query.descriptors, tile.descriptors
    if len(query) == 0 or len(tile) == 0:
        return
    if q.dtype == t.dtype and q.shape[1] == t.shape[1]:
        return
    raise InvalidInputError(
        "features.descriptors",
        f"the tile's descriptors {_described(t)} do not fit the query's {_described(q)} "
        f"(backbone {backbone}): extract gives every image descriptors of one dtype and width",
    )


def match_checked(backend: FeatureBackend, query: Features, tile: Features) -> RawMatches:
    """``backend.match(query, tile)``; ``InvalidInputError`` naming what it returned and the
    backbone when that is not :class:`RawMatches`."""
    raw = backend.match(query, tile)
    if not isinstance(raw, RawMatches):
        raise InvalidInputError(
            "raw_matches",
            f"match returned {type(raw).__name__}, not RawMatches (backbone {backend.label})",
        )
    return raw


def _described(descriptors: NDArray[Any]) -> str:
    """An array's shape and dtype, e.g. ``(812, 16) uint8``."""
    return f"{tuple(descriptors.shape)} {descriptors.dtype}"
