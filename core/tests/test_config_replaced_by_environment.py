"""A table (or section) set in the environment replaces the configuration file's whole, as the
README says; the file's values it leaves out no longer apply. That is said: ``c3-matcher
config`` shows each such value of the file as a comment naming the variable that replaced it,
every command that reads the file says it in one stderr line, and ``load_settings`` (the Python
entry point) logs one WARNING record. It was silent: a file's ``[matcher.options.xfeat] matcher
= "lighterglue"`` with ``C3_MATCHER_MATCHER__OPTIONS__XFEAT='{"max_keypoints": 1024}'`` ran
XFeat with mutual nearest neighbours without a word. An environment that sets what the file
does not have, or a value in place of the file's, says nothing."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import pytest

from c3_matcher.cli import main
from c3_matcher.config import load_settings
from c3_matcher.config_sources import ReplacedValue

from .conftest import LogCapture

XFEAT = "C3_MATCHER_MATCHER__OPTIONS__XFEAT"
LIGHTERGLUE = '[matcher]\nstrategy = "xfeat"\n[matcher.options.xfeat]\nmatcher = "lighterglue"\n'


@pytest.fixture
def toml(tmp_path: Path) -> Path:
    path = tmp_path / "c3.toml"
    path.write_text(LIGHTERGLUE)
    return path


def test_config_shows_the_files_value_the_environment_replaced(
    clean_env: pytest.MonkeyPatch, toml: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    clean_env.setenv(XFEAT, '{"max_keypoints": 1024}')
    assert main(["--config", str(toml), "config"]) == 0
    out, err = capsys.readouterr()
    comment = f'# matcher.options.xfeat.matcher = "lighterglue" from {toml}: replaced by {XFEAT}'
    assert comment in out.splitlines(), out
    assert tomllib.loads(out)["matcher"]["options"] == {"xfeat": {"max_keypoints": 1024}}
    (line,) = err.splitlines()
    assert str(toml) in line and "matcher.options.xfeat.matcher" in line and XFEAT in line


def test_every_command_reading_the_file_says_it_in_one_stderr_line(
    clean_env: pytest.MonkeyPatch, toml: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    clean_env.setenv(XFEAT, '{"max_keypoints": 1024}')
    assert main(["plugins", "--json", "--config", str(toml)]) == 0
    out, err = capsys.readouterr()
    assert json.loads(out)["selected"] == "xfeat"  # the result alone on stdout
    (line,) = err.splitlines()
    assert line.startswith("c3-matcher: note: ") and "do not apply" in line, line
    assert f"matcher.options.xfeat.matcher ({XFEAT})" in line, line


@pytest.mark.parametrize(
    ("variable", "value"),
    [
        (XFEAT, {"matcher": "mnn"}),  # the file's one key given again
        ("C3_MATCHER_MATCHER__OPTIONS__ALIKED", {"top_k": 1024}),  # a table the file lacks
        ("C3_MATCHER_MATCHER__MIN_INLIERS_THRESHOLD", 80),  # a setting the file lacks
        ("C3_MATCHER_MATCHER__STRATEGY", "xfeat"),  # a value in place of the file's
    ],
)
def test_an_environment_that_leaves_the_files_values_applying_says_nothing(
    clean_env: pytest.MonkeyPatch,
    toml: Path,
    capsys: pytest.CaptureFixture[str],
    variable: str,
    value: object,
) -> None:
    clean_env.setenv(variable, value if isinstance(value, str) else json.dumps(value))
    assert main(["--config", str(toml), "plugins"]) == 0
    assert capsys.readouterr().err == ""
    assert load_settings(toml).replaced_by_environment.values == ()


def test_a_sections_json_names_each_value_of_the_file_it_leaves_out(tmp_path: Path) -> None:
    toml = tmp_path / "c3.toml"
    toml.write_text(
        "[matcher]\nmin_inliers_threshold = 80\n"
        '[matcher.options.xfeat]\nmatcher = "lighterglue"\nmax_keypoints = 512\n'
        "[matcher.options.other]\na = 1\nb = [1, 2]\n"
    )
    given = {"options": {"xfeat": {"max_keypoints": 1024}}, "min_inliers_threshold": 90}
    settings = load_settings(toml, env={"C3_MATCHER_MATCHER": json.dumps(given)})
    replaced = settings.replaced_by_environment
    assert replaced.file == toml
    assert replaced.values == (
        ReplacedValue("matcher.options.other.a", 1, "C3_MATCHER_MATCHER"),
        ReplacedValue("matcher.options.other.b", [1, 2], "C3_MATCHER_MATCHER"),
        ReplacedValue("matcher.options.xfeat.matcher", "lighterglue", "C3_MATCHER_MATCHER"),
    )
    assert settings.matcher.options == {"xfeat": {"max_keypoints": 1024}}  # the rule kept


def test_load_settings_logs_one_warning_naming_the_keys_and_variable(
    toml: Path, logs: LogCapture
) -> None:
    load_settings(toml, env={XFEAT: '{"max_keypoints": 1024}'})
    (record,) = logs.of_kind("c3.config.file_values_replaced")
    assert record["level"] == "WARNING"
    assert record["keys"] == ["matcher.options.xfeat.matcher"]
    assert record["variables"] == [XFEAT]
    assert "matcher.options.xfeat.matcher" in record["message"] and XFEAT in record["message"]
    load_settings(toml, env={})
    assert len(logs.of_kind("c3.config.file_values_replaced")) == 1  # nothing replaced: silent
