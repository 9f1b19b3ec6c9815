"""Mutual nearest neighbour matching of L2-normalised descriptors (deterministic).

The rule of upstream ``XFeat.match``: keypoint i of image 0 and j of image 1 match when j is
i's most similar descriptor (cosine similarity = dot product of unit vectors) and i is j's, and,
when ``min_cossim > 0``, their similarity exceeds ``min_cossim``. Ties go to the lowest index
(``numpy.argmax``), so identical inputs give identical matches.

The similarity matrix (4096 x 4096 x 64 for two full XFeat sets) is the one heavy product. In
flight (``MutualNearestNeighbourMatcher``) it runs as ONNX Runtime's ``Gemm`` in a session of its
own whose threads do not spin after a run (``OnnxSimilarity``). numpy's product, through
OpenBLAS, gives the same matrix to float32 rounding (bit for bit on an AVX-512 CPU, where both
take the same kernel), but OpenBLAS's worker threads keep spinning for a while after it and
took the cores from the next XFeat extraction: on the 2-core reference machine that
extraction ran ~2x slower (docs/benchmarks.md). ``mutual_nearest_neighbours`` keeps numpy's
product as its default (ground tools and tests).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import onnxruntime as ort
from numpy.typing import NDArray

from c3_matcher.engines.providers import CPU_PROVIDER
from c3_matcher.engines.runtime import SessionSettings
from c3_matcher.features import Features, RawMatches

__all__ = [
    "SIMILARITY_GRAPH",
    "MutualNearestNeighbourMatcher",
    "OnnxSimilarity",
    "mutual_nearest_neighbours",
    "numpy_similarity",
]

SIMILARITY_GRAPH = Path(__file__).with_name("similarity.onnx")
"""``similarity = Gemm(desc0, desc1, transB=1)``: inputs ``desc0`` float32 (M, D) and ``desc1``
float32 (N, D), output ``similarity`` float32 (M, N). Package data, written by
``c3_matcher_xfeat.export.similarity_graph`` (a test keeps the two equal)."""

Similarity = Callable[[NDArray[np.float32], NDArray[np.float32]], NDArray[np.float32]]
"""``(desc0 (M, D), desc1 (N, D)) -> desc0 @ desc1.T`` float32 (M, N)."""


def numpy_similarity(desc0: NDArray[np.float32], desc1: NDArray[np.float32]) -> NDArray[np.float32]:
    """``desc0 @ desc1.T`` in numpy."""
    return np.asarray(desc0 @ desc1.T, np.float32)


class OnnxSimilarity:
    """``desc0 @ desc1.T`` on ONNX Runtime (CPU) over ``SIMILARITY_GRAPH``, ``threads`` intra-op
    threads (0: one per core), spinning off (``SessionSettings.allow_spinning``)."""

    def __init__(self, threads: int = 0) -> None:
        options = SessionSettings(intra_op_num_threads=threads, allow_spinning=False).build()
        self._session = ort.InferenceSession(
            str(SIMILARITY_GRAPH), options, providers=[CPU_PROVIDER]
        )

    def __call__(
        self, desc0: NDArray[np.float32], desc1: NDArray[np.float32]
    ) -> NDArray[np.float32]:
        out = self._session.run(None, {"desc0": desc0, "desc1": desc1})[0]
        return np.asarray(out, np.float32)


def mutual_nearest_neighbours(
    desc0: NDArray[np.float32],
    desc1: NDArray[np.float32],
    min_cossim: float,
    similarity: Similarity = numpy_similarity,
) -> RawMatches:
    """Match ``desc0`` float32 (M, D) with ``desc1`` float32 (N, D), both L2-normalised.

    Returns ``RawMatches``: ``matches`` int64 (P, 2) in ascending order of the image-0 index,
    ``scores`` float32 (P,) their cosine similarity clipped to [0, 1].
    """
    if desc0.ndim != 2 or desc1.ndim != 2 or desc0.shape[1] != desc1.shape[1]:
        raise ValueError(f"descriptors must be (M, D) and (N, D), got {desc0.shape}, {desc1.shape}")
    if len(desc0) == 0 or len(desc1) == 0:
        return RawMatches(np.zeros((0, 2), np.int64), np.zeros((0,), np.float32))
    sim = similarity(
        np.ascontiguousarray(desc0, np.float32), np.ascontiguousarray(desc1, np.float32)
    )
    best1 = np.argmax(sim, axis=1)
    index0 = np.arange(len(desc0))
    similarity_best = sim[index0, best1]
    # i is j's nearest neighbour iff sim[i, j] is column j's maximum; on a tie the lowest i wins
    # (argmax semantics). Same result as argmax over axis 0, which is ~50x slower (strided).
    candidates = np.flatnonzero(similarity_best == sim.max(axis=0)[best1])
    _, first = np.unique(best1[candidates], return_index=True)
    keep = np.zeros(len(desc0), dtype=bool)
    keep[candidates[first]] = True
    if min_cossim > 0:
        keep &= similarity_best > np.float32(min_cossim)
    matches = np.stack([index0[keep], best1[keep]], axis=-1).astype(np.int64)
    scores = np.clip(similarity_best[keep], 0.0, 1.0).astype(np.float32)
    return RawMatches(np.ascontiguousarray(matches.reshape(-1, 2)), np.ascontiguousarray(scores))


class MutualNearestNeighbourMatcher:
    """A ``PairMatcher``: ``mutual_nearest_neighbours`` with a fixed ``min_cossim``, the
    similarity on ONNX Runtime (``OnnxSimilarity`` with ``threads`` intra-op threads)."""

    def __init__(self, min_cossim: float, threads: int = 0) -> None:
        if not -1.0 <= min_cossim < 1.0:
            raise ValueError(f"min_cossim must be in [-1, 1), got {min_cossim}")
        self.min_cossim = float(min_cossim)
        self._similarity = OnnxSimilarity(threads)

    def match(self, query: Features, tile: Features) -> RawMatches:
        return mutual_nearest_neighbours(
            query.descriptors, tile.descriptors, self.min_cossim, self._similarity
        )
