"""Fixtures shared by every test directory of the workspace.

``engine_dir``: the real ONNX engines the installed plugins declare, built once per machine by
the real engine compiler (``c3-matcher engines build``'s code path) and cached where
``c3-matcher`` itself looks: ``[engines] directory`` as the environment sets it
(``C3_MATCHER_ENGINES__DIRECTORY``), else the default (``<repo>/.engines/`` for this
checkout); valid engines are reused, so only a fresh clone pays the build (about two minutes
on two cores). Nothing is skipped: a test that needs engines gets them built. ``read_image``
and ``gorinchem``: real imagery from ``data/imagery``.

Every test runs in an environment of its own (``_own_environment``, autouse): no
``C3_MATCHER_*`` variable of the caller's (the environment outranks the settings a test gives,
so one set in the developer's shell would silently replace them; ``engine_dir`` reads the
engine directory's once, before), and the user data directory (``XDG_DATA_HOME``: the default
FDR) in the test's own temporary directory, so no test writes the user's flight-data record, nor
waits on another process writing it.
"""

from __future__ import annotations

import dataclasses
import os
import sys
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import onnx
import pytest

from c3_matcher.engines.manifest import EngineManifest
from c3_matcher.engines.naming import EngineName
from c3_matcher.engines.spec import TensorSpec, file_sha256

REPO = Path(__file__).resolve().parent
CALLER_ENVIRONMENT = {k: v for k, v in os.environ.items() if k.upper().startswith("C3_MATCHER_")}
"""The ``C3_MATCHER_*`` variables the suite was started with, read once at its start."""


@pytest.fixture(autouse=True)
def _own_environment(
    monkeypatch: pytest.MonkeyPatch, tmp_path_factory: pytest.TempPathFactory
) -> None:
    """No caller's ``C3_MATCHER_*`` variable, and the default FDR under a temporary
    ``XDG_DATA_HOME`` (a child process started by the test inherits both)."""
    for key in CALLER_ENVIRONMENT:
        monkeypatch.delenv(key, raising=False)
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path_factory.mktemp("user-data")))


@pytest.fixture(scope="session")
def engine_dir() -> Path:
    from c3_matcher.compose import build_plugin_host
    from c3_matcher.config import load_settings
    from c3_matcher_tools.engines.compiler import ensure_engines

    with pytest.MonkeyPatch.context() as caller:  # the engine directory the caller set
        for key, value in CALLER_ENVIRONMENT.items():
            caller.setenv(key, value)
        directory = load_settings().engines.directory
    specs = build_plugin_host().engine_specs()
    assert specs, "no installed plugin declares an engine: run scripts/setup"
    ensure_engines(specs, directory, log=lambda line: print(line, file=sys.stderr))
    return directory


def read_rgb(relative: str) -> Any:
    """A real fixture image under ``data/imagery`` as RGB uint8 (H, W, 3)."""
    import cv2
    import numpy as np

    path = REPO / "data" / "imagery" / relative
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    assert bgr is not None, f"fixture image {path} is missing"
    return np.ascontiguousarray(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))


@pytest.fixture(scope="session")
def read_image() -> Callable[[str], Any]:
    """``read_image("naip_timeseries/....tif")``: a real fixture image as RGB uint8."""
    return read_rgb


@pytest.fixture(scope="session")
def gorinchem() -> Any:
    """The Gorinchem orthophoto (``open_orthophotos/test_tiled.tif``) as RGB uint8."""
    return read_rgb("open_orthophotos/test_tiled.tif")


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
    passed: bool = True,
    export_revision: int = 1,
    options: Mapping[str, int | float | str] | None = None,
    built_at: str = "2026-01-01T00:00:00+00:00",
    feature_type: str | None = None,
    input_rule: str = "any",
    versions: Mapping[str, str] | None = None,
) -> Path:
    """A tiny engine plus a consistent manifest (declaring ``inputs``/``outputs``, built by
    ``export_revision`` of its exporter with ``options`` and library ``versions``, at
    ``built_at``, for ``feature_type`` features), named by the build key recomputed from its
    fields, as a build names it (other ``versions``: another build of the same graph)."""
    directory.mkdir(parents=True, exist_ok=True)
    manifest = EngineManifest(
        file="",
        file_sha256="",
        file_bytes=0,
        model="toy",
        variant=variant,
        kind="extractor",
        precision="fp32",
        input_rule=input_rule,
        opset=18,
        build_key="",
        weights={"distribution": "none", "version": "0", "path": "none", "sha256": "cd" * 32},
        inputs=inputs,
        outputs=outputs,
        exporter={
            "callable": "tests:none",
            "export_revision": str(export_revision),
            **(versions or {}),
        },
        options=dict(options or {}),
        verification={"passed": passed, "checks": []},
        build_seconds=0.0,
        built_at=built_at,
        feature_type=feature_type,
    )
    key = manifest.recomputed_key()
    name = EngineName.from_build_key("toy", variant, "fp32", input_rule, 18, key)
    path = directory / name.filename
    write_tiny_onnx(path)
    dataclasses.replace(
        manifest,
        file=name.filename,
        file_sha256=file_sha256(path),
        file_bytes=path.stat().st_size,
        build_key=key,
    ).write(directory / name.manifest_filename)
    return path


@pytest.fixture()
def tiny_engine(tmp_path: Path) -> Path:
    return write_tiny_engine(tmp_path / "engines")


@pytest.fixture()
def make_tiny_engine() -> Callable[..., Path]:
    return write_tiny_engine
