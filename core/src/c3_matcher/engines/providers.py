"""Execution providers of the ONNX Runtime sessions: which, in what order, with what options.

Execution providers: ``[engines] providers`` names any ONNX Runtime provider, in order of
preference, by its full name or a short alias (TensorRT, CUDA, ROCm, MIGraphX, OpenVINO,
DirectML, CoreML, CPU); the list is intersected with what the installed onnxruntime offers (or
the injected ``providers_available``): a provider not installed is left out and said as a
WARNING at start-up (``providers_not_installed``), and nothing usable left is a
``ConfigurationError`` naming the setting. Without the setting: the first of TensorRT -> CUDA
-> ... -> CPU that is installed, the rest as fallbacks. Per-provider options: device id, GPU
memory limit, TensorRT FP16 switch, and ``[engines] provider_options`` keyed by any name
``providers`` accepts (``canonical_provider_options``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from c3_matcher.errors import ConfigurationError

__all__ = [
    "CPU_PROVIDER",
    "PROVIDERS_SETTING",
    "PROVIDER_ALIASES",
    "PROVIDER_CHAIN",
    "PROVIDER_OPTIONS_SETTING",
    "ProviderSettings",
    "canonical_provider",
    "canonical_provider_options",
    "configured_providers",
    "provider_options",
    "providers_not_installed",
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
PROVIDER_OPTIONS_SETTING = "[engines] provider_options (C3_MATCHER_ENGINES__PROVIDER_OPTIONS)"
CPU_SETTINGS = "[engines] intra_op_threads and [engines] cpu_mem_arena"
"""The settings that do apply to the CPU provider (onnxruntime takes no options for it)."""


def _refused(setting: str, reason: str) -> ConfigurationError:
    return ConfigurationError("engines", [(setting, reason)])


def canonical_provider(name: str, *, setting: str = PROVIDERS_SETTING) -> str:
    """The onnxruntime name of a provider given by full name (any case) or short alias; a
    provider this module does not list is looked up among the names the installed onnxruntime
    knows (``get_all_providers``). ``ConfigurationError`` naming ``setting`` for any other."""
    text = str(name).strip()
    lowered = text.lower()
    if lowered in PROVIDER_ALIASES:
        return PROVIDER_ALIASES[lowered]
    found = _full_name(lowered, PROVIDER_CHAIN) or _full_name(lowered, _onnxruntime_providers())
    if found is not None:
        return found
    raise _refused(
        setting,
        f"unknown execution provider {text!r}; use an onnxruntime name or one of "
        f"{sorted(PROVIDER_ALIASES)}",
    )


def _full_name(lowered: str, names: Sequence[str]) -> str | None:
    for full in names:
        if full.lower() in (lowered, lowered + "executionprovider"):
            return full
    return None


def _onnxruntime_providers() -> tuple[str, ...]:
    """Every provider the installed onnxruntime knows by name, installed or not (imported only
    for a name this module does not list: the configuration loads without onnxruntime)."""
    import onnxruntime as ort

    return tuple(str(p) for p in ort.get_all_providers())


def configured_providers(value: Sequence[str] | None) -> tuple[str, ...] | None:
    """``[engines] providers`` in canonical names (None: unset, the default chain);
    ``ConfigurationError`` naming the setting when it is empty or names an unknown provider."""
    if value is None:
        return None
    if not value:
        raise _refused(PROVIDERS_SETTING, "is empty: name at least one provider, or remove it")
    return tuple(canonical_provider(v) for v in value)


def canonical_provider_options(
    options: Mapping[str, Mapping[str, Any]] | None, providers: Sequence[str] | None = None
) -> dict[str, dict[str, Any]]:
    """``[engines] provider_options`` keyed by onnxruntime provider names: a key may be any name
    ``[engines] providers`` accepts (full name in any case, or a short alias such as ``CUDA``).
    ``ConfigurationError`` naming the setting for an unknown provider, two keys naming one
    provider, options for the CPU provider (onnxruntime ignores them: ``CPU_SETTINGS`` are its
    settings), and, given ``providers`` (the configured list), a provider it does not name
    (its options would never apply)."""
    out: dict[str, dict[str, Any]] = {}
    keys: dict[str, str] = {}
    for key, values in (options or {}).items():
        name = canonical_provider(key, setting=PROVIDER_OPTIONS_SETTING)
        problem = None
        if name in out:
            problem = f"{keys[name]!r} and {key!r} both name {name}: give its options once"
        elif name == CPU_PROVIDER and values:
            problem = (
                f"{key!r}: the CPU provider takes no provider options (onnxruntime ignores "
                f"them, got {sorted(values)}); set {CPU_SETTINGS} instead"
            )
        elif providers is not None and name not in providers:
            problem = (
                f"{key!r}: options for {name}, which {PROVIDERS_SETTING} does not name "
                f"({list(providers)}): they would never apply"
            )
        if problem:
            raise _refused(PROVIDER_OPTIONS_SETTING, problem)
        out[name], keys[name] = dict(values), key
    return out


def resolve_providers(configured: Sequence[str] | None, installed: Sequence[str]) -> list[str]:
    """The session provider list: ``configured`` (in its order, canonical names) intersected
    with ``installed``; without ``configured``, the default chain's members that are installed.
    ``ConfigurationError`` naming the setting when nothing usable remains."""
    have = list(dict.fromkeys(str(p) for p in installed))
    if configured is None:
        chosen = [p for p in PROVIDER_CHAIN if p in set(have)]
        if not chosen:
            raise _refused(
                PROVIDERS_SETTING,
                f"unset, and none of the known providers {list(PROVIDER_CHAIN)} is installed "
                f"(installed: {have}); name an installed one, or pip install onnxruntime",
            )
        return chosen
    wanted = list(dict.fromkeys(canonical_provider(p) for p in configured))
    if not wanted:
        raise _refused(
            PROVIDERS_SETTING,
            "is empty: name at least one provider, or remove the setting for the default chain",
        )
    chosen = [p for p in wanted if p in set(have)]
    if not chosen:
        raise _refused(
            PROVIDERS_SETTING,
            f"none of {wanted} is installed (installed onnxruntime providers: {have}); name "
            "installed providers, or remove the setting for the default chain",
        )
    return chosen


def providers_not_installed(
    configured: Sequence[str] | None, installed: Sequence[str]
) -> tuple[str, ...]:
    """The providers of ``configured`` (canonical names, in its order) that ``installed``
    lacks: :func:`resolve_providers` leaves them out, and the runtime says so as a WARNING at
    start-up (a flight config naming TensorRT on a CPU-only onnxruntime runs on the CPU).
    Without ``configured`` (the default chain: the installed ones), none."""
    if configured is None:
        return ()
    have = {str(p) for p in installed}
    wanted = dict.fromkeys(canonical_provider(p) for p in configured)
    return tuple(p for p in wanted if p not in have)


def select_providers(available: Sequence[str]) -> list[str]:
    """The default provider list over ``available`` (see :func:`resolve_providers`)."""
    return resolve_providers(None, available)


@dataclass(frozen=True, slots=True)
class ProviderSettings:
    """Per-provider options: ``device_id`` (CUDA, TensorRT, ROCm, MIGraphX, DirectML),
    ``gpu_mem_limit_bytes`` (CUDA, ROCm arena limit), ``tensorrt_fp16``, and raw ``extra``
    options by provider name or alias (merged last; ``canonical_provider_options``)."""

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
    limit; ``extra`` options are merged per provider (``ConfigurationError`` naming
    ``[engines] provider_options`` for a key no provider has, or options for the CPU provider:
    never dropped silently)."""
    cfg = settings or ProviderSettings()
    extra = canonical_provider_options(cfg.extra)
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
        opts.update(extra.get(name, {}))
        if not opts:
            out.append(name)
        else:
            out.append((name, opts))
    return out
