"""Features.pair_side and match_features: the query is set 0, the tile set 1 of match_pair."""

from __future__ import annotations

from typing import Any

import numpy as np

from c3_matcher.features import Features, PairSide, RawMatches
from c3_matcher.strategy.pairs import match_features


def _features(n: int, size: tuple[int, int]) -> Features:
    rng = np.random.default_rng(n)
    return Features(
        rng.uniform(0, 100, (n, 2)).astype(np.float32),
        rng.normal(size=(n, 8)).astype(np.float32),
        np.ones(n, np.float32),
        size,
    )


class _Recorder:
    def __init__(self) -> None:
        self.args: tuple[Any, ...] = ()
        self.feature_type = ""

    def match_pair(self, side0: PairSide, side1: PairSide, *, feature_type: str) -> RawMatches:
        self.args, self.feature_type = (side0, side1), feature_type
        return RawMatches(np.zeros((0, 2), np.int64), np.zeros(0, np.float32))


def test_pair_side_is_keypoints_descriptors_size() -> None:
    f = _features(5, (640, 480))
    side = f.pair_side
    assert side.keypoints is f.keypoints and side.descriptors is f.descriptors
    assert side.size == (640, 480) and tuple(side) == (f.keypoints, f.descriptors, (640, 480))


def test_match_features_passes_query_then_tile() -> None:
    query, tile = _features(5, (640, 480)), _features(7, (512, 512))
    runtime = _Recorder()
    match_features(runtime, query, tile, "disk")
    (k0, d0, s0), (k1, d1, s1) = runtime.args
    assert (k0 is query.keypoints, d0 is query.descriptors, s0) == (True, True, (640, 480))
    assert (k1 is tile.keypoints, d1 is tile.descriptors, s1) == (True, True, (512, 512))
    assert runtime.feature_type == "disk"
