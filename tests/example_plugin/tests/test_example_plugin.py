"""The example plugin's own tests: the core's contract kit, for free."""

from __future__ import annotations

from pathlib import Path

from c3_matcher import plugins as c3
from c3_matcher.testing.strategy_kit import ExtractorMatcherContract

CONFIG = c3.ExtractorLightGlueConfig(
    label="example_fast_disk",
    feature_type="disk",
    extract_phase="disk_forward",
    extractor_engine_path=Path("disk.onnx"),
    lightglue_engine_path=Path("lg.onnx"),
    size_multiple=16,
    max_long_side=64,
    max_keypoints=512,
)


class TestExampleContract(ExtractorMatcherContract):
    matcher_class = c3.ExtractorMatcher
    config = CONFIG
