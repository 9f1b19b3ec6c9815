"""Provider selection with the provider list injected (DECISIONS 18)."""

from __future__ import annotations

from typing import Any

import pytest
from loguru import logger

from c3_matcher.engines.runtime import OnnxInferenceRuntime, select_providers
from c3_matcher.errors import ConfigurationError

TRT = "TensorrtExecutionProvider"
CUDA = "CUDAExecutionProvider"
CPU = "CPUExecutionProvider"


@pytest.mark.parametrize(
    ("available", "chain"),
    [
        ([CPU, CUDA, TRT], [TRT, CUDA, CPU]),
        ([CUDA, CPU], [CUDA, CPU]),
        ([CPU], [CPU]),
        (["AzureExecutionProvider", CPU], [CPU]),
        ([TRT, CPU], [TRT, CPU]),
    ],
)
def test_chain_order(available: list[str], chain: list[str]) -> None:
    assert select_providers(available) == chain
    runtime = OnnxInferenceRuntime(available)
    assert runtime.provider == chain[0]
    assert list(runtime.providers) == chain


def test_no_usable_provider() -> None:
    with pytest.raises(ConfigurationError, match="none of"):
        OnnxInferenceRuntime(["AzureExecutionProvider"])


def test_choice_is_logged_with_a_kind() -> None:
    records: list[dict[str, Any]] = []
    sink = logger.add(lambda message: records.append(message.record["extra"]), level="INFO")
    try:
        OnnxInferenceRuntime([CUDA, CPU]).log_selection()
    finally:
        logger.remove(sink)
    selected = [r for r in records if r.get("kind") == "c3.inference.provider_selected"]
    assert selected and selected[0]["provider"] == CUDA


def test_tensorrt_engine_cache_directory_is_passed_to_the_provider(tmp_path):
    from c3_matcher.engines.runtime import provider_options

    opts = provider_options(
        ["TensorrtExecutionProvider", "CUDAExecutionProvider", "CPUExecutionProvider"], tmp_path
    )
    name, trt = opts[0]
    assert name == "TensorrtExecutionProvider"
    assert trt["trt_engine_cache_enable"] is True
    assert trt["trt_engine_cache_path"] == str(tmp_path)
    assert opts[1:] == [
        ("CUDAExecutionProvider", {"cudnn_conv_algo_search": "DEFAULT"}),
        "CPUExecutionProvider",
    ]


def test_lightglue_auto_mode_is_adaptive_on_cpu_and_full_on_gpu_providers() -> None:
    from c3_matcher.config import LightGlueSettings
    from c3_matcher.engines.lightglue import resolve_mode

    assert LightGlueSettings().mode == "auto"
    assert resolve_mode("auto", "CPUExecutionProvider") == "adaptive"
    assert resolve_mode("auto", "CUDAExecutionProvider") == "full"
    assert resolve_mode("auto", "TensorrtExecutionProvider") == "full"
    assert resolve_mode("adaptive", "CUDAExecutionProvider") == "adaptive"
    assert resolve_mode("full", "CPUExecutionProvider") == "full"
    with pytest.raises(ValueError, match="steps"):
        resolve_mode("steps", "CPUExecutionProvider")


# -- provider honesty, and any provider with its options and their intersection ---------------
OPENVINO = "OpenVINOExecutionProvider"


def test_provider_reported_is_the_one_the_session_actually_uses(tiny_engine) -> None:
    """onnxruntime falls back to CPU when CUDA cannot start: report CPU, warn, not CUDA."""
    seen: list[dict[str, Any]] = []
    sink = logger.add(lambda m: seen.append(dict(m.record["extra"])), level="DEBUG")
    try:
        runtime = OnnxInferenceRuntime([CUDA, CPU])  # says CUDA is there; it is not
        assert runtime.requested_provider == CUDA
        engine_id = runtime.load_engine(tiny_engine)
    finally:
        logger.remove(sink)
    assert runtime.session_providers[engine_id] == (CPU,)
    assert runtime.provider == CPU  # what the ready log and FDR provenance read
    fallback = [e for e in seen if e.get("kind") == "c3.inference.provider_fallback"]
    assert fallback and fallback[0]["requested"] == CUDA and fallback[0]["actual"] == [CPU]
    loaded = [e for e in seen if e.get("kind") == "c3.inference.engine_loaded"]
    assert loaded[0]["providers"] == [CPU]


@pytest.mark.parametrize(
    ("configured", "installed", "chain"),
    [
        (["openvino", "cpu"], [CPU, OPENVINO], [OPENVINO, CPU]),
        (["CUDA", "TensorRT", "CPU"], [CPU, CUDA, TRT], [CUDA, TRT, CPU]),
        (["ROCm", "cpu"], [CPU], [CPU]),
        (
            ["CoreML", "DirectML", "CPU"],
            ["DmlExecutionProvider", CPU],
            ["DmlExecutionProvider", CPU],
        ),
        ([CUDA, CPU], [CPU, CUDA], [CUDA, CPU]),
    ],
)
def test_configured_providers_are_intersected_with_installed(configured, installed, chain):
    from c3_matcher.engines.runtime import resolve_providers

    assert resolve_providers(configured, installed) == chain
    assert list(OnnxInferenceRuntime(installed, requested=configured).providers) == chain


def test_unusable_provider_list_names_the_setting() -> None:
    with pytest.raises(ConfigurationError, match=r"\[engines\] providers") as info:
        OnnxInferenceRuntime([CPU], requested=["CUDA", "TensorRT"])
    assert "pip install onnxruntime" not in str(info.value)
    assert not str(info.value).startswith("engine ")  # a setting, not an engine to build
    with pytest.raises(
        ConfigurationError, match=r"\[engines\] providers.*unknown execution provider"
    ):
        OnnxInferenceRuntime([CPU], requested=["Quantum"])


def test_per_provider_options_and_threads(tmp_path) -> None:
    from c3_matcher.config import EngineSettings
    from c3_matcher.engines.runtime import ProviderSettings, provider_options

    opts = provider_options(
        [TRT, CUDA, CPU],
        tmp_path,
        ProviderSettings(
            device_id=1,
            gpu_mem_limit_bytes=1 << 30,
            tensorrt_fp16=False,
            extra={CUDA: {"cudnn_conv_algo_search": "HEURISTIC"}},
        ),
    )
    assert opts[0][1]["device_id"] == 1 and opts[0][1]["trt_fp16_enable"] is False
    assert opts[1] == (
        CUDA,
        {"device_id": 1, "gpu_mem_limit": 1 << 30, "cudnn_conv_algo_search": "HEURISTIC"},
    )
    assert opts[2] == CPU
    engines = EngineSettings(providers=("cuda", "cpu"), intra_op_threads=2, device_id=1)
    assert engines.providers == (CUDA, CPU)
    runtime = OnnxInferenceRuntime.from_settings(engines, providers_available=[CPU, CUDA])
    assert runtime.providers == (CUDA, CPU)


def test_config_refuses_unknown_or_empty_provider_lists() -> None:
    from c3_matcher.config import load_settings
    from c3_matcher.errors import ConfigurationError

    with pytest.raises(ConfigurationError, match="engines.providers"):
        load_settings(env={"C3_MATCHER_ENGINES__PROVIDERS": '["Quantum"]'})
    with pytest.raises(ConfigurationError, match="engines.providers"):
        load_settings(env={"C3_MATCHER_ENGINES__PROVIDERS": "[]"})


def test_lightglue_filter_threshold_reaches_the_runtime() -> None:
    from c3_matcher.compose import build_default_helpers, strategy_settings
    from c3_matcher.config import load_settings

    settings = load_settings(env={"C3_MATCHER_LIGHTGLUE__FILTER_THRESHOLD": "0.02"})
    assert build_default_helpers(settings)["c3_lightglue_runtime"].filter_threshold == 0.02
    unset = load_settings(env={})
    own = strategy_settings(unset).lightglue.filter_threshold  # the strategy's own default
    assert build_default_helpers(unset)["c3_lightglue_runtime"].filter_threshold == own


def test_tensorrt_fp16_is_opt_in(tmp_path) -> None:
    """FP16 is not verified against FP32 yet: the default asks TensorRT for FP32."""
    from c3_matcher.config import EngineSettings
    from c3_matcher.engines.runtime import ProviderSettings, provider_options

    assert EngineSettings().tensorrt_fp16 is False
    opts = provider_options([TRT, CPU], tmp_path, ProviderSettings())
    assert opts[0][1]["trt_fp16_enable"] is False


def test_the_runtime_of_the_settings_keeps_onnxruntimes_warnings_off_stderr(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """ONNX Runtime's own log is plain text on stderr, where every line is JSON; on a GPU it
    warns per convolution and input shape. The product's runtime sets it to errors."""
    import onnxruntime as ort

    from c3_matcher.config import EngineSettings

    levels: list[int] = []
    monkeypatch.setattr(ort, "set_default_logger_severity", levels.append)
    OnnxInferenceRuntime.from_settings(EngineSettings(), providers_available=[CPU])
    assert levels == [3]
