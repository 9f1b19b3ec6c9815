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


def test_the_runs_keypoint_budget_wins_over_the_options(engine_dir, monkeypatch) -> None:
    """``--max-keypoints`` (``[matcher] max_keypoints``) is the run's budget, as the plugin guide
    tells authors; the example applied its own option's 512 whatever the run asked."""
    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parents[1] / "src"))
    from c3_matcher_example_fast_disk.plugin import Options, make_config

    settings = c3.C3Settings(engines={"directory": engine_dir})
    assert make_config(settings, Options()).max_keypoints == 512
    assert make_config(settings, Options(max_keypoints=256)).max_keypoints == 256
    run = settings.model_copy(
        update={"matcher": settings.matcher.model_copy(update={"max_keypoints": 64})}
    )
    assert make_config(run, Options(max_keypoints=256)).max_keypoints == 64
