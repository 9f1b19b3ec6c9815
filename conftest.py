"""Fixtures shared by every test directory of the workspace.

``engine_dir``: the real ONNX engines the installed plugins declare, built once per machine by
the real engine compiler (``c3-matcher engines build``'s code path) and cached in
``$C3_MATCHER_ENGINE_DIR`` or the default engine directory (``<repo>/.engines/`` for this
checkout, where ``c3-matcher`` itself looks); valid engines are reused, so only a fresh
clone pays the build (about two minutes on two cores). Nothing is skipped: a test that needs
engines gets them built. ``read_image`` and ``gorinchem``: real imagery from ``data/imagery``.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

REPO = Path(__file__).resolve().parent


@pytest.fixture(scope="session")
def engine_dir() -> Path:
    from c3_matcher.compose import build_plugin_host
    from c3_matcher.engines.store import default_engine_dir
    from c3_matcher_tools.engines.compiler import ensure_engines

    directory = Path(os.environ.get("C3_MATCHER_ENGINE_DIR") or default_engine_dir())
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
