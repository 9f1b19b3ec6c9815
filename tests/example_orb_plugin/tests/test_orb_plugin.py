"""The ORB example plugin: the core's contract kit for any backend, and the real path on the
demo's real imagery (discovered by the plugin host, created by its factory, matched with real
OpenCV RANSAC)."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path
from types import ModuleType

import cv2
import numpy as np

from c3_matcher.config import C3Settings
from c3_matcher.dto import TileId
from c3_matcher.fdr import InMemoryFdr
from c3_matcher.health import RollingHealthWindow
from c3_matcher.pipeline import FeatureBackend
from c3_matcher.plugins import PluginHost
from c3_matcher.plugins.manager import PluginSource
from c3_matcher.profiles import BuildProfile
from c3_matcher.ransac import OpenCvRansacFilter
from c3_matcher.testing import FakeClock, FakeInferenceRuntime, FakeLightGlueRuntime
from c3_matcher.testing.contract import BackendContract
from c3_matcher.testing.strategy_kit import compose_ready
from c3_matcher_tools.run.inputs import demo_inputs

HERE = Path(__file__).resolve().parents[1]
DEMO = HERE.parents[1] / "data" / "demo"


def load_plugin() -> ModuleType:
    """The plugin module from its source file (the workspace does not install this example)."""
    path = HERE / "src" / "c3_matcher_example_orb" / "plugin.py"
    spec = importlib.util.spec_from_file_location("c3_matcher_example_orb.plugin", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


PLUGIN = load_plugin()


def test_plugin_stays_whole_in_the_guide() -> None:
    """docs/plugins.md shows the plugin whole, with its line count: both stay as they are."""
    lines = (HERE / "src" / "c3_matcher_example_orb" / "plugin.py").read_text().splitlines()
    guide = (HERE.parents[1] / "docs" / "plugins.md").read_text()
    assert (
        len(lines) <= 55
        and f"`tests/example_orb_plugin` in the repository, {len(lines)} lines" in guide
    )
    assert "\n".join(lines) in guide


class TestOrbContract(BackendContract):
    def make_backend(self) -> FeatureBackend:
        backend: FeatureBackend = PLUGIN.OrbBackend(max_keypoints=1000)
        return backend


def test_descriptors_stay_binary() -> None:
    features = TestOrbContract()._textured()
    assert features.descriptors.dtype == np.uint8 and features.descriptors.shape[1] == 32


def test_real_demo_frame_through_the_plugin_host() -> None:
    """Composed as the flight software composes any strategy (the runtimes it is handed are
    the allowed doubles: ORB never calls them; RANSAC is OpenCV's)."""
    profile = BuildProfile.from_data({"name": "research", "strict": False, "flags": {}}, "test")
    source = PluginSource("example_orb", "c3-matcher-example-orb", "0.1.0", module=PLUGIN)
    settings = C3Settings(
        matcher={"strategy": "example_orb", "options": {"example_orb": {"max_keypoints": 3000}}}
    )
    pre = {
        "c7_inference": FakeInferenceRuntime(),
        "c3_lightglue_runtime": FakeLightGlueRuntime(),
        "c282_ransac_filter": OpenCvRansacFilter(),
        "clock": FakeClock(),
    }
    root, ready = compose_ready(settings, pre, plugin_host=PluginHost(profile, [source]))
    assert ready["provider"] == f"opencv {cv2.__version__}"  # the backend's, not the runtime's
    matcher = root.matcher
    frame, rerank, calibration = demo_inputs(DEMO)
    result = matcher.match(frame, rerank, calibration)
    best = result.per_candidate[result.best_candidate_idx]
    truth = next(t for t in json.loads((DEMO / "demo.json").read_text())["tiles"] if t["true"])
    assert best.tile_id == TileId(*truth["tile_id"])
    assert best.inlier_count >= 200 and best.per_candidate_residual_px < 2.0  # 1043, 0.82 px
    assert result.matcher_label == "example_orb"
    assert isinstance(root.fdr, InMemoryFdr) and root.fdr.of_kind("matcher.frame_done")


def test_create_with_the_kit_fixtures(c3_fake_clock: FakeClock, c3_fdr: InMemoryFdr) -> None:
    """The strategy's ``create`` over the fixtures the core's pytest plugin gives every plugin's
    tests: the frame is stamped on the fake clock and recorded in the in-memory FDR, and the
    health window forgets it once that clock has moved a minute on."""
    settings = C3Settings(matcher={"strategy": "example_orb"})
    health = RollingHealthWindow(c3_fake_clock, settings.matcher.min_inliers_threshold)
    matcher = PLUGIN.create(
        settings,
        ransac_filter=OpenCvRansacFilter(),
        fdr_client=c3_fdr,
        health_window=health,
        clock=c3_fake_clock,
    )
    result = matcher.match(*demo_inputs(DEMO))
    assert result.matched_at == c3_fake_clock.now_ns
    assert len(c3_fdr.of_kind("matcher.frame_done")) == 1
    assert health.snapshot().mean_inliers_60s > 0
    c3_fake_clock.advance(61)
    assert health.snapshot().mean_inliers_60s == 0.0
