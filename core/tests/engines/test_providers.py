"""Provider selection with the provider list injected (DECISIONS 18)."""

from __future__ import annotations

from typing import Any

import pytest
from loguru import logger

from c3_matcher.engines.runtime import OnnxInferenceRuntime, select_providers
from c3_matcher.errors import EngineError

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
    with pytest.raises(EngineError, match="none of"):
        OnnxInferenceRuntime(["AzureExecutionProvider"])


def test_choice_is_logged_with_a_kind() -> None:
    records: list[dict[str, Any]] = []
    sink = logger.add(lambda message: records.append(message.record["extra"]), level="INFO")
    try:
        OnnxInferenceRuntime([CUDA, CPU])
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
    assert opts[1:] == ["CUDAExecutionProvider", "CPUExecutionProvider"]
