"""A refused setting is named with the value refused and where it was set (the variable, or the
file), and NaN as not a number: ``C3_MATCHER_MATCHER__RANSAC_SEED=-1`` said only
``matcher.ransac_seed: Input should be greater than or equal to 0``, and a NaN heading
tolerance that it should be at most 90."""

from __future__ import annotations

from pathlib import Path

import pytest

from c3_matcher.cli import main
from c3_matcher.config import load_settings
from c3_matcher.config_problems import MAX_SHOWN
from c3_matcher.errors import ConfigurationError

SEED = "C3_MATCHER_MATCHER__RANSAC_SEED"
TOLERANCE = "C3_MATCHER_MATCHER__PRIOR_ROTATION_TOL_DEG"


def _refusal(toml: Path | None = None, **env: str) -> tuple[str, str]:
    with pytest.raises(ConfigurationError) as refused:
        load_settings(toml, env=env)
    ((field, reason),) = refused.value.problems
    return field, reason


def test_a_variable_out_of_range_is_named_with_its_value() -> None:
    field, reason = _refusal(**{SEED: "-1"})
    assert field == "matcher.ransac_seed"
    assert reason == f"Input should be greater than or equal to 0, got '-1', set by {SEED}"


@pytest.mark.parametrize("value", ["nan", "NaN", "-nan"])
def test_nan_is_said_to_be_no_number_not_out_of_range(value: str) -> None:
    field, reason = _refusal(**{TOLERANCE: value})
    assert field == "matcher.prior_rotation_tol_deg"
    assert reason == f"not a number (NaN), got {value!r}, set by {TOLERANCE}"


def test_a_file_value_is_named_with_the_file(tmp_path: Path) -> None:
    toml = tmp_path / "c3.toml"
    toml.write_text("[matcher]\nprior_rotation_tol_deg = nan\n")
    assert _refusal(toml) == (
        "matcher.prior_rotation_tol_deg",
        f"not a number (NaN), got nan, set in {toml}",
    )


def test_a_sections_json_is_named_for_the_keys_it_gives_the_file_for_the_others(
    tmp_path: Path,
) -> None:
    toml = tmp_path / "c3.toml"
    toml.write_text("[matcher]\nransac_seed = -1\n")
    section = "C3_MATCHER_MATCHER"
    _, reason = _refusal(toml, **{section: '{"tile_cache_size": 4}'})
    assert reason.endswith(f"got -1, set in {toml}")
    _, reason = _refusal(toml, **{section: '{"ransac_seed": -2}'})
    assert reason.endswith(f"got -2, set by {section}")


def test_a_variable_replacing_the_files_value_is_named_not_the_file(tmp_path: Path) -> None:
    toml = tmp_path / "c3.toml"
    toml.write_text("[matcher]\nransac_seed = 3\n")
    _, reason = _refusal(toml, **{SEED: "-1"})
    assert reason.endswith(f"got '-1', set by {SEED}")


def test_a_long_value_is_shortened() -> None:
    _, reason = _refusal(C3_MATCHER_LOGGING__LEVEL="x" * 500)
    shown = reason.split("got ", 1)[1].split(", set by")[0]
    assert len(shown) == MAX_SHOWN and shown.endswith("...")


def test_the_command_says_the_value_and_the_variable(
    clean_env: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    clean_env.setenv(SEED, "-1")
    assert main(["config"]) == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert (
        f"matcher.ransac_seed: Input should be greater than or equal to 0, got '-1', set by {SEED}"
        in line
    )
