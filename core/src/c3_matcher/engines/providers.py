"""Execution providers of the ONNX Runtime sessions: which, in what order, with what options.

Execution providers: ``[engines] providers`` names any ONNX Runtime provider, in order of
preference, by its full name or a short alias (TensorRT, CUDA, ROCm, MIGraphX, OpenVINO,
DirectML, CoreML, CPU); the list is intersected with what the installed onnxruntime offers (or
the injected ``providers_available``), and nothing usable left is an ``EngineError`` naming the
setting. Without the setting: the first of TensorRT -> CUDA -> ... -> CPU that is installed,
the rest as fallbacks. Per-provider options: device id, GPU memory limit, TensorRT FP16 switch
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from c3_matcher.errors import EngineError

__all__ = [
    "CPU_PROVIDER",
    "PROVIDERS_SETTING",
    "PROVIDER_ALIASES",
    "PROVIDER_CHAIN",
    "ProviderSettings",
    "canonical_provider",
    "provider_options",
    "resolve_providers",
    "select_providers",
]

CPU_PROVIDER = "CPUExecutionProvider"
"""The provider every onnxruntime build has, the last of the chain."""

PROVIDER_CHAIN: tuple[str, ...] = (
    "TensorrtExecutionProvider",
    "CUDAExecutionProvider",
    "ROCMExecutionProvider",
    "MIGraphXExecutionProvider",
    "OpenVINOExecutionProvider",
    "DmlExecutionProvider",
    "CoreMLExecutionProvider",
    CPU_PROVIDER,
)

PROVIDER_ALIASES: dict[str, str] = {
    "tensorrt": "TensorrtExecutionProvider",
    "trt": "TensorrtExecutionProvider",
    "cuda": "CUDAExecutionProvider",
    "rocm": "ROCMExecutionProvider",
    "migraphx": "MIGraphXExecutionProvider",
    "openvino": "OpenVINOExecutionProvider",
    "directml": "DmlExecutionProvider",
    "dml": "DmlExecutionProvider",
    "coreml": "CoreMLExecutionProvider",
    "cpu": CPU_PROVIDER,
}

_GPU_PROVIDERS = frozenset(
    {
        "TensorrtExecutionProvider",
        "CUDAExecutionProvider",
        "ROCMExecutionProvider",
        "MIGraphXExecutionProvider",
        "DmlExecutionProvider",
    }
)

PROVIDERS_SETTING = "[engines] providers (C3_MATCHER_ENGINES__PROVIDERS)"


def canonical_provider(name: str) -> str:
    """The onnxruntime name of a provider given by full name (any case) or short alias."""
    text = str(name).strip()
    lowered = text.lower()
    if lowered in PROVIDER_ALIASES:
        return PROVIDER_ALIASES[lowered]
    for full in (*PROVIDER_CHAIN, *PROVIDER_ALIASES.values()):
        if full.lower() == lowered or full.lower() == lowered + "executionprovider":
            return full
    if text.endswith("ExecutionProvider") and text[:-17].isidentifier():
        return text  # a provider this module does not know by name: onnxruntime will tell
    raise EngineError(
        PROVIDERS_SETTING,
        f"unknown execution provider {text!r}; use an onnxruntime name or one of "
        f"{sorted(PROVIDER_ALIASES)}",
        "set [engines] providers to installed providers",
    )


def resolve_providers(configured: Sequence[str] | None, installed: Sequence[str]) -> list[str]:
    """The session provider list: ``configured`` (in its order, canonical names) intersected
    with ``installed``; without ``configured``, the default chain's members that are installed.
    ``EngineError`` naming the setting when nothing usable remains."""
    have = list(dict.fromkeys(str(p) for p in installed))
    if configured is None:
        chosen = [p for p in PROVIDER_CHAIN if p in set(have)]
        if not chosen:
            raise EngineError(
                PROVIDERS_SETTING,
                f"none of the known providers {list(PROVIDER_CHAIN)} is installed "
                f"(installed: {have})",
                "pip install onnxruntime",
            )
        return chosen
    wanted = list(dict.fromkeys(canonical_provider(p) for p in configured))
    if not wanted:
        raise EngineError(
            PROVIDERS_SETTING,
            "is empty: name at least one provider",
            "set [engines] providers, or remove it for the default chain",
        )
    chosen = [p for p in wanted if p in set(have)]
    if not chosen:
        raise EngineError(
            PROVIDERS_SETTING,
            f"none of {wanted} is installed (installed onnxruntime providers: {have})",
            "set [engines] providers to installed providers, or remove it for the default chain",
        )
    return chosen


def select_providers(available: Sequence[str]) -> list[str]:
    """The default provider list over ``available`` (see :func:`resolve_providers`)."""
    return resolve_providers(None, available)


@dataclass(frozen=True, slots=True)
class ProviderSettings:
    """Per-provider options: ``device_id`` (CUDA, TensorRT, ROCm, MIGraphX, DirectML),
    ``gpu_mem_limit_bytes`` (CUDA, ROCm arena limit), ``tensorrt_fp16``, and raw ``extra``
    options by provider name (merged last)."""

    device_id: int = 0
    gpu_mem_limit_bytes: int | None = None
    tensorrt_fp16: bool = False  # opt-in until FP16 is verified against FP32
    extra: Mapping[str, Mapping[str, Any]] | None = None


def provider_options(
    providers: Sequence[str],
    tensorrt_cache_dir: Path | None,
    settings: ProviderSettings | None = None,
) -> list[str | tuple[str, dict[str, Any]]]:
    """The session's provider list with options: TensorRT caches the engines it compiles (FP16
    unless switched off) in ``tensorrt_cache_dir``, so a flight computer whose cache was filled
    on the ground never recompiles in flight; GPU providers get the device id and memory
    limit; ``extra`` options are merged per provider."""
    cfg = settings or ProviderSettings()
    out: list[str | tuple[str, dict[str, Any]]] = []
    for name in providers:
        opts: dict[str, Any] = {}
        if name in _GPU_PROVIDERS and cfg.device_id != 0:
            opts["device_id"] = cfg.device_id
        if name == "TensorrtExecutionProvider":
            opts["trt_fp16_enable"] = cfg.tensorrt_fp16
            if tensorrt_cache_dir is not None:
                opts.update(
                    trt_engine_cache_enable=True,
                    trt_engine_cache_path=str(tensorrt_cache_dir),
                    trt_timing_cache_enable=True,
                    trt_timing_cache_path=str(tensorrt_cache_dir),
                )
        elif name in ("CUDAExecutionProvider", "ROCMExecutionProvider"):
            if cfg.gpu_mem_limit_bytes is not None:
                opts["gpu_mem_limit"] = int(cfg.gpu_mem_limit_bytes)
            if name == "CUDAExecutionProvider":
                # ONNX Runtime's EXHAUSTIVE default benchmarks every convolution algorithm for
                # each new input shape, and query and candidate windows change shape through a
                # flight: DISK query extraction 130 ms vs 15 ms, XFeat 450 vs 33 ms on an H100
                # (docs/decisions.md, GPU defaults). ``provider_options`` can set it back.
                opts["cudnn_conv_algo_search"] = "DEFAULT"
        if cfg.extra and name in cfg.extra:
            opts.update(dict(cfg.extra[name]))
        if name == CPU_PROVIDER or not opts:
            out.append(name)
        else:
            out.append((name, opts))
    return out
