"""The example plugin's own tests: the core's contract kit, for free."""

from __future__ import annotations

import types
from pathlib import Path
from typing import Any

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


def _composed(engine_dir: Path, spec: c3.StrategySpec) -> Any:
    """``compose_root`` over a host offering ``spec`` alone (fake runtimes, the real engine
    directory), its strategy selected."""
    from c3_matcher.compose import compose_root
    from c3_matcher.plugins.manager import PluginSource
    from c3_matcher.testing import InMemoryFdr
    from c3_matcher.testing.hosts import RESEARCH_PROFILE, fake_helpers

    module = types.SimpleNamespace(c3_matcher_strategies=c3.hookimpl(lambda: [spec]))
    host = c3.PluginHost(RESEARCH_PROFILE, [PluginSource("x", "x-dist", "0.1", module=module)])
    settings = c3.C3Settings(engines={"directory": engine_dir}, matcher={"strategy": spec.name})
    helpers = {**fake_helpers(), "c13_fdr": InMemoryFdr()}  # not the user's default FDR
    return compose_root(settings, helpers, plugin_host=host, configure_logs=False)


def test_a_strategy_s_own_defaults_reach_the_loop_it_runs(engine_dir, monkeypatch) -> None:
    """Defaults a strategy declares where the configuration leaves a setting unset
    (``photometric``: CLAHE here, unlike every shipped strategy's ``none``, which is also the
    loop's fallback) are what its per-frame loop runs with."""
    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parents[1] / "src"))
    from c3_matcher_example_fast_disk.plugin import NAME, Options, create

    defaults = c3.StrategyDefaults(photometric="clahe")
    spec = c3.StrategySpec(NAME, create, options_model=Options, defaults=defaults)
    root = _composed(engine_dir, spec)
    try:
        assert root.matcher.settings.photometric == "clahe"
    finally:
        root.close()


def test_a_make_config_of_two_parameters_as_plugins_wrote_it_before_still_composes(
    engine_dir, monkeypatch
) -> None:
    """``make_config(settings, options)``, opening the engine directory itself, was the
    documented form before the kit handed it over: such a plugin composes as it did, with the
    same config as the three-parameter form."""
    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parents[1] / "src"))
    from c3_matcher_example_fast_disk.plugin import Options, make_config

    def two(settings: c3.C3Settings, options: Options) -> c3.ExtractorLightGlueConfig:
        return make_config(settings, options, c3.EngineStore(settings.engines.directory))

    spec = c3.StrategySpec("old_form", c3.strategy_factory(c3.ExtractorMatcher, two, Options))
    root = _composed(engine_dir, spec)
    try:
        settings = c3.C3Settings(engines={"directory": engine_dir})
        expected = make_config(settings, Options(), c3.EngineStore(engine_dir))
        assert root.matcher.config == expected
    finally:
        root.close()
