"""Fused attention for LightGlue-family exports (build time only: imports torch).

kornia's LightGlue blocks export as plain ``MatMul -> Softmax -> MatMul`` (self-attention) and
``Einsum`` chains (cross-attention, with a transposed softmax), which ONNX Runtime runs unfused:
each (M, N) score matrix is written out, soft-maxed and read back per head. This module swaps
each ``SelfBlock`` / ``CrossBlock`` of a LightGlue copy for an export-friendly subclass whose
attention is one custom op, ``c3_export::attention``, translated to ONNX Runtime's fused
``com.microsoft.MultiHeadAttention`` kernel (CPU, CUDA) at export. The maths is upstream's:

- self-attention: ``Wqkv`` split per head as ``(heads, head_dim, 3)``, rotary encoding on q and
  k, ``softmax(q k^T / sqrt(head_dim)) v``, ``out_proj``, then the same FFN;
- cross-attention: ``m0 = softmax(qk0 qk1^T / sqrt(d)) v1`` and ``m1 = softmax(qk1 qk0^T /
  sqrt(d)) v0``, which is exactly upstream's ``softmax(sim^T)`` for the second direction.

Only float rounding differs (the fused kernel accumulates in another order), so the export
checks (identical matches, layers and kept points) hold as before. Parameter names are unchanged
(the subclasses add no parameters), so state dicts and ``functional_call`` keep working.
"""

from __future__ import annotations

import copy
from typing import Any, TypeVar

import torch
from kornia.feature.lightglue import CrossBlock, SelfBlock, apply_cached_rotary_emb
from torch import nn
from torch.nn import functional as nnf

__all__ = ["ONNX_TRANSLATIONS", "attention", "fused_attention_copy"]

_M = TypeVar("_M", bound=nn.Module)


@torch.library.custom_op("c3_export::attention", mutates_args=())
def attention(
    query: torch.Tensor, key: torch.Tensor, value: torch.Tensor, num_heads: int
) -> torch.Tensor:
    """Multi-head attention on packed heads: ``query (B, M, H*d)``, ``key`` / ``value``
    ``(B, N, H*d)`` -> ``(B, M, H*d)``, scale ``1/sqrt(d)`` (ONNX Runtime's
    ``MultiHeadAttention`` with 3-D inputs)."""

    def heads(t: torch.Tensor) -> torch.Tensor:
        return t.unflatten(-1, (num_heads, -1)).transpose(1, 2)

    out = nnf.scaled_dot_product_attention(heads(query), heads(key), heads(value))
    return out.transpose(1, 2).flatten(start_dim=-2).contiguous()


@attention.register_fake
def _attention_fake(
    query: torch.Tensor, key: torch.Tensor, value: torch.Tensor, num_heads: int
) -> torch.Tensor:
    return query.new_empty((*query.shape[:-1], value.shape[-1]))


def _onnx_attention(query: Any, key: Any, value: Any, num_heads: int) -> Any:
    from onnxscript.values import Op, Opset

    fused = Op(Opset(_MHA_DOMAIN, 1), "MultiHeadAttention", _mha_schema())
    return fused(query, key, value, num_heads=num_heads)


_MHA_DOMAIN = "com.microsoft"


def _mha_schema() -> Any:
    """The part of ONNX Runtime's contrib ``MultiHeadAttention`` schema this export uses (3-D
    query, key and value; ``num_heads``): onnx.defs has no schema for contrib ops."""
    from onnx.defs import OpSchema

    return OpSchema(
        "MultiHeadAttention",
        _MHA_DOMAIN,
        1,
        inputs=[OpSchema.FormalParameter(name, "T") for name in ("query", "key", "value")],
        outputs=[OpSchema.FormalParameter("output", "T")],
        type_constraints=[("T", ["tensor(float)", "tensor(float16)"], "")],
        attributes=[OpSchema.Attribute("num_heads", OpSchema.AttrType.INT, "heads")],
    )


ONNX_TRANSLATIONS: dict[Any, Any] = {torch.ops.c3_export.attention.default: _onnx_attention}
"""The dynamo exporter's ``custom_translation_table`` for the ops of this module."""


class _FusedSelfBlock(SelfBlock):
    def forward(
        self, x: torch.Tensor, encoding: torch.Tensor, mask: torch.Tensor | None = None
    ) -> torch.Tensor:
        if mask is not None:
            raise NotImplementedError("the fused export runs without padding masks")
        qkv = self.Wqkv(x).unflatten(-1, (self.num_heads, -1, 3))  # (B, N, H, d, 3)
        freqs = encoding.transpose(2, 3)  # (2, B, N, 1, d): rotary per head, heads last but one
        q = apply_cached_rotary_emb(freqs, qkv[..., 0]).flatten(start_dim=-2)
        k = apply_cached_rotary_emb(freqs, qkv[..., 1]).flatten(start_dim=-2)
        v = qkv[..., 2].flatten(start_dim=-2)
        message = self.out_proj(attention(q, k, v, self.num_heads))
        return x + self.ffn(torch.cat([x, message], -1))


class _FusedCrossBlock(CrossBlock):
    def forward(
        self, x0: torch.Tensor, x1: torch.Tensor, mask: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        if mask is not None:
            raise NotImplementedError("the fused export runs without padding masks")
        qk0, qk1 = self.to_qk(x0), self.to_qk(x1)
        v0, v1 = self.to_v(x0), self.to_v(x1)
        m0 = self.to_out(attention(qk0, qk1, v1, self.heads))
        m1 = self.to_out(attention(qk1, qk0, v0, self.heads))
        x0 = x0 + self.ffn(torch.cat([x0, m0], -1))
        x1 = x1 + self.ffn(torch.cat([x1, m1], -1))
        return x0, x1


def fused_attention_copy(model: _M) -> _M:
    """A deep copy of ``model`` (a kornia ``LightGlue`` or anything holding its blocks) whose
    ``SelfBlock`` / ``CrossBlock`` modules run ``attention``; ``model`` itself is untouched (it
    stays the reference the export is verified against)."""
    fused = copy.deepcopy(model)
    for module in fused.modules():
        if type(module) is SelfBlock:
            module.__class__ = _FusedSelfBlock
        elif type(module) is CrossBlock:
            module.__class__ = _FusedCrossBlock
    return fused
