"""The export rewrite of kornia ``DISK`` (build time only: imports torch at module level, so it is
imported only by ``c3_matcher_disk_lightglue.export.build_disk_export_module``, whose docstring
describes the sparse descriptor head)."""

from __future__ import annotations

from typing import Any

import torch
from torch import nn
from torch.nn import functional as nnf

from c3_matcher_tools.engines.export.extractor import (
    TwoStageInstanceNorm,
    strict_maxima_candidates,
)

__all__ = ["DiskForExport", "swap_norms"]


def swap_norms(module: nn.Module) -> None:
    """Replace every ``InstanceNorm2d`` below ``module`` by a ``TwoStageInstanceNorm``."""
    for name, child in module.named_children():
        if isinstance(child, nn.InstanceNorm2d):
            if child.affine or child.track_running_stats:
                raise ValueError("DISK export expects InstanceNorm2d without affine/stats")
            setattr(module, name, TwoStageInstanceNorm(child.eps))
        else:
            swap_norms(child)


class DiskForExport(nn.Module):
    """kornia ``DISK`` with the sparse descriptor head (``build_disk_export_module``)."""

    heat_w: torch.Tensor  # (1, C, 5, 5): the heat-map row of the last convolution
    heat_b: torch.Tensor  # (1,)
    desc_w: torch.Tensor  # (D, C * 25): its descriptor rows, flattened as the patches
    desc_b: torch.Tensor  # (D,)

    def __init__(self, unet: nn.Module, k: int, dim: int) -> None:
        super().__init__()
        self.unet = unet
        self.k = k
        self.dim = dim
        path_up: Any = unet.path_up
        head: Any = path_up[-1].conv[-1]  # kornia's Conv block ends in its Conv2d
        if not isinstance(head, nn.Conv2d) or head.kernel_size != (5, 5):
            raise ValueError("DISK export expects a 5x5 Conv2d as the U-Net's last layer")
        weight, bias = head.weight.detach(), head.bias.detach()  # type: ignore[union-attr]
        self.register_buffer("heat_w", weight[dim:].clone())
        self.register_buffer("heat_b", bias[dim:].clone())
        self.register_buffer("desc_w", weight[:dim].reshape(dim, -1).clone())  # (D, C*25)
        self.register_buffer("desc_b", bias[:dim].clone())

    def head_input(self, image: torch.Tensor) -> torch.Tensor:
        """The U-Net up to its last convolution's input (1, C, H, W)."""
        unet: Any = self.unet
        features = [image]
        for layer in unet.path_down:
            features.append(layer(features[-1]))
        pairs = list(zip(unet.path_up, features[-2::-1], strict=False))
        bottom = features[-1]
        for layer, horizontal in pairs[:-1]:
            bottom = layer(bottom, horizontal)
        last, horizontal = pairs[-1]
        x = torch.cat([last.upsample(bottom), horizontal], dim=1)
        for module in list(last.conv)[:-1]:
            x = module(x)
        return x

    def forward(
        self, image: torch.Tensor, mask: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        x = self.head_input(image)
        heat = nnf.conv2d(x, self.heat_w, self.heat_b, padding=2)[0] * mask[0]  # (1, H, W)
        candidates = strict_maxima_candidates(heat)
        ones = torch.ones_like(heat[0])
        xs = torch.cumsum(ones, 1) - 1
        ys = torch.cumsum(ones, 0) - 1
        pad = torch.zeros(self.k, dtype=heat.dtype)
        scores, index = torch.topk(torch.cat([candidates.reshape(-1), pad]), self.k, sorted=True)
        kx = torch.cat([xs.reshape(-1), pad]).gather(0, index)
        ky = torch.cat([ys.reshape(-1), pad]).gather(0, index)
        # 5x5 patches around (kx, ky) of the zero-padded input, flattened as the weights
        padded = nnf.pad(x[0], (2, 2, 2, 2))  # (C, H + 4, W + 4)
        row = torch.ones_like(padded[0, 0]).sum()  # W + 4, as a tensor (no symbolic sizes)
        flat = padded.reshape(padded.shape[0], -1)
        taps = [((ky + dy) * row + (kx + dx)).to(torch.int64) for dy in range(5) for dx in range(5)]
        patches = flat.index_select(1, torch.cat(taps))  # (C, 25 K), tap-major
        patches = patches.reshape(flat.shape[0], 25, self.k).reshape(-1, self.k)  # (C*25, K)
        dense = torch.matmul(self.desc_w, patches) + self.desc_b[:, None]  # (D, K)
        descriptors = nnf.normalize(dense.transpose(0, 1), dim=-1)
        return torch.stack([kx, ky], -1), scores, descriptors
