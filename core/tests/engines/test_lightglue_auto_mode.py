"""``[lightglue] mode = "auto"`` is adaptive on a CPU and the full graph on a GPU, for the
provider the sessions ACTUALLY run on: onnxruntime-gpu whose CUDA libraries fail to load runs
every session on the CPU (``c3.inference.provider_fallback``), and LightGlue then runs adaptive,
as on any CPU, not the full graph.

The fallback is made as the provider tests make it: CUDA injected as available on this CPU-only
onnxruntime, whose sessions then run on the CPU. Real engines of disk_lightglue."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from loguru import logger

from c3_matcher.compose import build_default_helpers, build_plugin_host, compose_root
from c3_matcher.config import C3Settings
from c3_matcher.engines.lightglue import OnnxLightGlueRuntime
from c3_matcher.engines.lightglue_specs import steps_specs
from c3_matcher.engines.runtime import OnnxInferenceRuntime
from c3_matcher.engines.store import EngineStore
from c3_matcher.fdr import InMemoryFdr

CUDA = "CUDAExecutionProvider"
CPU = "CPUExecutionProvider"


@pytest.fixture(scope="module")
def steps_engine(engine_dir: Path) -> Path:
    return EngineStore(engine_dir).require("lightglue", "disk-steps")


@pytest.fixture(scope="module")
def declared() -> dict[str, Any]:
    return steps_specs(build_plugin_host().engine_specs())


def _loaded(inference: OnnxInferenceRuntime) -> list[str]:
    return sorted(inference.engine_path(i).name for i in inference.session_providers)


def test_auto_runs_adaptive_when_the_sessions_fell_back_to_the_cpu(
    engine_dir: Path, steps_engine: Path
) -> None:
    """The whole start-up, as ``c3-matcher match`` composes it."""
    settings = C3Settings(matcher={"strategy": "disk_lightglue"}, engines={"directory": engine_dir})
    assert settings.lightglue.mode == "auto"
    helpers = {**build_default_helpers(settings, (CUDA, CPU)), "c13_fdr": InMemoryFdr()}
    seen: list[dict[str, Any]] = []
    sink = logger.add(lambda m: seen.append(dict(m.record["extra"])), level="WARNING")
    try:
        root = compose_root(settings, helpers, configure_logs=False)
    finally:
        logger.remove(sink)
    try:
        inference, lightglue = helpers["c7_inference"], helpers["c3_lightglue_runtime"]
        assert inference.requested_provider == CUDA and inference.provider == CPU
        assert lightglue.mode == "adaptive"
        assert lightglue.serving_engine("disk") == steps_engine
        assert [e for e in seen if e.get("kind") == "c3.lightglue.mode_fallback"]
    finally:
        root.close()


def test_auto_takes_the_provider_of_sessions_loaded_before_it(
    disk_engine: Path, lightglue_engine: Path, steps_engine: Path, declared: dict[str, Any]
) -> None:
    """An extractor loaded first tells the provider: only the steps engine is then loaded."""
    inference = OnnxInferenceRuntime([CUDA, CPU])
    inference.load_engine(disk_engine)
    runtime = OnnxLightGlueRuntime(inference, mode="auto", steps_specs=declared)
    assert runtime.load("disk", lightglue_engine) == steps_engine
    assert runtime.mode == "adaptive"
    assert _loaded(inference) == sorted([disk_engine.name, steps_engine.name])


class _ReportsCuda(OnnxInferenceRuntime):
    """Sessions that say they run on CUDA (a GPU machine), for the control flow only."""

    @property
    def provider(self) -> str:
        return CUDA


def test_auto_keeps_the_full_graph_where_the_sessions_run_on_the_gpu(
    lightglue_engine: Path, declared: dict[str, Any]
) -> None:
    inference = _ReportsCuda([CUDA, CPU])
    runtime = OnnxLightGlueRuntime(inference, mode="auto", steps_specs=declared)
    assert runtime.load("disk", lightglue_engine) == lightglue_engine
    assert runtime.mode == "full"
    assert _loaded(inference) == [lightglue_engine.name]


def test_auto_on_a_requested_cpu_loads_only_the_steps_engine(
    lightglue_engine: Path, steps_engine: Path, declared: dict[str, Any]
) -> None:
    inference = OnnxInferenceRuntime([CPU])
    runtime = OnnxLightGlueRuntime(inference, mode="auto", steps_specs=declared)
    assert runtime.mode == "adaptive"
    assert runtime.load("disk", lightglue_engine) == steps_engine
    assert _loaded(inference) == [steps_engine.name]


def test_an_unknown_mode_is_refused_naming_the_modes() -> None:
    with pytest.raises(ValueError, match="auto, adaptive, full"):
        OnnxLightGlueRuntime(OnnxInferenceRuntime([CPU]), mode="steps")
