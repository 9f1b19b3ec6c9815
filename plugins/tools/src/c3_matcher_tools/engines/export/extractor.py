"""Export and verification pieces every keypoint-extractor exporter shares (build time: imports
torch). The extractors (DISK, ALIKED, XFeat) declare the same I/O (``extractor_spec``): inputs
``image`` (1, 3, H, W) and ``mask`` (1, 1, H, W), H and W multiples of the spec's
``size_multiple``; outputs ``keypoints``, ``keypoint_scores``, ``descriptors`` (top-K rows, score
0 on padding rows)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import onnxruntime as ort
import torch
from numpy.typing import NDArray
from torch import nn
from torch.nn import functional as nnf

from c3_matcher.engines.runtime import SessionSettings
from c3_matcher_tools.engines.export import ExportRequest
from c3_matcher_tools.engines.export.onnx_export import export_module

__all__ = [
    "TwoStageInstanceNorm",
    "compare_keypoint_sets",
    "export_extractor",
    "strict_maxima_candidates",
    "verification_inputs",
]


class TwoStageInstanceNorm(nn.Module):
    """InstanceNorm2d (no affine) with the mean and variance reduced over W, then H (one
    reduction over the flattened H*W axis loses float32 precision in ONNX Runtime)."""

    def __init__(self, eps: float) -> None:
        super().__init__()
        self.eps = eps

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        mean = x.mean(dim=3, keepdim=True).mean(dim=2, keepdim=True)
        centred = x - mean
        var = (centred * centred).mean(dim=3, keepdim=True).mean(dim=2, keepdim=True)
        return centred / torch.sqrt(var + self.eps)


def strict_maxima_candidates(heat: torch.Tensor) -> torch.Tensor:
    """``heat`` (1, H, W) where it is a strict 5x5 local maximum scoring > 0 and at least 2 px
    from the border, else 0: 24 shifted comparisons (no symbolic-size arithmetic)."""
    centre = heat[:, 2:-2, 2:-2]
    shifts = [slice(0, -4), slice(1, -3), slice(2, -2), slice(3, -1), slice(4, None)]
    strict: torch.Tensor | None = None
    for i, rows in enumerate(shifts):
        for j, cols in enumerate(shifts):
            if i == 2 and j == 2:
                continue
            greater = centre > heat[:, rows, cols]
            strict = greater if strict is None else strict & greater
    assert strict is not None
    is_max = nnf.pad(strict.to(heat.dtype), (2, 2, 2, 2)) > 0.5  # border never a maximum
    return torch.where(is_max & (heat > 0), heat, torch.zeros_like(heat))


def verification_inputs(
    rgb: NDArray[np.uint8], sizes: Sequence[tuple[int, int]]
) -> list[tuple[str, NDArray[np.uint8]]]:
    """Real inputs at every (width, height) of ``sizes``: centre crops where the image is large
    enough, otherwise a bilinear resize."""
    import cv2

    inputs: list[tuple[str, NDArray[np.uint8]]] = []
    height, width = rgb.shape[:2]
    for w, h in sizes:
        if w <= width and h <= height:
            top, left = (height - h) // 2, (width - w) // 2
            crop = rgb[top : top + h, left : left + w]
            inputs.append((f"crop {w}x{h}", np.ascontiguousarray(crop)))
        else:
            resized = cv2.resize(rgb, (w, h), interpolation=cv2.INTER_LINEAR)
            inputs.append((f"resize {w}x{h}", np.ascontiguousarray(resized)))
    return inputs


def export_extractor(
    request: ExportRequest, module: nn.Module, *, multiple: int, max_blocks: int, label: str
) -> ort.InferenceSession:
    """Export ``module`` with the extractor I/O (H and W ``multiple`` x 2..``max_blocks``) to
    ``request.output_path`` and open it on the CPU for verification."""
    rows = torch.export.Dim(f"height{multiple}", min=2, max=max_blocks)
    cols = torch.export.Dim(f"width{multiple}", min=2, max=max_blocks)
    request.log(f"exporting {label} (opset {request.spec.opset})")
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
    return ort.InferenceSession(
        str(request.output_path),
        sess_options=SessionSettings().build(),
        providers=["CPUExecutionProvider"],
    )


def compare_keypoint_sets(
    name: str,
    got: tuple[NDArray[Any], NDArray[Any], NDArray[Any]],
    reference: tuple[NDArray[Any], NDArray[Any], NDArray[Any]],
    tolerances: Mapping[str, float],
    failures: list[str],
    *,
    relative_scores: bool = False,
) -> dict[str, Any]:
    """Figures comparing (keypoints (N, 2), scores (N,), descriptors (N, D)) with a reference
    whose keypoints sit on whole pixels: the (x, y) sets must be identical, then scores and
    descriptors (paired in raster order) within ``tolerances``; appends to ``failures``."""
    kp, sc, de = got
    rk, rs, rd = reference
    mine = {(float(x), float(y)) for x, y in kp}
    theirs = {(float(x), float(y)) for x, y in rk}
    mismatch = len(mine ^ theirs)
    check: dict[str, Any] = {
        "input": name,
        "keypoints": len(kp),
        "reference_keypoints": len(rk),
        "keypoints_mismatch": mismatch,
    }
    if mismatch == 0 and len(kp) == len(rk):
        order = np.lexsort((kp[:, 0], kp[:, 1]))
        ref_order = np.lexsort((rk[:, 0], rk[:, 1]))
        score_err = np.abs(sc[order] - rs[ref_order])
        check["scores_max_abs"] = float(score_err.max(initial=0.0))
        if relative_scores:
            check["scores_max_rel"] = float((score_err / np.abs(rs[ref_order])).max(initial=0.0))
        check["descriptors_max_abs"] = float(np.abs(de[order] - rd[ref_order]).max(initial=0.0))
        for key in ("scores_max_abs", "descriptors_max_abs"):
            if check[key] > tolerances[key]:
                failures.append(f"{name}: {key} {check[key]:.3g} > {tolerances[key]:.3g}")
    else:
        failures.append(f"{name}: {mismatch} keypoints differ ({len(kp)} vs reference {len(rk)})")
    return check
