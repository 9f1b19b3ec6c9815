"""The DISK+LightGlue plugin's build time: exporters and PyTorch references (imports torch and
kornia inside its functions, at ``c3-matcher engines build`` and in the reference backend only).
The graphs it writes are described in ``c3_matcher_disk_lightglue.engines``."""

from __future__ import annotations

import importlib.metadata
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from c3_matcher_disk_lightglue.engines import (
    DISK_DESCRIPTOR_DIM,
    DISK_SPEC,
    DISK_TOLERANCES,
    DISK_TOP_K,
    DISK_VERIFICATION_SIZES,
)

if TYPE_CHECKING:
    from c3_matcher_tools.engines.export import ExportReport, ExportRequest

__all__ = [
    "build_disk_export_module",
    "disk_reference_features",
    "export_disk",
    "export_lightglue_disk",
    "load_disk_reference",
]


def load_disk_reference(weights_path: Any) -> Any:
    """kornia ``DISK`` with the ``extractor`` state dict of ``weights_path`` (eval mode)."""
    import torch
    from kornia.feature import DISK

    state = torch.load(str(weights_path), map_location="cpu", weights_only=True)
    model = DISK(desc_dim=DISK_DESCRIPTOR_DIM)
    model.load_state_dict(state.get("extractor", state))
    return model.eval()


def build_disk_export_module(reference: Any, top_k: int = DISK_TOP_K) -> Any:
    """The export rewrite of a kornia ``DISK`` (see the module docstring); shares no state with
    ``reference`` (its U-Net is deep-copied before the instance norms are swapped)."""
    import copy

    import torch
    from torch import nn
    from torch.nn import functional as nnf

    class TwoStageInstanceNorm(nn.Module):
        """InstanceNorm2d (no affine) with the mean and variance reduced over W, then H."""

        def __init__(self, eps: float) -> None:
            super().__init__()
            self.eps = eps

        def forward(self, x: torch.Tensor) -> torch.Tensor:
            mean = x.mean(dim=3, keepdim=True).mean(dim=2, keepdim=True)
            centred = x - mean
            var = (centred * centred).mean(dim=3, keepdim=True).mean(dim=2, keepdim=True)
            return centred / torch.sqrt(var + self.eps)

    def swap_norms(module: nn.Module) -> None:
        for name, child in module.named_children():
            if isinstance(child, nn.InstanceNorm2d):
                if child.affine or child.track_running_stats:
                    raise ValueError("DISK export expects InstanceNorm2d without affine/stats")
                setattr(module, name, TwoStageInstanceNorm(child.eps))
            else:
                swap_norms(child)

    class DiskForExport(nn.Module):
        def __init__(self, unet: nn.Module, k: int, dim: int) -> None:
            super().__init__()
            self.unet = unet
            self.k = k
            self.dim = dim

        def forward(
            self, image: torch.Tensor, mask: torch.Tensor
        ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
            out = self.unet(image)
            desc = out[0, : self.dim]  # (D, H, W)
            heat = out[0, self.dim :] * mask[0]  # (1, H, W)
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
            candidates = torch.where(is_max & (heat > 0), heat, torch.zeros_like(heat))
            ones = torch.ones_like(heat[0])
            xs = torch.cumsum(ones, 1) - 1
            ys = torch.cumsum(ones, 0) - 1
            pad = torch.zeros(self.k, dtype=heat.dtype)
            scores, index = torch.topk(
                torch.cat([candidates.reshape(-1), pad]), self.k, sorted=True
            )
            x = torch.cat([xs.reshape(-1), pad]).gather(0, index)
            y = torch.cat([ys.reshape(-1), pad]).gather(0, index)
            dense = torch.cat([desc.reshape(self.dim, -1), torch.zeros(self.dim, self.k)], 1)
            descriptors = nnf.normalize(dense.index_select(1, index).transpose(0, 1), dim=-1)
            return torch.stack([x, y], -1), scores, descriptors

    unet = copy.deepcopy(reference.unet)
    swap_norms(unet)
    return DiskForExport(unet, top_k, reference.desc_dim).eval()


def _verification_inputs(rgb: NDArray[np.uint8]) -> list[tuple[str, NDArray[np.uint8]]]:
    """Real inputs at ``DISK_VERIFICATION_SIZES``: crops where the image is large enough,
    otherwise a bilinear resize."""
    import cv2

    inputs: list[tuple[str, NDArray[np.uint8]]] = []
    height, width = rgb.shape[:2]
    for w, h in DISK_VERIFICATION_SIZES:
        if w <= width and h <= height:
            top, left = (height - h) // 2, (width - w) // 2
            crop = rgb[top : top + h, left : left + w]
            inputs.append((f"crop {w}x{h}", np.ascontiguousarray(crop)))
        else:
            resized = cv2.resize(rgb, (w, h), interpolation=cv2.INTER_LINEAR)
            inputs.append((f"resize {w}x{h}", np.ascontiguousarray(resized)))
    return inputs


def export_disk(request: ExportRequest) -> ExportReport:
    """Export DISK and verify it against kornia's DISK (same weights) on real imagery at every
    ``DISK_VERIFICATION_SIZES``: identical keypoint sets, scores and descriptors within
    ``DISK_TOLERANCES``."""
    import onnxruntime as ort
    import torch

    from c3_matcher.engines.extract import image_to_feeds
    from c3_matcher.engines.runtime import SessionSettings
    from c3_matcher_tools.engines.export import ExportReport
    from c3_matcher_tools.engines.export.onnx_export import export_module

    torch.set_grad_enabled(False)
    top_k = int(request.spec.option("top_k"))
    reference = load_disk_reference(request.weights_path)
    module = build_disk_export_module(reference, top_k)
    height16 = torch.export.Dim("height16", min=2, max=1024)
    width16 = torch.export.Dim("width16", min=2, max=1024)
    request.log(f"exporting DISK (top-K {top_k}, opset {request.spec.opset})")
    export_module(
        module,
        (torch.rand(1, 3, 256, 320), torch.ones(1, 1, 256, 320)),
        request.output_path,
        input_names=["image", "mask"],
        output_names=["keypoints", "keypoint_scores", "descriptors"],
        dynamic_shapes={
            "image": {2: 16 * height16, 3: 16 * width16},
            "mask": {2: 16 * height16, 3: 16 * width16},
        },
        opset=request.spec.opset,
    )
    request.log("verifying DISK against kornia on real imagery")
    session = ort.InferenceSession(
        str(request.output_path),
        sess_options=SessionSettings().build(),
        providers=["CPUExecutionProvider"],
    )
    checks: list[dict[str, Any]] = []
    failures: list[str] = []
    for image in request.images:
        for label, rgb in _verification_inputs(image.rgb):
            feeds = image_to_feeds(rgb, np.ones(rgb.shape[:2], dtype=bool))
            kp, sc, de = session.run(None, feeds)
            keep = sc > 0
            kp, sc, de = kp[keep], sc[keep], de[keep]
            ref = reference(torch.from_numpy(feeds["image"]), n=top_k)[0]
            rk = ref.keypoints.numpy()
            rs = ref.detection_scores.numpy()
            rd = ref.descriptors.numpy()
            mine = {(float(x), float(y)) for x, y in kp}
            theirs = {(float(x), float(y)) for x, y in rk}
            mismatch = len(mine ^ theirs)
            check: dict[str, Any] = {
                "input": f"{image.name}:{label}",
                "keypoints": len(kp),
                "reference_keypoints": len(rk),
                "keypoints_mismatch": mismatch,
            }
            if mismatch == 0 and len(kp) == len(rk):
                order = np.lexsort((kp[:, 0], kp[:, 1]))
                ref_order = np.lexsort((rk[:, 0], rk[:, 1]))
                check["scores_max_abs"] = float(np.abs(sc[order] - rs[ref_order]).max())
                check["scores_max_rel"] = float(
                    (np.abs(sc[order] - rs[ref_order]) / np.abs(rs[ref_order])).max()
                )
                check["descriptors_max_abs"] = float(np.abs(de[order] - rd[ref_order]).max())
                for key in ("scores_max_abs", "descriptors_max_abs"):
                    if check[key] > DISK_TOLERANCES[key]:
                        failures.append(
                            f"{check['input']}: {key} {check[key]:.3g} > {DISK_TOLERANCES[key]:.3g}"
                        )
            else:
                failures.append(
                    f"{check['input']}: {mismatch} keypoints differ "
                    f"({len(kp)} vs reference {len(rk)})"
                )
            checks.append(check)
            request.log(f"  {check}")
    return ExportReport(
        passed=not failures and bool(checks),
        reference=f"kornia {importlib.metadata.version('kornia')} DISK (same state dict)",
        tolerances=DISK_TOLERANCES,
        checks=checks,
        failures=tuple(failures) if checks else ("no verification input was run",),
    )


def disk_reference_features(
    reference: Any, rgb: NDArray[np.uint8], max_keypoints: int
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Keypoints (K, 2) px and descriptors (K, 128) of kornia's DISK (``n=max_keypoints``)."""
    import torch

    from c3_matcher.engines.extract import image_to_feeds

    feeds = image_to_feeds(rgb, np.ones(rgb.shape[:2], dtype=bool))
    with torch.no_grad():
        feats = reference(torch.from_numpy(feeds["image"]), n=max_keypoints)[0]
    return (
        np.ascontiguousarray(feats.keypoints.numpy(), dtype=np.float32),
        np.ascontiguousarray(feats.descriptors.numpy(), dtype=np.float32),
    )


def export_lightglue_disk(request: ExportRequest) -> ExportReport:
    """Export LightGlue for DISK and verify it on real kornia-DISK features (core's shared
    ``export_lightglue``)."""
    from c3_matcher_tools.engines.export.lightglue import export_lightglue

    disk = load_disk_reference(DISK_SPEC.weights.resolve())
    return export_lightglue(
        request,
        features_fn=lambda rgb, n: disk_reference_features(disk, rgb, n),
        input_dim=int(request.spec.option("input_dim")),
        feature_type="disk",
    )
