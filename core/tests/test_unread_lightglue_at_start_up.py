"""A ``[lightglue]`` value the user set for a strategy that does not match with LightGlue (XFeat
with mutual nearest neighbours, the SIFT baseline) is said at start-up: one WARNING
``c3.config.ignored`` naming the settings and the strategy, on stderr and in the flight data
recorder; the run goes on (a site file tuned for DISK must still run XFeat). It was accepted
and changed nothing, without a word: the README's demo match with
``C3_MATCHER_LIGHTGLUE__FILTER_THRESHOLD=0.99 --strategy xfeat`` gave the same result."""

from __future__ import annotations

import json
import types
from pathlib import Path
from typing import Any

import pytest
from pydantic import BaseModel

from c3_matcher.cli import main

from .conftest import LogCapture
from .demo_match import DEMO_MATCH

KIND = "c3.config.ignored"


def _ignored(capsys: pytest.CaptureFixture[str], *extra: str) -> list[dict[str, Any]]:
    """The demo match (with ``extra`` arguments, exit 0): its ``KIND`` records on stderr."""
    assert main([*DEMO_MATCH, *extra]) == 0, capsys.readouterr().err[-2000:]
    records = [json.loads(line) for line in capsys.readouterr().err.splitlines()]
    return [r for r in records if r["kind"] == KIND]


def test_the_baseline_says_the_lightglue_settings_it_does_not_read(
    clean_env: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    clean_env.setenv("C3_MATCHER_LIGHTGLUE__FILTER_THRESHOLD", "0.99")
    clean_env.setenv("C3_MATCHER_LIGHTGLUE__EXIT_MATCHES", "4")
    clean_env.setenv("C3_MATCHER_LIGHTGLUE__MODE", "auto")  # the default: changes nothing
    (record,) = _ignored(capsys)
    assert record["level"] == "WARNING" and record["strategy"] == "sift_magsac"
    assert record["settings"] == ["lightglue.filter_threshold", "lightglue.exit_matches"]
    assert record["message"].startswith(
        "lightglue.filter_threshold, lightglue.exit_matches set, but strategy sift_magsac "
        "does not match with LightGlue"
    )
    fdr = [json.loads(line) for line in (tmp_path / "fdr.jsonl").read_text().splitlines()]
    assert [r["payload"]["kind"] for r in fdr if r["kind"] == "log.warning"].count(KIND) == 1


def test_nothing_is_said_when_the_user_set_no_lightglue_value(
    clean_env: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    assert _ignored(capsys) == []


def test_the_readme_demo_match_with_xfeat_says_the_filter_threshold_is_unread(
    clean_env: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], engine_dir: Path
) -> None:
    clean_env.setenv("C3_MATCHER_ENGINES__DIRECTORY", str(engine_dir))
    clean_env.setenv("C3_MATCHER_LIGHTGLUE__FILTER_THRESHOLD", "0.99")
    (record,) = _ignored(capsys, "--strategy", "xfeat")
    assert (record["strategy"], record["settings"]) == ("xfeat", ["lightglue.filter_threshold"])


def test_settings_the_strategys_defaults_filled_say_nothing(clean_env: pytest.MonkeyPatch) -> None:
    """A ground worker is handed settings already composed for its strategy (as JSON): every
    field is set there, each to what would apply unset; a value the user set still counts."""
    from c3_matcher.compose import build_plugin_host, strategy_settings
    from c3_matcher.config import C3Settings, load_settings
    from c3_matcher.unread_settings import unread_lightglue

    host = build_plugin_host()
    spec = host.resolve("xfeat")
    engines = host.strategy_engine_specs("xfeat")
    options = spec.options_model.model_validate({}) if spec.options_model else None
    composed = strategy_settings(load_settings(), "xfeat", host)
    handed = C3Settings.model_validate_json(composed.model_dump_json())
    assert handed.lightglue.model_fields_set >= {"filter_threshold", "exit_matches", "mode"}
    assert unread_lightglue(handed, options, engines, spec.defaults) == ()
    clean_env.setenv("C3_MATCHER_LIGHTGLUE__EXIT_MATCHES", "3")
    given = strategy_settings(load_settings(), "xfeat", host)
    assert unread_lightglue(given, options, engines, spec.defaults) == ("lightglue.exit_matches",)


class _SaysNoLightGlue(BaseModel):
    """Options that declare their pair matcher (``PairMatcherOptions``): never LightGlue."""

    def matches_with_lightglue(self) -> bool:
        return False


class _SaysNothing(BaseModel):
    """Options that choose nothing about the pair matcher."""


@pytest.mark.parametrize(
    ("options_model", "warned"),
    [(None, False), (_SaysNothing, False), (_SaysNoLightGlue, True)],
    ids=["no-options", "options-silent", "options-say-no"],
)
def test_only_a_strategy_declared_not_to_match_with_lightglue_is_warned(
    clean_env: pytest.MonkeyPatch,
    logs: LogCapture,
    tmp_path: Path,
    options_model: type[BaseModel] | None,
    warned: bool,
) -> None:
    """A plugin that declares no engines of its own (it takes another plugin's DISK and
    LightGlue, as the example plugin does) and whose options do not choose the pair matcher
    may read ``[lightglue]``: it was warned that its run is the same without a setting that
    changed it."""
    from c3_matcher.compose import compose_root
    from c3_matcher.config import C3Settings
    from c3_matcher.plugins import PluginHost, StrategySpec, hookimpl
    from c3_matcher.plugins.manager import PluginSource
    from c3_matcher.testing.hosts import RESEARCH_PROFILE, fake_helpers, pipeline_strategy

    spec = StrategySpec("reuses", pipeline_strategy(), options_model=options_model)
    module = types.SimpleNamespace(c3_matcher_strategies=hookimpl(lambda: [spec]))
    host = PluginHost(RESEARCH_PROFILE, [PluginSource("x", "x-dist", "0.1", module=module)])
    assert host.strategy_engine_specs("reuses") == []
    fdr_path = {"path": str(tmp_path / "fdr.jsonl")}
    given = {"matcher": {"strategy": "reuses"}, "lightglue": {"filter_threshold": 0.9}}
    settings = C3Settings(**given, fdr=fdr_path)
    compose_root(settings, fake_helpers(), plugin_host=host, configure_logs=False).close()
    said = [r["settings"] for r in logs.of_kind(KIND)]
    assert said == ([["lightglue.filter_threshold"]] if warned else [])


def test_the_answer_is_the_options_then_the_engines_declared_else_not_known() -> None:
    """Where the options choose the pair matcher, theirs; else a LightGlue-family engine among
    the plugin's own (a spec with a ``feature_type``); None where it declares neither."""
    from c3_matcher.keypoint_budget import reads_lightglue

    matcher = next(s for s in _installed_specs() if s.feature_type is not None)
    extractor = next(s for s in _installed_specs() if s.feature_type is None)
    assert reads_lightglue(None, []) is None
    assert reads_lightglue(_SaysNothing(), []) is None
    assert reads_lightglue(_SaysNothing(), [extractor]) is False
    assert reads_lightglue(None, [extractor, matcher]) is True
    assert reads_lightglue(_SaysNoLightGlue(), [extractor, matcher]) is False


def _installed_specs() -> list[Any]:
    """The engine specifications the installed plugins declare."""
    from c3_matcher.compose import build_plugin_host

    return list(build_plugin_host().engine_specs())
