"""Fixtures of the DISK plugin's engine tests: its real engines (found in the workspace's engine
directory, which the root ``engine_dir`` fixture fills), real imagery, and the PyTorch
references its exporters verify against (kornia's DISK and LightGlue, the same weights)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from numpy.typing import NDArray

from c3_matcher.engines.runtime import OnnxInferenceRuntime
from c3_matcher.engines.store import EngineStore
from c3_matcher_disk_lightglue.engines import DISK_SPEC, LIGHTGLUE_DISK_SPEC

IMAGERY = Path(__file__).resolve().parents[3] / "data" / "imagery"


def read_rgb(relative: str) -> NDArray[np.uint8]:
    """A fixture image under ``data/imagery`` as RGB uint8 (H, W, 3)."""
    bgr = cv2.imread(str(IMAGERY / relative), cv2.IMREAD_COLOR)
    assert bgr is not None, f"fixture image {IMAGERY / relative} is missing"
    return np.ascontiguousarray(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))


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
def gorinchem() -> NDArray[np.uint8]:
    return read_rgb("open_orthophotos/test_tiled.tif")


@pytest.fixture(scope="session")
def read_image() -> Callable[[str], NDArray[np.uint8]]:
    """``read_image("naip_timeseries/....tif")``: a fixture image as RGB uint8."""
    return read_rgb


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
