"""Adaptive LightGlue on ONNX Runtime: the transformer in steps, upstream's early exit (depth)
and point pruning (width) decided in numpy between steps. No PyTorch.

A *steps* engine (``EngineSpec`` option ``("pruning", "steps")``, variant ``<feature>-steps``) is
ONE ONNX file holding three disjoint sub-graphs; ONNX Runtime runs every node of a graph on
each call, so the sub-graph a call does not need is fed one dummy row (it costs microseconds):

    input stage   desc0 (1, M, Din), desc1 (1, N, Din)   -> proj0 (1, M, C), proj1 (1, N, C)
    layer stage   kpts0 (1, M, 2), kpts1 (1, N, 2) normalised, state0 (1, M, C),
                  state1 (1, N, C), layer (1,) int64      -> out0, out1 (1, M|N, C) after layer
                  ``layer``; confidence0/1 (M|N,) its token confidence (upstream
                  ``token_confidence[min(layer, L-2)]``); matchability0/1 (M|N,) its
                  ``log_assignment[layer].get_matchability``
    head          final0 (1, M, C), final1 (1, N, C), final_layer (1,) int64
                                                        -> matches0 (M,) int64, mscores0 (M,)
                  (``log_assignment[final_layer]`` then ``filter_matches`` before the threshold)

``AdaptiveLightGlue.match`` mirrors upstream ``LightGlue._forward`` (cvg/LightGlue, kornia) for one
pair on CPU (pruning from the first layer on): after each layer but the last, stop when the share
of confident tokens over the ``M + N`` input points exceeds ``depth_confidence``; otherwise keep
the points whose matchability exceeds ``1 - width_confidence`` or whose confidence is at most the
layer's threshold (points upstream would still refine), gather their rows and go on with smaller
tensors. ``-1`` disables either rule. Comparisons run in float32 as upstream's do.

One test of our own, the unmatchable-pair exit (``exit_matches`` > 0; off unless a strategy or
the configuration sets it): after layer ``exit_after`` the assignment head runs once on the kept
points, and a pair with fewer than ``exit_matches`` mutual matches of confidence above
``exit_confidence`` stops there with no matches: a candidate tile that shows another place (a
distractor) no longer runs the layers upstream's confidence exit would give it. A strategy turns
it on only after a measurement over every shipped flight (``scripts/early_exit_sweep.py``,
docs/decisions.md).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from c3_matcher.engines.lightglue_specs import UPSTREAM_DEPTH_CONFIDENCE, UPSTREAM_WIDTH_CONFIDENCE

__all__ = [
    "AdaptiveLightGlue",
    "AdaptiveResult",
    "confidence_threshold",
]

RunFn = Callable[[Mapping[str, NDArray[Any]]], Mapping[str, NDArray[Any]]]
"""Runs the steps graph on a full feed dict and returns its outputs by name."""


def confidence_threshold(layer_index: int, n_layers: int) -> np.float32:
    """Upstream's per-layer token-confidence threshold ``0.8 + 0.1 exp(-4 i / L)`` (float32)."""
    threshold = 0.8 + 0.1 * math.exp(-4.0 * layer_index / n_layers)
    return np.float32(min(max(threshold, 0.0), 1.0))


@dataclass(slots=True)
class AdaptiveResult:
    """One adaptive match: ``matches0`` (M,) index into set 1 or -1 and ``mscores0`` (M,) over
    the ORIGINAL set 0 (upstream's scatter back), ``layers`` run, points kept per layer,
    ``matched`` the confident mutual matches at the unmatchable-pair test (None: not tested)
    and ``unmatchable`` True when that test stopped the pair (no matches then)."""

    matches0: NDArray[np.int64]
    mscores0: NDArray[np.float32]
    layers: int
    kept0: list[int] = field(default_factory=list)
    kept1: list[int] = field(default_factory=list)
    matched: int | None = None
    unmatchable: bool = False


class AdaptiveLightGlue:
    """Drives a steps graph (``run``) for a LightGlue of ``n_layers`` layers."""

    def __init__(
        self,
        run: RunFn,
        *,
        n_layers: int,
        input_dim: int,
        descriptor_dim: int,
        depth_confidence: float = UPSTREAM_DEPTH_CONFIDENCE,
        width_confidence: float = UPSTREAM_WIDTH_CONFIDENCE,
        exit_matches: int = 0,
        exit_after: int = 1,
        exit_confidence: float = 0.3,
    ) -> None:
        if n_layers < 1:
            raise ValueError(f"n_layers must be >= 1, got {n_layers}")
        for name, value in (("depth", depth_confidence), ("width", width_confidence)):
            if not -1.0 <= value <= 1.0:
                raise ValueError(f"{name}_confidence must be in [-1, 1] (<= 0: off), got {value}")
        self._run = run
        self.n_layers = int(n_layers)
        self.input_dim = int(input_dim)
        self.descriptor_dim = int(descriptor_dim)
        self.depth_confidence = float(depth_confidence)
        self.width_confidence = float(width_confidence)
        if exit_matches < 0 or exit_after < 0 or not 0.0 <= exit_confidence < 1.0:
            raise ValueError(
                "exit_matches and exit_after must be >= 0 and exit_confidence in [0, 1), got "
                f"{exit_matches}, {exit_after}, {exit_confidence}"
            )
        self.exit_matches = int(exit_matches)
        self.exit_after = int(exit_after)
        self.exit_confidence = np.float32(exit_confidence)
        self._thresholds = [confidence_threshold(i, n_layers) for i in range(n_layers)]

    def _dummy(self, dim: int) -> NDArray[np.float32]:
        return np.zeros((1, 1, dim), np.float32)

    def _feeds(self, **given: NDArray[Any]) -> dict[str, NDArray[Any]]:
        c, d = self.descriptor_dim, self.input_dim
        feeds: dict[str, NDArray[Any]] = {
            "desc0": self._dummy(d),
            "desc1": self._dummy(d),
            "kpts0": np.zeros((1, 1, 2), np.float32),
            "kpts1": np.zeros((1, 1, 2), np.float32),
            "state0": self._dummy(c),
            "state1": self._dummy(c),
            "layer": np.zeros((1,), np.int64),
            "final0": self._dummy(c),
            "final1": self._dummy(c),
            "final_layer": np.zeros((1,), np.int64),
        }
        feeds.update(given)
        return feeds

    def match(
        self,
        kpts0: NDArray[np.float32],
        kpts1: NDArray[np.float32],
        desc0: NDArray[np.float32],
        desc1: NDArray[np.float32],
    ) -> AdaptiveResult:
        """Match normalised keypoints (K, 2) with descriptors (K, Din) of two images."""
        m, n = len(kpts0), len(kpts1)
        if m == 0 or n == 0:
            return AdaptiveResult(
                np.full((m,), -1, np.int64), np.zeros((m,), np.float32), 0, [m], [n]
            )
        out = self._run(
            self._feeds(
                desc0=np.ascontiguousarray(desc0, np.float32)[None],
                desc1=np.ascontiguousarray(desc1, np.float32)[None],
            )
        )
        side0 = _Side(kpts0, np.asarray(out["proj0"]))
        side1 = _Side(kpts1, np.asarray(out["proj1"]))
        layer, matched = 0, None
        for layer in range(self.n_layers):
            out = self._run(
                self._feeds(
                    kpts0=side0.kpts,
                    kpts1=side1.kpts,
                    state0=side0.state,
                    state1=side1.state,
                    layer=np.array([layer], np.int64),
                )
            )
            side0.state, side1.state = np.asarray(out["out0"]), np.asarray(out["out1"])
            if layer == self.n_layers - 1:
                break  # no exit test or pruning after the last layer (upstream)
            if self.exit_matches and layer == self.exit_after:
                matched = self._confident_matches(layer, side0, side1)
                if matched < self.exit_matches:
                    return _result(m, side0, side1, layer + 1, matched, unmatchable=True)
            if self._after_layer(layer, out, side0, side1) == "confident":
                break
            if not (len(side0.index) and len(side1.index)):
                break  # a side pruned to no point: nothing left to match (upstream stops too)
        result = _result(m, side0, side1, layer + 1, matched)
        if len(side0.index) and len(side1.index):
            out = self._run(
                self._feeds(
                    final0=side0.state,
                    final1=side1.state,
                    final_layer=np.array([layer], np.int64),
                )
            )
            sub_m0 = np.asarray(out["matches0"]).reshape(-1).astype(np.int64, copy=False)
            valid = sub_m0 > -1
            result.matches0[side0.index[valid]] = side1.index[sub_m0[valid]]
            result.mscores0[side0.index] = np.asarray(out["mscores0"], np.float32).reshape(-1)
        return result

    def _confident_matches(self, layer: int, side0: _Side, side1: _Side) -> int:
        """The mutual matches the assignment head gives after ``layer`` whose confidence
        exceeds ``exit_confidence``."""
        return int((self.mutual_scores(layer, side0, side1) > self.exit_confidence).sum())

    def mutual_scores(self, layer: int, side0: _Side, side1: _Side) -> NDArray[np.float32]:
        """The confidences of the mutual matches the assignment head gives after ``layer`` (one
        head call on the kept points)."""
        out = self._run(
            self._feeds(
                final0=side0.state, final1=side1.state, final_layer=np.array([layer], np.int64)
            )
        )
        matched = np.asarray(out["matches0"]).reshape(-1) > -1
        return np.asarray(out["mscores0"], np.float32).reshape(-1)[matched]

    def _after_layer(
        self, layer: int, out: Mapping[str, NDArray[Any]], side0: _Side, side1: _Side
    ) -> str:
        """Upstream's tests after ``layer`` (not the last): ``"confident"`` (early exit) or
        ``"go"``, having pruned both sides."""
        conf0 = np.asarray(out["confidence0"]).reshape(-1)
        conf1 = np.asarray(out["confidence1"]).reshape(-1)
        threshold = self._thresholds[layer]
        depth_on = self.depth_confidence > 0
        if depth_on:
            unconfident = np.float32((conf0 < threshold).sum() + (conf1 < threshold).sum())
            total = np.float32(side0.kept[0] + side1.kept[0])
            if np.float32(1.0) - unconfident / total > np.float32(self.depth_confidence):
                return "confident"
        if self.width_confidence > 0:
            min_match = np.float32(1.0 - self.width_confidence)
            keep0 = np.asarray(out["matchability0"]).reshape(-1) > min_match
            keep1 = np.asarray(out["matchability1"]).reshape(-1) > min_match
            if depth_on:  # upstream: low-confidence points are never pruned
                keep0 |= conf0 <= threshold
                keep1 |= conf1 <= threshold
            side0.prune(keep0)
            side1.prune(keep1)
        return "go"


class _Side:
    """One image's working set during an adaptive match: its kept points' keypoints (1, K, 2),
    transformer state (1, K, C) and original indices, points kept per layer."""

    def __init__(self, kpts: NDArray[np.float32], state: NDArray[np.float32]) -> None:
        self.kpts = np.ascontiguousarray(kpts, np.float32)[None]
        self.state = state
        self.index = np.arange(len(kpts))
        self.kept = [len(kpts)]

    def prune(self, keep: NDArray[np.bool_]) -> None:
        self.index = self.index[keep]
        self.state = np.ascontiguousarray(self.state[:, keep])
        self.kpts = np.ascontiguousarray(self.kpts[:, keep])
        self.kept.append(len(self.index))


def _result(
    m: int,
    side0: _Side,
    side1: _Side,
    layers: int,
    matched: int | None = None,
    *,
    unmatchable: bool = False,
) -> AdaptiveResult:
    """A result with no matches yet over the ``m`` points of image 0."""
    return AdaptiveResult(
        np.full((m,), -1, np.int64),
        np.zeros((m,), np.float32),
        layers,
        side0.kept,
        side1.kept,
        matched,
        unmatchable,
    )
