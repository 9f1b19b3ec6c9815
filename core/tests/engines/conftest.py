"""Fixtures of the core's engine tests: real engines found in the workspace's engine directory
(the root ``engine_dir`` fixture builds what the installed plugins declare) and real imagery;
the tiny synthetic engine for the manifest checks is in the workspace conftest. Core only: the
engines are found by the core's ``EngineStore``, as at run time; the exporters, the compiler and
the PyTorch references live with the ground tools and the plugins (their tests sit beside them).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from c3_matcher.engines.runtime import OnnxInferenceRuntime
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
