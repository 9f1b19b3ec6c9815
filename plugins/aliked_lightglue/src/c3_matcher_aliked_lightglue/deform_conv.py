"""Deformable convolution (DCNv1) as GridSample + MatMul: exportable to plain ONNX (build time).

ONNX Runtime has no deformable-convolution op, so ALIKED's ``DeformableConv2d`` is rewritten for
export. For an input ``x`` (B, C, H, W) and offsets (B, 2 * kh * kw, H, W), interleaved
``(dy, dx)`` per kernel point ``k = i * kw + j`` (torchvision's layout), the output at (y, x) is

    out[o, y, x] = bias[o] + sum_{c, k} weight[o, c, i, j] * bilinear(x[c], y - p + i + dy_k,
                                                                         x - p + j + dx_k)

with ``bilinear`` reading zero outside the image (torchvision's corner rule). Here all ``kh * kw``
sampling positions of every output pixel go through ONE ``grid_sample`` (bilinear, zero padding,
``align_corners=False``: pixel ``i`` of ``n`` has its centre at normalised ``(2 i + 1) / n - 1``,
which also holds for ``n = 1``),
stacked along the grid's height: (B, C, K * H, W) = (B, C * K, H * W) after a reshape, which one
matmul with the weight viewed as (O, C * K) turns into the output. Stride 1, dilation 1, one
group, one offset group, no modulation mask and "same" padding ``(k - 1) / 2`` only (what ALIKED
uses); anything else is refused.

Everything size-dependent is computed from tensors (``cumsum`` grids, sizes as 0-d tensors): the
dynamo exporter cannot export Python arithmetic on symbolic sizes. ``max_offset_fraction``
reproduces ALIKED's clamp of the offsets to ``max(H, W) / 4`` px.

Imports torch: build time and tests only.
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as nnf

__all__ = ["GridSampleDeformConv2d", "deform_conv2d_gridsample", "deform_conv2d_reference"]


def _pixel_grids(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Row and column index maps (H, W) of ``x`` (B, C, H, W) as float, from ``cumsum``."""
    ones = torch.ones_like(x[0, 0])
    rows = torch.cumsum(ones, 0) - 1
    cols = torch.cumsum(ones, 1) - 1
    return rows, cols


def deform_conv2d_gridsample(
    x: torch.Tensor,
    offset: torch.Tensor,
    weight: torch.Tensor,
    bias: torch.Tensor | None = None,
) -> torch.Tensor:
    """Deformable convolution of ``x`` (B, C, H, W) with ``offset`` (B, 2*kh*kw, H, W) px
    (``(dy, dx)`` interleaved), ``weight`` (O, C, kh, kw), optional ``bias`` (O,); stride 1,
    dilation 1, padding ``(k - 1) // 2``. Returns (B, O, H, W). See the module docstring."""
    out_channels, in_channels, kh, kw = weight.shape
    if kh % 2 == 0 or kw % 2 == 0:
        raise ValueError(f"odd kernel sizes only, got {kh}x{kw}")
    if x.shape[1] != in_channels:
        raise ValueError(f"x has {x.shape[1]} channels, weight expects {in_channels}")
    k = kh * kw
    if offset.shape[1] != 2 * k:
        raise ValueError(f"offset has {offset.shape[1]} channels, expected {2 * k}")
    batch = x.shape[0]
    rows, cols = _pixel_grids(x)
    # Kernel point offsets relative to the output pixel ("same" padding): (1, K, 1, 1).
    ky = torch.tensor([i - kh // 2 for i in range(kh) for _ in range(kw)], dtype=x.dtype)
    kx = torch.tensor([j - kw // 2 for _ in range(kh) for j in range(kw)], dtype=x.dtype)
    off = offset.reshape(batch, k, 2, offset.shape[2], offset.shape[3])
    sample_y = rows + ky.reshape(1, k, 1, 1) + off[:, :, 0]  # (B, K, H, W) px
    sample_x = cols + kx.reshape(1, k, 1, 1) + off[:, :, 1]
    # align_corners=False: pixel i spans normalised [2i/n - 1, 2(i+1)/n - 1], its centre at
    # (2i + 1)/n - 1; exact for any size, 1 included.
    height = rows[-1, 0] + 1.0
    width = cols[0, -1] + 1.0
    grid = torch.stack(
        [(2.0 * sample_x + 1.0) / width - 1.0, (2.0 * sample_y + 1.0) / height - 1.0], -1
    )
    grid = grid.reshape(batch, -1, grid.shape[3], 2)  # (B, K * H, W, 2), kernel point major
    sampled = nnf.grid_sample(x, grid, mode="bilinear", padding_mode="zeros", align_corners=False)
    columns = sampled.reshape(batch, in_channels * k, -1)  # (B, C * K, H * W), index c * K + k
    out = torch.matmul(weight.reshape(out_channels, in_channels * k), columns)
    if bias is not None:
        out = out + bias.reshape(1, out_channels, 1)
    return out.reshape(batch, out_channels, x.shape[2], x.shape[3])


def deform_conv2d_reference(
    x: torch.Tensor,
    offset: torch.Tensor,
    weight: torch.Tensor,
    bias: torch.Tensor | None = None,
) -> torch.Tensor:
    """The same operation written directly (tests only): for every kernel point, explicit
    bilinear interpolation from the four integer neighbours, each read as zero outside the
    image, in float64, then a sum over channels and kernel points. Slow; small inputs only."""
    out_channels, in_channels, kh, kw = weight.shape
    batch, _, height, width = x.shape
    xd, od, wd = x.double(), offset.double(), weight.double()
    ys = torch.arange(height, dtype=torch.float64).reshape(height, 1)
    xs = torch.arange(width, dtype=torch.float64).reshape(1, width)
    out = torch.zeros(batch, out_channels, height, width, dtype=torch.float64)
    for i in range(kh):
        for j in range(kw):
            kp = i * kw + j
            sy = ys + (i - kh // 2) + od[:, 2 * kp]  # (B, H, W)
            sx = xs + (j - kw // 2) + od[:, 2 * kp + 1]
            y0, x0 = torch.floor(sy), torch.floor(sx)
            ly, lx = sy - y0, sx - x0
            value = torch.zeros(batch, in_channels, height, width, dtype=torch.float64)
            for cy, cx, wgt in (
                (y0, x0, (1 - ly) * (1 - lx)),
                (y0, x0 + 1, (1 - ly) * lx),
                (y0 + 1, x0, ly * (1 - lx)),
                (y0 + 1, x0 + 1, ly * lx),
            ):
                inside = (cy >= 0) & (cy <= height - 1) & (cx >= 0) & (cx <= width - 1)
                flat = (cy.clamp(0, height - 1) * width + cx.clamp(0, width - 1)).long()
                gathered = torch.gather(
                    xd.reshape(batch, in_channels, -1),
                    2,
                    flat.reshape(batch, 1, -1).expand(batch, in_channels, -1),
                ).reshape(batch, in_channels, height, width)
                value = value + gathered * (wgt * inside)[:, None]
            out = out + torch.einsum("bchw,oc->bohw", value, wd[:, :, i, j])
    if bias is not None:
        out = out + bias.double().reshape(1, -1, 1, 1)
    return out.to(x.dtype)


class GridSampleDeformConv2d(nn.Module):
    """Drop-in export replacement of kornia's / upstream ALIKED's ``DeformableConv2d``: the same
    ``offset_conv`` and ``regular_conv`` (shared modules), offsets clamped to
    ``max(H, W) * max_offset_fraction`` px, then ``deform_conv2d_gridsample``."""

    def __init__(
        self, offset_conv: nn.Conv2d, regular_conv: nn.Conv2d, max_offset_fraction: float = 0.25
    ) -> None:
        super().__init__()
        for name, conv in (("offset_conv", offset_conv), ("regular_conv", regular_conv)):
            if conv.stride != (1, 1) or conv.dilation != (1, 1) or conv.groups != 1:
                raise ValueError(f"{name}: stride 1, dilation 1, groups 1 only")
            if conv.padding != tuple((k - 1) // 2 for k in conv.kernel_size):
                raise ValueError(f"{name}: 'same' padding only, got {conv.padding}")
        self.offset_conv = offset_conv
        self.regular_conv = regular_conv
        self.max_offset_fraction = max_offset_fraction

    @classmethod
    def from_module(cls, module: nn.Module) -> GridSampleDeformConv2d:
        """From a ``DeformableConv2d`` (kornia or upstream ALIKED); refuses the masked DCNv2."""
        if getattr(module, "mask", False):
            raise ValueError("modulated (DCNv2) deformable convolution is not supported")
        offset_conv = module.offset_conv
        regular_conv = module.regular_conv
        if not isinstance(offset_conv, nn.Conv2d) or not isinstance(regular_conv, nn.Conv2d):
            raise TypeError("expected offset_conv and regular_conv to be Conv2d")
        return cls(offset_conv, regular_conv)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        rows, cols = _pixel_grids(x)
        limit = torch.maximum(rows[-1, 0], cols[0, -1]) + 1.0  # max(H, W) as a tensor
        limit = limit * self.max_offset_fraction
        offset = torch.minimum(torch.maximum(self.offset_conv(x), -limit), limit)
        return deform_conv2d_gridsample(x, offset, self.regular_conv.weight, self.regular_conv.bias)
