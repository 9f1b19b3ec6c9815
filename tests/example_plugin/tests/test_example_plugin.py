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


def test_the_keypoint_budget_is_the_options_then_the_configurations_then_512(
    engine_dir, monkeypatch
) -> None:
    """The strategy's own option is the more specific; ``--max-keypoints`` clears it
    (``with_keypoint_budget``), so a run's flag is above both. The example applied its option's
    512 whatever the run asked."""
    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parents[1] / "src"))
    from c3_matcher.commands import with_keypoint_budget
    from c3_matcher_example_fast_disk.plugin import Options, make_config

    engines = c3.EngineStore(engine_dir)
    settings = c3.C3Settings(engines={"directory": engine_dir})
    assert make_config(settings, Options(), engines).max_keypoints == 512
    configured = c3.C3Settings(
        engines={"directory": engine_dir},
        matcher={"max_keypoints": 1024, "options": {"example_fast_disk": {"max_keypoints": 256}}},
    )
    table = Options(**configured.matcher.options["example_fast_disk"])
    assert make_config(configured, table, engines).max_keypoints == 256
    assert make_config(configured, Options(), engines).max_keypoints == 1024
    run = with_keypoint_budget(configured, 64)
    cleared = Options(**run.matcher.options["example_fast_disk"])
    assert make_config(run, cleared, engines).max_keypoints == 64
