"""The export rewrite of upstream XFeat (build time only: imports torch at module level, so it is
imported only by ``c3_matcher_xfeat.export.build_xfeat_export_module``). The graph's I/O and the
rewrites are described in ``c3_matcher_xfeat.engines``."""

from __future__ import annotations

from typing import Any, NamedTuple

import torch
from torch import nn
from torch.nn import functional as nnf

from c3_matcher_tools.engines.export.extractor import TwoStageInstanceNorm

__all__ = ["XFeatForExport"]


class _GridPoints(NamedTuple):
    """Points of a separable normalised grid: the grid's y values ``gy`` (H',) and x values
    ``gx`` (W',), and the (``rows``, ``cols``) index pairs (P,) of the points to read."""

    gy: torch.Tensor
    gx: torch.Tensor
    rows: torch.Tensor
    cols: torch.Tensor


class XFeatForExport(nn.Module):
    """Upstream ``XFeat`` with the export rewrites described in ``c3_matcher_xfeat.engines``."""

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
