"""Fixtures of the core's engine tests: real engines found in the workspace's engine directory
(the root ``engine_dir`` fixture builds what the installed plugins declare), real imagery, and a
tiny synthetic engine for the manifest checks. Core only: the engines are found by the core's
``EngineStore``, as at run time; the exporters, the compiler and the PyTorch references live
with the ground tools and the plugins (their tests sit beside them).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import onnx
import pytest

from c3_matcher.engines.manifest import EngineManifest
from c3_matcher.engines.naming import EngineName
from c3_matcher.engines.runtime import OnnxInferenceRuntime
from c3_matcher.engines.spec import TensorSpec, file_sha256
from c3_matcher.engines.store import EngineStore

REAL_ENGINES = (("disk", "depth"), ("lightglue", "disk"), ("lightglue", "disk-steps"))
"""The real engines the core's tests run: the default strategy's extractor, its single-graph
LightGlue and its steps LightGlue."""


@pytest.fixture(scope="session")
def built_engines(engine_dir: Path) -> dict[tuple[str, str], Path]:
    store = EngineStore(engine_dir)
    return {key: store.require(*key) for key in REAL_ENGINES}


@pytest.fixture(scope="session")
def disk_engine(built_engines: dict[tuple[str, str], Path]) -> Path:
    return built_engines[("disk", "depth")]


@pytest.fixture(scope="session")
def lightglue_engine(built_engines: dict[tuple[str, str], Path]) -> Path:
    return built_engines[("lightglue", "disk")]


@pytest.fixture(scope="session")
def runtime() -> OnnxInferenceRuntime:
    return OnnxInferenceRuntime(["CPUExecutionProvider"])


TINY_INPUTS = (TensorSpec("x", "float32", (1, "n")),)
TINY_OUTPUTS = (TensorSpec("y", "float32", (1, "n")),)


def write_tiny_onnx(path: Path, input_name: str = "x", output_name: str = "y") -> None:
    """An Identity graph ``y = x`` with x float32 (1, n)."""
    x = onnx.helper.make_tensor_value_info(input_name, onnx.TensorProto.FLOAT, [1, "n"])
    y = onnx.helper.make_tensor_value_info(output_name, onnx.TensorProto.FLOAT, [1, "n"])
    node = onnx.helper.make_node("Identity", [input_name], [output_name])
    graph = onnx.helper.make_graph([node], "tiny", [x], [y])
    model = onnx.helper.make_model(graph, opset_imports=[onnx.helper.make_opsetid("", 18)])
    model.ir_version = 9
    onnx.save(model, str(path))


def write_tiny_engine(
    directory: Path,
    *,
    variant: str = "tiny",
    inputs: tuple[TensorSpec, ...] = TINY_INPUTS,
    outputs: tuple[TensorSpec, ...] = TINY_OUTPUTS,
    build_key: str = "ab" * 32,
    passed: bool = True,
) -> Path:
    """A tiny engine plus a consistent manifest (declaring ``inputs``/``outputs``)."""
    directory.mkdir(parents=True, exist_ok=True)
    name = EngineName.from_build_key("toy", variant, "fp32", "any", 18, build_key)
    path = directory / name.filename
    write_tiny_onnx(path)
    EngineManifest(
        file=name.filename,
        file_sha256=file_sha256(path),
        file_bytes=path.stat().st_size,
        model="toy",
        variant=variant,
        kind="extractor",
        precision="fp32",
        input_rule="any",
        opset=18,
        build_key=build_key,
        weights={"distribution": "none", "version": "0", "path": "none", "sha256": "cd" * 32},
        inputs=inputs,
        outputs=outputs,
        exporter={"callable": "tests:none"},
        options={},
        verification={"passed": passed, "checks": []},
        build_seconds=0.0,
        built_at="2026-01-01T00:00:00+00:00",
    ).write(directory / name.manifest_filename)
    return path


@pytest.fixture()
def tiny_engine(tmp_path: Path) -> Path:
    return write_tiny_engine(tmp_path / "engines")


@pytest.fixture()
def make_tiny_engine() -> Callable[..., Path]:
    return write_tiny_engine
