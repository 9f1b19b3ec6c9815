"""Shared ONNX export helpers (build time only: imports torch).

Uses the dynamo exporter (``torch.onnx.export(..., dynamo=True)``) at the spec's opset and saves
one self-contained file (``external_data=False``). The exporter's console chatter goes to stderr
so that a CLI's stdout carries only its result.
"""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import onnx
import onnxruntime as ort
import torch

from c3_matcher.engines.providers import CPU_PROVIDER
from c3_matcher.engines.runtime import SessionSettings
from c3_matcher.engines.spec import TensorSpec
from c3_matcher_tools.engines.export import ExportRequest

__all__ = ["check_onnx_io", "export_module", "export_requested", "verification_session"]

_ONNX_TO_NUMPY = {
    onnx.TensorProto.FLOAT: "float32",
    onnx.TensorProto.FLOAT16: "float16",
    onnx.TensorProto.INT64: "int64",
    onnx.TensorProto.INT32: "int32",
    onnx.TensorProto.BOOL: "bool",
    onnx.TensorProto.UINT8: "uint8",
}


def export_module(
    module: torch.nn.Module,
    args: tuple[torch.Tensor, ...],
    path: Path,
    *,
    input_names: Sequence[str],
    output_names: Sequence[str],
    dynamic_shapes: Mapping[str, Any],
    opset: int,
    translations: Mapping[Any, Any] | None = None,
) -> None:
    """Export ``module`` (eval mode, no grad) to ``path`` as one ONNX file; ``translations``
    maps custom torch ops to their ONNX functions (e.g. ``attention.ONNX_TRANSLATIONS``)."""
    module.eval()
    with torch.no_grad(), contextlib.redirect_stdout(sys.stderr):
        program = torch.onnx.export(
            module,
            args,
            None,
            dynamo=True,
            opset_version=opset,
            input_names=list(input_names),
            output_names=list(output_names),
            dynamic_shapes=dict(dynamic_shapes),
            verbose=False,
            custom_translation_table=dict(translations or {}),
        )
        if program is None:
            raise RuntimeError("torch.onnx.export returned no program")
        program.save(str(path), external_data=False)


def export_requested(
    request: ExportRequest,
    module: torch.nn.Module,
    args: tuple[torch.Tensor, ...],
    *,
    dynamic_shapes: Mapping[str, Any],
    translations: Mapping[Any, Any] | None = None,
) -> None:
    """Export ``module`` as ``request`` asks: to its output path, its inputs and outputs named
    and its opset taken from the engine spec it declares (see :func:`export_module`)."""
    export_module(
        module,
        args,
        request.output_path,
        input_names=[t.name for t in request.spec.inputs],
        output_names=[t.name for t in request.spec.outputs],
        dynamic_shapes=dynamic_shapes,
        opset=request.spec.opset,
        translations=translations,
    )


def check_onnx_io(path: Path, inputs: Sequence[TensorSpec], outputs: Sequence[TensorSpec]) -> None:
    """Assert the saved graph's inputs and outputs (names, element types, ranks, fixed dims) are
    the declared ones; ``ValueError`` says which differ. Also runs ``onnx.checker``."""
    model = onnx.load(str(path))
    onnx.checker.check_model(model)
    for role, declared, actual in (
        ("input", inputs, model.graph.input),
        ("output", outputs, model.graph.output),
    ):
        got = {v.name: v for v in actual}
        want = {t.name: t for t in declared}
        if set(got) != set(want):
            raise ValueError(f"graph {role}s {sorted(got)} != declared {sorted(want)}")
        for name, spec in want.items():
            tensor_type = got[name].type.tensor_type
            dtype = _ONNX_TO_NUMPY.get(tensor_type.elem_type, str(tensor_type.elem_type))
            if dtype != spec.dtype:
                raise ValueError(f"{role} {name}: dtype {dtype} != declared {spec.dtype}")
            dims = [d.dim_value if d.HasField("dim_value") else None for d in tensor_type.shape.dim]
            if len(dims) != len(spec.shape):
                raise ValueError(f"{role} {name}: rank {len(dims)} != declared {len(spec.shape)}")
            for axis, (want_dim, got_dim) in enumerate(zip(spec.shape, dims, strict=True)):
                if isinstance(want_dim, int) and got_dim != want_dim:
                    raise ValueError(f"{role} {name}: dim {axis} is {got_dim}, declared {want_dim}")
                if isinstance(want_dim, str) and got_dim is not None:
                    raise ValueError(
                        f"{role} {name}: dim {axis} is fixed {got_dim}, declared dynamic"
                    )


def verification_session(path: Path) -> ort.InferenceSession:
    """An exported graph opened as the run time opens it, on the CPU, for its verification."""
    return ort.InferenceSession(
        str(path), sess_options=SessionSettings().build(), providers=[CPU_PROVIDER]
    )
