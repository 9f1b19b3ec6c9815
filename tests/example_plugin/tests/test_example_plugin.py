"""The example plugin's own tests: the core's contract kit, for free."""

from __future__ import annotations

from pathlib import Path

from c3_matcher import plugins as c3
from c3_matcher.protocols import CrossDomainMatcher
from c3_matcher.testing.contract import Doubles, MatcherContract

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


class TestExampleContract(MatcherContract):
    extract_phase = "disk_forward"
    match_phase = "lightglue_match"

    def make_matcher(self, doubles: Doubles) -> CrossDomainMatcher:
        return c3.ExtractorMatcher(
            doubles.inference,
            doubles.lightglue,
            doubles.ransac,
            doubles.fdr,
            doubles.health,
            CONFIG,
            doubles.clock,
        )
