"""A configured execution provider the installed onnxruntime lacks is a WARNING at start-up.

``[engines] providers`` is a preference list: the providers that are not installed are left
out and the matcher runs on the rest, but a flight config naming TensorRT or CUDA on a CPU-only
onnxruntime (the airborne wheelhouse's) would otherwise run every frame on the CPU, seconds per
frame, with nothing at a level an operator watches. Composed with the real CPU onnxruntime of
this environment (CPU and Azure providers, no CUDA); the strategy's own runtimes are doubles:
what is checked is the shared runtime's start-up log, which comes before any strategy."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from c3_matcher.compose import build_default_helpers, compose_root
from c3_matcher.config import C3Settings
from c3_matcher.fdr import InMemoryFdr
from c3_matcher.testing import fake_helpers, one_strategy_host, pipeline_strategy

CUDA, TRT, CPU = "CUDAExecutionProvider", "TensorrtExecutionProvider", "CPUExecutionProvider"
NOT_INSTALLED = "c3.inference.provider_not_installed"


def _doubles_strategy(**kw: Any) -> Any:
    """A pipeline strategy over runtime doubles: it loads no engine of the real runtime."""
    doubles = fake_helpers()
    return pipeline_strategy()(
        **{
            **kw,
            "inference_runtime": doubles["c7_inference"],
            "lightglue_runtime": doubles["c3_lightglue_runtime"],
            "ransac_filter": doubles["c282_ransac_filter"],
        }
    )


def _compose(
    tmp_path: Path, providers: list[str], capsys: pytest.CaptureFixture[str]
) -> tuple[list[dict[str, Any]], InMemoryFdr]:
    """Compose and close a root over the real ONNX Runtime configured with ``providers``: its
    stderr log records and its FDR."""
    settings = C3Settings(
        matcher={"strategy": "doubles"},
        engines={"providers": providers},
        fdr={"path": tmp_path / "fdr.jsonl"},
    )
    host = one_strategy_host("doubles", _doubles_strategy)
    helpers = build_default_helpers(settings, plugin_host=host)  # the real onnxruntime
    fdr = InMemoryFdr()
    capsys.readouterr()
    compose_root(settings, {**helpers, "c13_fdr": fdr}, plugin_host=host).close()
    lines = capsys.readouterr().err.splitlines()
    return [json.loads(line) for line in lines if line.startswith("{")], fdr


@pytest.mark.parametrize(
    "configured", [["TensorRTExecutionProvider", CUDA, CPU], ["TensorRT", "CUDA", "CPU"]]
)
def test_a_configured_provider_not_installed_is_one_warning_naming_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], configured: list[str]
) -> None:
    records, fdr = _compose(tmp_path, configured, capsys)
    warned = [r for r in records if r["kind"] == NOT_INSTALLED]
    assert len(warned) == 1, [r["kind"] for r in records]
    warning = warned[0]
    assert warning["level"] == "WARNING"
    assert warning["requested"] == [TRT, CUDA, CPU]
    assert warning["not_installed"] == [TRT, CUDA] and warning["chain"] == [CPU]
    assert CUDA in warning["message"] and TRT in warning["message"]
    assert f"runs on {CPU}" in warning["message"]
    assert [p["kind"] for p in fdr.of_kind("log.warning")].count(NOT_INSTALLED) == 1
    selected = [r for r in records if r["kind"] == "c3.inference.provider_selected"]
    assert len(selected) == 1 and f"requested: {CPU}" not in selected[0]["message"]


def test_no_warning_when_every_configured_provider_is_installed(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    records, fdr = _compose(tmp_path, ["CPU"], capsys)
    assert not [r for r in records if r["kind"] == NOT_INSTALLED]
    assert not [r for r in records if r["level"] == "WARNING"], records
    assert not fdr.of_kind("log.warning")
    assert [r["chain"] for r in records if r["kind"] == "c3.inference.provider_selected"] == [[CPU]]
