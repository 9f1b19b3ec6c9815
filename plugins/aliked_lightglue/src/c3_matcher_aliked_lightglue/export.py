"""The ALIKED+LightGlue plugin's build time: the export rewrite of ALIKED, its exporters and
PyTorch reference (imports torch and kornia).

``AlikedForExport`` computes exactly what kornia's ``ALIKED`` computes in top-K mode
(``detection_threshold <= 0``, ``max_num_keypoints = K``) with a mask multiplied into the score
map (``forward_laf``'s rule), in a single graph the dynamo exporter can write and ONNX Runtime can
run without custom ops:

- backbone and heads: the reference's own modules (deep-copied), except each
  ``DeformableConv2d``, replaced by ``GridSampleDeformConv2d`` (GridSample + MatMul); no input
  padder: H and W must be multiples of 32 (the backbone pools by 2 * 4 * 4 and upsamples by 32),
  so the reference's replicate padding is a no-op there;
- DKD: strict 5x5 local maxima of ``score * mask`` scoring > 0, at least 2 px (the NMS radius)
  from the border, by 24 shifted comparisons; top-K over the flattened map padded with K zeros (so
  images with fewer than K maxima work; padding rows get score 0); soft-argmax refinement over
  each maximum's 5x5 window (temperature 0.1) gathered by flat index; the score is the masked map
  read bilinearly at the refined position (``align_corners=True``);
- SDDH: the 3x3 feature patch at each keypoint (the reference's truncation and clamping of the
  patch corner), its offset network, 16 deformable bilinear samples, ``sf_conv`` + SELU and the
  aggregation ``einsum('ncp,pcd->nd')`` as one MatMul, L2-normalised. The feature map is not
  normalised densely: the pixels the patches and samples read are gathered (rows of the
  pixel-major map) and normalised alone, and each bilinear sample is its four taps weighted as
  ``grid_sample`` weights them (ONNX Runtime's GridSample kernel is scalar, and the dense
  normalisation of a 128-channel full-resolution map is work no descriptor reads).

Outputs: ``keypoints`` (K, 2) (x, y) px (``wh * (k + 1) / 2`` of the normalised position, as the
reference), ``keypoint_scores`` (K,) in (0, 1), 0 on padding rows, best NMS score first,
``descriptors`` (K, D) L2-normalised. Sizes enter as tensors (``cumsum`` grids), never as Python
arithmetic on symbolic sizes.

``AlikedLightGlueReference`` is the bench's PyTorch reference (hook
``c3_matcher_reference_backend``): kornia's ALIKED (top-K mode, ``max_keypoints``, the valid mask
multiplied into the score map through ``forward_laf``) on every image and kornia's LightGlue with
its upstream adaptive depth and width ON (depth_confidence 0.95, width_confidence 0.99), the same
weights as the engines.
"""

from __future__ import annotations

import copy
import importlib.metadata
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray
from torch import nn
from torch.nn import functional as nnf

from c3_matcher.config import C3Settings
from c3_matcher.features import Features
from c3_matcher.prepared import PreparedImage
from c3_matcher_aliked_lightglue.deform_conv import GridSampleDeformConv2d
from c3_matcher_aliked_lightglue.engines import (
    ALIKED_DESCRIPTOR_DIM,
    ALIKED_N16_SPEC,
    ALIKED_SIZE_MULTIPLE,
    ALIKED_SPECS,
    ALIKED_TOLERANCES,
    ALIKED_TOP_K,
    ALIKED_VERIFICATION_SIZES,
    LIGHTGLUE_ALIKED_SPEC,
)
from c3_matcher_aliked_lightglue.matcher import EXTRACT_PHASE, AlikedLightGlueOptions
from c3_matcher_tools.engines.export import (
    ExportReport,
    ExportRequest,
    VerificationImage,
    tolerance_failures,
)
from c3_matcher_tools.engines.export.extractor import (
    ExtractorCase,
    KeypointSet,
    export_and_verify_extractor,
    extractor_exporter,
    strict_maxima_candidates,
    verification_inputs,
)
from c3_matcher_tools.engines.export.lightglue_steps import lightglue_exporters
from c3_matcher_tools.engines.export.reference import PyTorchReference, load_upstream_lightglue

__all__ = [
    "AlikedForExport",
    "AlikedLightGlueReference",
    "aliked_features_fn",
    "aliked_reference_features",
    "build_aliked_export_module",
    "compare_features",
    "export_aliked",
    "export_lightglue_aliked",
    "export_lightglue_aliked_steps",
    "load_aliked_reference",
]


def load_aliked_reference(weights_path: Path, model_name: str, top_k: int) -> Any:
    """kornia ``ALIKED(model_name)`` in top-K mode (``max_num_keypoints=top_k``,
    ``detection_threshold=0``) with the state dict at ``weights_path``, eval mode.
    ``RuntimeError`` if a learned parameter or buffer is missing or unexpected (the DKD's
    constant ``hw_grid`` buffer is not in upstream checkpoints)."""
    from kornia.feature import ALIKED

    state = torch.load(str(weights_path), map_location="cpu", weights_only=True)
    model = ALIKED(model_name, max_num_keypoints=top_k, detection_threshold=0.0, nms_radius=2)
    incompatible = model.load_state_dict(state, strict=False)
    missing = [k for k in incompatible.missing_keys if k != "dkd.hw_grid"]
    if missing or incompatible.unexpected_keys:
        raise RuntimeError(
            f"ALIKED weights {weights_path}: missing {missing}, "
            f"unexpected {list(incompatible.unexpected_keys)}"
        )
    return model.eval()


def _swap_deform_convs(module: nn.Module) -> int:
    """Replace every ``DeformableConv2d`` below ``module`` in place; returns how many."""
    count = 0
    for name, child in module.named_children():
        if type(child).__name__ == "DeformableConv2d":
            setattr(module, name, GridSampleDeformConv2d.from_module(child))
            count += 1
        else:
            count += _swap_deform_convs(child)
    return count


class AlikedForExport(nn.Module):
    """ALIKED (top-K mode, masked score map) for export; see the module docstring."""

    hw_grid: torch.Tensor  # (25, 2) (dx, dy) of the 5x5 window, the reference DKD's buffer

    def __init__(self, reference: Any, top_k: int) -> None:
        super().__init__()
        net = copy.deepcopy(reference)
        if _swap_deform_convs(net) == 0:
            raise ValueError("the reference has no DeformableConv2d to rewrite")
        if net.nms_radius != 2 or net.dkd.kernel_size != 5:
            raise ValueError("the export handles nms_radius 2 (5x5 window) only")
        if net.desc_head.mask or net.desc_head.conv2d or net.desc_head.kernel_size != 3:
            raise ValueError("the export handles SDDH with kernel 3, no mask, no conv2d only")
        self.net = net
        self.k = int(top_k)
        self.temperature = float(net.dkd.temperature)
        self.register_buffer("hw_grid", net.dkd.hw_grid.clone(), persistent=False)

    def dense_maps(self, image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(feature_map (1, D, H, W) before its L2 normalisation, score_map (1, 1, H, W))``:
        only the keypoints' samples of the feature map are read, so they alone are normalised
        (``describe``)."""
        n = self.net
        x1 = n.block1(image)
        x2 = n.block2(n.pool2(x1))
        x3 = n.block3(n.pool4(x2))
        x4 = n.block4(n.pool4(x3))
        x1 = n.gate(n.conv1(x1))
        x2 = n.gate(n.conv2(x2))
        x3 = n.gate(n.conv3(x3))
        x4 = n.gate(n.conv4(x4))
        x1234 = torch.cat([x1, n.upsample2(x2), n.upsample8(x3), n.upsample32(x4)], dim=1)
        score_map = torch.sigmoid(n.score_head(x1234))
        return x1234, score_map

    def forward(
        self, image: torch.Tensor, mask: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        feature_map, score_map = self.dense_maps(image)
        scores = score_map * mask  # (1, 1, H, W)
        heat = scores[0]  # (1, H, W)
        ones = torch.ones_like(heat[0])
        xs = torch.cumsum(ones, 1) - 1  # (H, W) column index
        ys = torch.cumsum(ones, 0) - 1
        width = xs[0, -1] + 1  # 0-d float tensors
        height = ys[-1, 0] + 1
        wh = torch.stack([width - 1, height - 1])  # (2,)

        # Strict 5x5 maxima away from the 2 px border, scoring > 0; top-K of them.
        candidates = strict_maxima_candidates(heat)
        pad = torch.zeros(self.k, dtype=heat.dtype)
        top, index = torch.topk(torch.cat([candidates.reshape(-1), pad]), self.k, sorted=True)
        valid = top > 0
        two = torch.full((self.k,), 2.0, dtype=heat.dtype)  # padding rows sit at (2, 2)
        x0 = torch.cat([xs.reshape(-1), two]).gather(0, index)
        y0 = torch.cat([ys.reshape(-1), two]).gather(0, index)

        # Soft-argmax refinement over the 5x5 window (the reference's unfold order).
        flat_scores = heat.reshape(-1)
        window = torch.arange(-2, 3, dtype=heat.dtype)
        dy = window.repeat_interleave(5)  # (25,) row offset of window entry k = 5 * i + j
        dx = window.repeat(5)
        patch_index = (y0[:, None] + dy) * width + (x0[:, None] + dx)
        patch = flat_scores[patch_index.to(torch.int64)]  # (K, 25)
        max_v = patch.max(dim=1).values[:, None]
        x_exp = ((patch - max_v) / self.temperature).exp()
        x_sum = x_exp.sum(dim=1, keepdim=True)
        residual = x_exp @ self.hw_grid / x_sum  # (K, 2) (dx, dy)
        kp_norm = (torch.stack([x0, y0], -1) + residual) / wh * 2 - 1  # (K, 2) in [-1, 1]
        kp_score = nnf.grid_sample(
            scores, kp_norm.reshape(1, 1, -1, 2), mode="bilinear", align_corners=True
        )[0, 0, 0]
        kp_score = torch.where(valid, kp_score, torch.zeros_like(kp_score))

        descriptors = self.describe(feature_map[0], kp_norm, wh, width, height)
        keypoints = wh * (kp_norm + 1) / 2.0
        return keypoints, kp_score, descriptors

    def describe(
        self,
        fmap: torch.Tensor,
        kp_norm: torch.Tensor,
        wh: torch.Tensor,
        width: torch.Tensor,
        height: torch.Tensor,
    ) -> torch.Tensor:
        """SDDH descriptors (K, D) of the keypoints ``kp_norm`` (K, 2) in [-1, 1] on the feature
        map ``fmap`` (D, H, W) before normalisation; ``wh`` = (W - 1, H - 1), ``width``/``height``
        0-d tensors. The reference normalises every pixel of the map, then reads 3x3 patches and
        16 bilinear samples per keypoint; here the pixels those read are gathered and normalised
        alone (the same values: normalisation is per pixel), and the bilinear samples are four
        gathered taps weighted as ``grid_sample`` weights them (ONNX Runtime's GridSample kernel
        is scalar)."""
        head = self.net.desc_head
        dim = fmap.shape[0]
        n_pos = int(head.n_pos)
        kp_wh = (kp_norm / 2 + 0.5) * wh  # (K, 2) px
        # The reference's get_patches: corner = long(long(kp) - ps / 2 + 1), clamped.
        corner = (kp_wh.to(torch.int64).to(kp_wh.dtype) - 0.5).to(torch.int64)
        w_long = width.to(torch.int64)
        h_long = height.to(torch.int64)
        zero = torch.zeros_like(w_long)
        cx = torch.minimum(torch.maximum(corner[:, 0], zero), w_long - 4)
        cy = torch.minimum(torch.maximum(corner[:, 1], zero), h_long - 4)
        offs = torch.arange(3, dtype=torch.int64)
        rows = (cy[:, None, None] + offs[None, :, None]) * w_long  # (K, 3, 1)
        cols = cx[:, None, None] + offs[None, None, :]  # (K, 1, 3)
        flat = (rows + cols).reshape(-1)  # (K * 9,) row-major 3x3 patches
        pixels = fmap.reshape(dim, -1).transpose(0, 1)  # (H * W, D): a pixel is one row
        patches = _unit_pixels(pixels, flat).reshape(-1, 3, 3, dim).permute(0, 3, 1, 2)

        limit = torch.maximum(width, height) / 4.0
        offset = head.offset_conv(patches)  # (K, 2 * n_pos, 1, 1)
        offset = torch.minimum(torch.maximum(offset, -limit), limit)
        offset = offset[:, :, 0, 0].reshape(-1, 2, n_pos).permute(0, 2, 1)  # (K, n_pos, 2)
        pos = kp_wh.unsqueeze(1) + offset
        pos = 2.0 * pos / wh[None] - 1
        features = _bilinear(pixels, pos.reshape(-1, 2), width, height)  # (K * n_pos, D)
        features = features.reshape(-1, n_pos, dim, 1).permute(0, 2, 1, 3)  # (K, D, n_pos, 1)
        features = nnf.selu(head.sf_conv(features)).squeeze(-1)  # (K, D, n_pos)
        agg = head.agg_weights  # (n_pos, D, D_out)
        flat_features = features.permute(0, 2, 1).reshape(features.shape[0], -1)
        descs = flat_features @ agg.reshape(-1, agg.shape[-1])
        return nnf.normalize(descs, p=2.0, dim=1)


def _unit_pixels(pixels: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """Rows ``index`` (N,) of ``pixels`` (H * W, D), each L2-normalised -> (N, D)."""
    return nnf.normalize(pixels.index_select(0, index), p=2.0, dim=1)


def _bilinear(
    pixels: torch.Tensor, grid: torch.Tensor, width: torch.Tensor, height: torch.Tensor
) -> torch.Tensor:
    """``grid_sample(normalised map, grid, "bilinear", align_corners=True)`` (zero padding) at
    the N points ``grid`` (N, 2) in [-1, 1] of the (H * W, D) map ``pixels`` (normalised per
    pixel as read) -> (N, D); taps summed nw, ne, sw, se with ``grid_sample``'s weights."""
    x = (grid[:, 0] + 1) / 2 * (width - 1)
    y = (grid[:, 1] + 1) / 2 * (height - 1)
    x0, y0 = torch.floor(x), torch.floor(y)
    x1, y1 = x0 + 1, y0 + 1
    total = torch.zeros_like(pixels[:1]) * x[:, None]  # (N, D) zeros
    for tx, ty, weight in (
        (x0, y0, (x1 - x) * (y1 - y)),
        (x1, y0, (x - x0) * (y1 - y)),
        (x0, y1, (x1 - x) * (y - y0)),
        (x1, y1, (x - x0) * (y - y0)),
    ):
        inside = (tx >= 0) & (tx <= width - 1) & (ty >= 0) & (ty <= height - 1)
        cx = torch.minimum(torch.maximum(tx, torch.zeros_like(tx)), width - 1)
        cy = torch.minimum(torch.maximum(ty, torch.zeros_like(ty)), height - 1)
        index = (cy * width + cx).to(torch.int64)
        total = total + _unit_pixels(pixels, index) * (weight * inside.to(weight.dtype))[:, None]
    return total


def build_aliked_export_module(reference: Any, top_k: int) -> AlikedForExport:
    """The export rewrite of a kornia ``ALIKED``; shares no state with ``reference``."""
    return AlikedForExport(reference, top_k).eval()


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
    keys = ("keypoints_max_abs_px", "scores_max_abs", "descriptors_max_abs")
    present = [key for key in keys if key in figures]  # none when no keypoint was paired
    return failures + tolerance_failures(label, figures, ALIKED_TOLERANCES, present)


def _paired_check(
    name: str, got: KeypointSet, ref: KeypointSet, failures: list[str]
) -> dict[str, Any]:
    """The kit's ``compare`` for sub-pixel keypoints: ``compare_features`` pairing."""
    figures = compare_features(got, ref)
    failures.extend(_check(figures, name))
    return {"input": name, **figures}


def _cases(image: VerificationImage) -> list[ExtractorCase]:
    """Every ``ALIKED_VERIFICATION_SIZES`` input (full mask), then the second one masked."""
    inputs = verification_inputs(image.rgb, ALIKED_VERIFICATION_SIZES)
    masked_label, masked_rgb = inputs[1]
    return [
        *(ExtractorCase(label, rgb) for label, rgb in inputs),
        ExtractorCase(f"{masked_label} masked", masked_rgb, _partial_mask(*masked_rgb.shape[:2])),
    ]


@extractor_exporter
def export_aliked(request: ExportRequest, top_k: int) -> ExportReport:
    """Export one ALIKED variant and verify it against kornia's ALIKED (same weights, top-K
    mode) on real imagery at every ``ALIKED_VERIFICATION_SIZES`` plus one masked input."""
    model_name = str(request.spec.option("model_name"))
    reference = load_aliked_reference(request.weights_path, model_name, top_k)
    return export_and_verify_extractor(
        request,
        build_aliked_export_module(reference, top_k),
        label=f"{model_name} (top-K {top_k})",
        max_blocks=64,
        reference=lambda _feeds, case: aliked_reference_features(reference, case.rgb, case.mask),
        reference_name=f"kornia {importlib.metadata.version('kornia')} ALIKED {model_name} "
        f"(same state dict, top-K {top_k})",
        tolerances=ALIKED_TOLERANCES,
        sizes=ALIKED_VERIFICATION_SIZES,
        compare=_paired_check,
        cases=_cases,
        notes={"deform_conv": "GridSample (bilinear, zeros, align_corners) + MatMul"},
    )


def aliked_features_fn() -> Callable[
    [NDArray[np.uint8], int], tuple[NDArray[np.float32], NDArray[np.float32]]
]:
    """The LightGlue exporters' ``features_fn``: kornia ALIKED n16 (the engine's weights), one
    reference per keypoint count."""
    references: dict[int, Any] = {}

    def features(rgb: NDArray[np.uint8], n: int) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
        if n not in references:
            references[n] = load_aliked_reference(
                ALIKED_N16_SPEC.weights.resolve(), "aliked-n16", n
            )
        kp, _, de = aliked_reference_features(references[n], rgb)
        return kp, de

    return features


export_lightglue_aliked, export_lightglue_aliked_steps = lightglue_exporters(
    "aliked", aliked_features_fn
)
"""The exporters of ``lightglue/aliked`` and ``lightglue/aliked-steps`` (the kit's, verified on
real kornia-ALIKED n16 features)."""


class AlikedLightGlueReference(PyTorchReference):
    """FeatureBackend over kornia's ALIKED and LightGlue (PyTorch, CPU)."""

    label = "aliked_lightglue[pytorch]"
    extract_phase = EXTRACT_PHASE

    def __init__(self, settings: C3Settings) -> None:
        super().__init__(
            settings,
            ALIKED_SIZE_MULTIPLE,
            load_upstream_lightglue(
                LIGHTGLUE_ALIKED_SPEC.weights.resolve(), input_dim=ALIKED_DESCRIPTOR_DIM
            ),
        )
        raw = settings.matcher.options.get("aliked_lightglue", {})
        variant = AlikedLightGlueOptions.model_validate(raw).variant
        self._aliked = load_aliked_reference(
            ALIKED_SPECS[variant].weights.resolve(),
            f"aliked-{variant}",
            settings.matcher.max_keypoints or ALIKED_TOP_K,  # None: the strategy's default
        )

    def extract(self, image: PreparedImage) -> Features:
        kp, scores, desc = aliked_reference_features(self._aliked, image.image, image.valid)
        order = np.argsort(-scores, kind="stable")
        return Features(kp[order], desc[order], scores[order], image.engine_size)
