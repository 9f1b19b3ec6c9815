"""Configuration: defaults, TOML, environment, and refusals that name the field."""

from __future__ import annotations

import pytest

from c3_matcher.config import load_settings
from c3_matcher.errors import ConfigurationError


def test_defaults_follow_decisions_14():
    s = load_settings(env={})
    m = s.matcher
    assert (
        m.strategy,
        m.min_inliers_threshold,
        m.residual_warn_threshold_px,
        m.ransac_threshold_px,
        m.max_long_side,
        m.max_keypoints,
    ) == ("disk_lightglue", 60, 2.5, 3.0, 1024, None)


def test_toml_then_environment_override(tmp_path):
    toml = tmp_path / "c3.toml"
    toml.write_text(
        '[matcher]\nmin_inliers_threshold = 80\nstrategy = "xfeat"\n'
        '[engines]\ndirectory = "/opt/engines"\n'
    )
    s = load_settings(toml, env={"C3_MATCHER_MATCHER__STRATEGY": "aliked_lightglue"})
    assert s.matcher.min_inliers_threshold == 80
    assert s.matcher.strategy == "aliked_lightglue"
    assert str(s.engines.directory) == "/opt/engines"


@pytest.mark.parametrize(
    ("text", "field"),
    [
        ("[matcher]\nmin_inliers_threshold = 2\n", "matcher.min_inliers_threshold"),
        ("[matcher]\nmin_inlier_threshold = 80\n", "matcher.min_inlier_threshold"),
        ("[matchr]\nstrategy = 'x'\n", "matchr"),
        ("[matcher]\nresidual_warn_threshold_px = -1\n", "matcher.residual_warn_threshold_px"),
        ("[logging]\nlevel = 'LOUD'\n", "logging.level"),
    ],
)
def test_bad_or_unknown_values_are_refused_naming_the_field(tmp_path, text, field):
    toml = tmp_path / "c3.toml"
    toml.write_text(text)
    with pytest.raises(ConfigurationError) as info:
        load_settings(toml, env={})
    assert field in [f for f, _ in info.value.problems]


@pytest.mark.parametrize("text", ["[matcher]\nmin_inlier_threshold = 80\n", "[matchr]\nx = 1\n"])
def test_an_unknown_key_in_the_file_is_named_a_misspelling_as_in_the_environment(tmp_path, text):
    toml = tmp_path / "c3.toml"
    toml.write_text(text)
    with pytest.raises(ConfigurationError) as info:
        load_settings(toml, env={})
    assert [r for _, r in info.value.problems] == ["unknown setting (check the spelling)"]


@pytest.mark.parametrize("where", ["file", "environment"])
def test_the_specifications_engine_file_key_names_where_engines_are_found(tmp_path, where):
    """``[matcher] disk_weights_path`` (the component specification's key for the DISK engine
    file) read as a misspelling; it is told that engines are found in ``[engines] directory``."""
    toml = tmp_path / "c3.toml"
    toml.write_text('[matcher]\ndisk_weights_path = "disk.onnx"\n' if where == "file" else "")
    env = {} if where == "file" else {"C3_MATCHER_MATCHER__DISK_WEIGHTS_PATH": "disk.onnx"}
    with pytest.raises(ConfigurationError) as info:
        load_settings(toml, env=env)
    ((field, reason),) = info.value.problems
    assert field.lower().endswith("disk_weights_path"), field
    assert reason.startswith("not a setting") and "[engines] directory" in reason, reason


def test_unknown_environment_variable_is_refused():
    with pytest.raises(ConfigurationError, match="C3_MATCHER_MATCHER__MIN_INLIER_THRESHOLD"):
        load_settings(env={"C3_MATCHER_MATCHER__MIN_INLIER_THRESHOLD": "80"})
    with pytest.raises(ConfigurationError, match="matcher.min_inliers_threshold"):
        load_settings(env={"C3_MATCHER_MATCHER__MIN_INLIERS_THRESHOLD": "many"})
    with pytest.raises(ConfigurationError, match="C3_MATCHER_MATCHR__STRATEGY"):
        load_settings(env={"C3_MATCHER_MATCHR__STRATEGY": "xfeat"})


def test_process_switches_are_not_settings():
    """Single-word C3_MATCHER_* variables that name no section are switches of the command and
    the tools (C3_MATCHER_TRACEBACK, C3_MATCHER_TOOLS_NO_PYPROJ), not settings."""
    env = {"C3_MATCHER_TOOLS_NO_RASTERIO": "1", "C3_MATCHER_TRACEBACK": "1"}
    assert load_settings(env=env).matcher.strategy == "disk_lightglue"


def test_unreadable_file_is_named(tmp_path):
    with pytest.raises(ConfigurationError, match="file not found"):
        load_settings(tmp_path / "missing.toml", env={})
    bad = tmp_path / "bad.toml"
    bad.write_text("[matcher\n")
    with pytest.raises(ConfigurationError, match="unreadable TOML"):
        load_settings(bad, env={})


def test_a_given_environment_is_read_alone_and_the_process_environment_left_untouched(
    monkeypatch,
):
    import os

    monkeypatch.setenv("C3_MATCHER_MATCHER__MIN_INLIERS_THRESHOLD", "99")
    before = dict(os.environ)
    given = load_settings(env={"C3_MATCHER_MATCHER__RANSAC_SEED": "7"})
    assert given.matcher.min_inliers_threshold == 60  # os.environ's value not read
    assert given.matcher.ransac_seed == 7
    assert dict(os.environ) == before
    assert load_settings().matcher.min_inliers_threshold == 99  # default: os.environ
