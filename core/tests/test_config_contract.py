"""The configuration as the command line keeps it, through ``c3-matcher`` itself (``main``):
every ``C3_MATCHER_`` variable the product does not read is refused, the test suite's own
switches included; one spelling of each variable, the documented upper-case one; a strategy
option is shown and recorded as the value it runs with; a relative path setting is made
absolute against the working directory when the settings are read, so every message names
where the product looked; and ``match``'s warnings about the inputs it was not given are JSON
log records on stderr, at the configured level, and in the flight data recorder."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from c3_matcher.cli import main

REPO = Path(__file__).resolve().parents[2]
DEMO = REPO / "data" / "demo"
FLIGHT = REPO / "data" / "flights" / "naip_demo"


def _config_json(capsys: pytest.CaptureFixture[str]) -> dict[str, Any]:
    assert main(["config", "--json"]) == 0, capsys.readouterr().err
    data: dict[str, Any] = json.loads(capsys.readouterr().out)
    return data


def _refusal(capsys: pytest.CaptureFixture[str], *argv: str) -> str:
    """The one line a refused configuration prints (exit 2, nothing on stdout)."""
    assert main(list(argv)) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    (line,) = captured.err.strip().splitlines()
    return line


def test_the_engine_dir_variable_is_refused_naming_the_setting_meant(
    clean_env: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """It was taken for a switch (the test suite's, no product code reads it) and ignored: the
    default engine directory was used, without a word."""
    clean_env.setenv("C3_MATCHER_ENGINE_DIR", str(tmp_path / "engines"))
    line = _refusal(capsys, "engines", "list")
    assert "C3_MATCHER_ENGINE_DIR" in line and "unknown setting" in line
    assert "did you mean C3_MATCHER_ENGINES__DIRECTORY?" in line


def test_a_refused_variable_lists_only_the_switches_the_product_reads(
    clean_env: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    clean_env.setenv("C3_MATCHER_FOO", "1")
    line = _refusal(capsys, "config")
    assert "C3_MATCHER_TRACEBACK" in line
    assert "ENGINE_DIR" not in line


@pytest.mark.parametrize(
    "spellings",
    [
        {"c3_matcher_matcher__min_inliers_threshold": "5"},
        {"C3_MATCHER_matcher__min_inliers_threshold": "5"},
        {
            "C3_MATCHER_MATCHER__MIN_INLIERS_THRESHOLD": "7",
            "c3_matcher_matcher__min_inliers_threshold": "5",
        },
    ],
)
def test_only_the_documented_upper_case_spelling_of_a_variable_is_read(
    clean_env: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], spellings: dict[str, str]
) -> None:
    """Both spellings were read (case-insensitively): the one later in the environment won."""
    for key, value in spellings.items():
        clean_env.setenv(key, value)
    line = _refusal(capsys, "config", "--json")
    other = next(k for k in spellings if k != k.upper())
    assert other in line
    assert "did you mean C3_MATCHER_MATCHER__MIN_INLIERS_THRESHOLD?" in line


def test_the_upper_case_spelling_alone_is_read(
    clean_env: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    clean_env.setenv("C3_MATCHER_MATCHER__MIN_INLIERS_THRESHOLD", "7")
    assert _config_json(capsys)["matcher"]["min_inliers_threshold"] == 7


def test_a_strategy_option_from_the_environment_is_shown_as_the_value_used(
    clean_env: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """It was printed (and written to the TOML ``config`` emits) as the string ``"0.5"``."""
    clean_env.setenv("C3_MATCHER_MATCHER__OPTIONS__XFEAT__MIN_COSSIM", "0.5")
    assert _config_json(capsys)["matcher"]["options"] == {"xfeat": {"min_cossim": 0.5}}
    assert main(["config"]) == 0
    text = capsys.readouterr().out
    assert "[matcher.options.xfeat]\nmin_cossim = 0.5\n" in text + "\n"


def test_a_strategy_option_from_the_environment_is_recorded_as_the_value_used(
    clean_env: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    tmp_path: Path,
    engine_dir: Path,
) -> None:
    """replay's ``report.json`` recorded the string too."""
    clean_env.setenv("C3_MATCHER_ENGINES__DIRECTORY", str(engine_dir))
    clean_env.setenv("C3_MATCHER_MATCHER__OPTIONS__XFEAT__MIN_COSSIM", "0.5")
    out = tmp_path / "run"
    argv = ["replay", str(FLIGHT), "--limit", "1", "--strategy", "xfeat", "--out", str(out)]
    assert main(argv) == 0, capsys.readouterr().err[-2000:]
    report = json.loads((out / "report.json").read_text())
    (settings,) = _find(report, "options")
    assert settings == {"xfeat": {"min_cossim": 0.5}}


def _find(data: Any, key: str) -> list[Any]:
    """Every value of ``key`` anywhere in ``data``."""
    if isinstance(data, dict):
        found = [data[key]] if key in data else []
        return found + [v for value in data.values() for v in _find(value, key)]
    if isinstance(data, list):
        return [v for value in data for v in _find(value, key)]
    return []


def test_relative_path_settings_are_made_absolute_against_the_working_directory(
    clean_env: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """A file's, the environment's alike; ``config`` printed them as written."""
    work = tmp_path / "work"
    work.mkdir()
    toml = tmp_path / "c3.toml"
    toml.write_text('[fdr]\npath = "fdr/x.jsonl"\n[engines]\ndirectory = "eng"\n')
    clean_env.delenv("C3_MATCHER_FDR__PATH")
    clean_env.setenv("C3_MATCHER_ENGINES__TENSORRT_CACHE_DIR", "trt")
    clean_env.chdir(work)
    data = _config_json_with(capsys, "--config", str(toml))
    assert data["fdr"]["path"] == str(work / "fdr" / "x.jsonl")
    assert data["engines"]["directory"] == str(work / "eng")
    assert data["engines"]["tensorrt_cache_dir"] == str(work / "trt")


def test_a_relative_path_with_no_working_directory_left_is_refused_naming_it(
    clean_env: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    gone = tmp_path / "gone"
    gone.mkdir()
    clean_env.chdir(gone)
    gone.rmdir()
    clean_env.setenv("C3_MATCHER_FDR__PATH", "rel.jsonl")
    line = _refusal(capsys, "config")
    assert "fdr.path" in line and "rel.jsonl is relative to a working directory" in line


def _config_json_with(capsys: pytest.CaptureFixture[str], *argv: str) -> dict[str, Any]:
    assert main([*argv, "config", "--json"]) == 0, capsys.readouterr().err
    data: dict[str, Any] = json.loads(capsys.readouterr().out)
    return data


def test_a_missing_engine_names_the_absolute_directory_looked_in(
    clean_env: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """ "no valid disk/depth engine in good" did not say where ``good`` was."""
    clean_env.chdir(tmp_path)
    clean_env.setenv("C3_MATCHER_ENGINES__DIRECTORY", "good")
    argv = ["match", "--query", str(DEMO / "frame.jpg"), "--tile", str(DEMO / "tile_b.png")]
    assert main([*argv, "--tile-gsd", "0.0968"]) == 1
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert f" in {tmp_path / 'good'}" in err, err


MISSING_INPUT = "c3.match.input_missing"


def _match_without_attitude_or_height(
    env: pytest.MonkeyPatch, engine_dir: Path, capsys: pytest.CaptureFixture[str]
) -> list[dict[str, Any]]:
    """``match`` of the demo frame without ``--attitude`` and ``--height``: its stderr lines,
    each read as JSON (a line that is not fails the test)."""
    env.setenv("C3_MATCHER_ENGINES__DIRECTORY", str(engine_dir))
    env.setenv("C3_MATCHER_MATCHER__STRATEGY", "xfeat")
    argv = ["match", "--query", str(DEMO / "frame.jpg"), "--tile", str(DEMO / "tile_b.png")]
    assert main([*argv, "--tile-gsd", "0.0968", "--no-correspondences"]) in (0, 3)
    err = capsys.readouterr().err
    return [json.loads(line) for line in err.splitlines()]


def test_match_warns_of_missing_inputs_in_json_log_records_and_the_fdr(
    clean_env: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    tmp_path: Path,
    engine_dir: Path,
) -> None:
    """They were plain-text lines among the JSON ones, and never in the FDR."""
    records = _match_without_attitude_or_height(clean_env, engine_dir, capsys)
    warned = [r for r in records if r["kind"] == MISSING_INPUT]
    assert [(r["level"], r["option"]) for r in warned] == [
        ("WARNING", "--attitude"),
        ("WARNING", "--height"),
    ]
    assert "yaw >= ~60 deg fails" in warned[0]["message"]
    fdr = [json.loads(line) for line in (tmp_path / "fdr.jsonl").read_text().splitlines()]
    recorded = [r["payload"] for r in fdr if r["kind"] == "log.warning"]
    assert [r["option"] for r in recorded if r["kind"] == MISSING_INPUT] == [
        "--attitude",
        "--height",
    ]


def test_match_warnings_of_missing_inputs_follow_the_logging_level(
    clean_env: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], engine_dir: Path
) -> None:
    clean_env.setenv("C3_MATCHER_LOGGING__LEVEL", "ERROR")
    records = _match_without_attitude_or_height(clean_env, engine_dir, capsys)
    assert all(r["level"] == "ERROR" for r in records), records
