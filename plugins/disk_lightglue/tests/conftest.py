"""Fixtures of the DISK plugin's engine tests: its real engines (found in the workspace's engine
directory, which the root ``engine_dir`` fixture fills), real imagery, and the PyTorch
references its exporters verify against (kornia's DISK and LightGlue, the same weights)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from c3_matcher.engines.runtime import OnnxInferenceRuntime
from c3_matcher.engines.store import EngineStore
from c3_matcher_disk_lightglue.engines import DISK_SPEC, LIGHTGLUE_DISK_SPEC


@pytest.fixture(scope="session")
def disk_engine(engine_dir: Path) -> Path:
    return EngineStore(engine_dir).require(DISK_SPEC.model, DISK_SPEC.variant)


@pytest.fixture(scope="session")
def lightglue_engine(engine_dir: Path) -> Path:
    return EngineStore(engine_dir).require(LIGHTGLUE_DISK_SPEC.model, LIGHTGLUE_DISK_SPEC.variant)


@pytest.fixture(scope="session")
def runtime() -> OnnxInferenceRuntime:
    return OnnxInferenceRuntime(["CPUExecutionProvider"])


@pytest.fixture(scope="session")
def disk_reference() -> Any:
    from c3_matcher_disk_lightglue.export import load_disk_reference

    return load_disk_reference(DISK_SPEC.weights.resolve())


@pytest.fixture(scope="session")
def lightglue_reference() -> Any:
    from c3_matcher_tools.engines.export.lightglue import load_lightglue_reference

    return load_lightglue_reference(
        LIGHTGLUE_DISK_SPEC.weights.resolve(),
        input_dim=int(LIGHTGLUE_DISK_SPEC.option("input_dim")),
    )
