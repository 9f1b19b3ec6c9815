"""The deformable convolution rewrite (GridSample + MatMul) against a direct reference: random
inputs in PyTorch, the module against kornia's DeformableConv2d, and the ONNX export in ONNX
Runtime at two sizes (one graph, dynamic H and W)."""

from __future__ import annotations

import numpy as np
import onnxruntime as ort
import pytest
import torch
from kornia.feature.aliked.aliked import DeformableConv2d
from kornia.feature.aliked.deform_conv2d import deform_conv2d as kornia_deform_conv2d

from c3_matcher_aliked_lightglue.deform_conv import (
    GridSampleDeformConv2d,
    deform_conv2d_gridsample,
    deform_conv2d_reference,
)
from c3_matcher_tools.engines.export.onnx_export import export_module

TOL = 2e-5  # float32 vs the float64 direct reference, O(1) inputs and weights


def _random_case(seed, batch, channels, out_channels, height, width, kernel, scale):
    g = torch.Generator().manual_seed(seed)
    x = torch.randn(batch, channels, height, width, generator=g)
    offset = torch.randn(batch, 2 * kernel * kernel, height, width, generator=g) * scale
    weight = torch.randn(out_channels, channels, kernel, kernel, generator=g) / kernel
    bias = torch.randn(out_channels, generator=g)
    return x, offset, weight, bias


@pytest.mark.parametrize(
    ("seed", "batch", "channels", "out_channels", "height", "width", "kernel", "scale"),
    [
        (0, 1, 4, 6, 8, 8, 3, 1.0),
        (1, 2, 5, 3, 7, 11, 3, 3.0),  # non-square, batch 2, many samples outside the image
        (2, 1, 3, 4, 9, 6, 5, 2.0),  # 5x5 kernel
        (3, 1, 8, 8, 16, 12, 3, 0.0),  # zero offsets: an ordinary convolution
        (4, 1, 2, 2, 1, 5, 3, 1.5),  # a single row
    ],
)
def test_gridsample_matches_the_direct_reference(
    seed, batch, channels, out_channels, height, width, kernel, scale
):
    x, offset, weight, bias = _random_case(
        seed, batch, channels, out_channels, height, width, kernel, scale
    )
    got = deform_conv2d_gridsample(x, offset, weight, bias)
    want = deform_conv2d_reference(x, offset, weight, bias)
    assert got.shape == (batch, out_channels, height, width)
    assert float((got - want).abs().max()) < TOL
    no_bias = deform_conv2d_gridsample(x, offset, weight)
    assert float((no_bias - deform_conv2d_reference(x, offset, weight)).abs().max()) < TOL


def test_the_direct_reference_agrees_with_kornia_and_with_conv2d():
    x, offset, weight, bias = _random_case(5, 1, 4, 3, 10, 9, 3, 2.5)
    want = deform_conv2d_reference(x, offset, weight, bias)
    kornia = kornia_deform_conv2d(x, offset, weight, bias, padding=1)
    assert float((kornia - want).abs().max()) < TOL
    zero = torch.zeros_like(offset)
    conv = torch.nn.functional.conv2d(x, weight, bias, padding=1)
    assert float((deform_conv2d_reference(x, zero, weight, bias) - conv).abs().max()) < TOL


def test_integer_offsets_shift_the_samples_exactly():
    x, _, weight, _ = _random_case(6, 1, 2, 2, 6, 6, 3, 0.0)
    offset = torch.zeros(1, 18, 6, 6)
    offset[:, 0::2] = 1.0  # every kernel point one row down: conv of x shifted up by one row
    shifted = torch.nn.functional.pad(x[:, :, 1:], (0, 0, 0, 1))
    conv = torch.nn.functional.conv2d(shifted, weight, padding=1)
    got = deform_conv2d_gridsample(x, offset, weight)
    # Row 0 differs by design: its top kernel row reads x's row 0, the shifted conv its padding.
    assert float((got - conv)[:, :, 1:].abs().max()) < TOL


def test_module_matches_kornia_deformable_conv_including_the_offset_clamp():
    torch.manual_seed(7)
    dcn = DeformableConv2d(6, 5, kernel_size=3, padding=1, bias=True).eval()
    with torch.no_grad():
        dcn.offset_conv.bias.add_(torch.linspace(-40, 40, 18))  # some offsets beyond max(H,W)/4
        x = torch.randn(1, 6, 12, 20)
        want = dcn(x)
        got = GridSampleDeformConv2d.from_module(dcn)(x)
        clamped = (dcn.offset_conv(x).abs() > 5.0).float().mean()
    assert float(clamped) > 0.1
    assert float((got - want).abs().max()) < 5e-5


def test_module_refuses_what_it_does_not_implement():
    dcn = DeformableConv2d(4, 4, mask=True)
    with pytest.raises(ValueError, match="DCNv2"):
        GridSampleDeformConv2d.from_module(dcn)
    strided = torch.nn.Conv2d(4, 18, 3, stride=2, padding=1)
    with pytest.raises(ValueError, match="stride 1"):
        GridSampleDeformConv2d(strided, torch.nn.Conv2d(4, 4, 3, padding=1))
    with pytest.raises(ValueError, match="offset has"):
        deform_conv2d_gridsample(
            torch.zeros(1, 4, 5, 5), torch.zeros(1, 8, 5, 5), torch.zeros(2, 4, 3, 3)
        )


def test_onnx_export_runs_in_onnx_runtime_without_custom_ops(tmp_path):
    torch.manual_seed(8)
    dcn = DeformableConv2d(4, 6, kernel_size=3, padding=1, bias=False).eval()
    with torch.no_grad():
        dcn.offset_conv.weight.mul_(20.0)  # offsets of several px
    module = GridSampleDeformConv2d.from_module(dcn).eval()
    height = torch.export.Dim("height", min=2, max=256)
    width = torch.export.Dim("width", min=2, max=256)
    path = tmp_path / "dcn.onnx"
    export_module(
        module,
        (torch.randn(1, 4, 16, 24),),
        path,
        input_names=["x"],
        output_names=["y"],
        dynamic_shapes={"x": {2: height, 3: width}},
        opset=18,
    )
    import onnx

    ops = {node.op_type for node in onnx.load(str(path)).graph.node}
    assert "GridSample" in ops
    assert not any("deform" in op.lower() for op in ops)
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    for shape in ((1, 4, 16, 24), (1, 4, 33, 17)):
        x = torch.randn(*shape)
        (got,) = session.run(None, {"x": x.numpy()})
        with torch.no_grad():
            want = deform_conv2d_reference(
                x,
                module.offset_conv(x).clamp(-max(shape[2:]) / 4, max(shape[2:]) / 4),
                dcn.regular_conv.weight,
            )
        assert got.shape == tuple(want.shape)
        assert float(np.abs(got - want.numpy()).max()) < 1e-4
