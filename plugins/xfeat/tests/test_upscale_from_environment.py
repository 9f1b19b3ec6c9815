"""XFeat's ``upscale`` is read from its own variable as every other option is:
``C3_MATCHER_MATCHER__OPTIONS__XFEAT__UPSCALE=3`` was refused as "Input should be a valid
integer" (the option took integers only, and the environment gives text). A boolean or a
fraction is still no factor."""

from __future__ import annotations

import os
import tomllib

import pytest
from pydantic import ValidationError

from c3_matcher.cli import main
from c3_matcher_xfeat import XFeatOptions

UPSCALE = "C3_MATCHER_MATCHER__OPTIONS__XFEAT__UPSCALE"


@pytest.fixture
def clean_env(monkeypatch: pytest.MonkeyPatch) -> pytest.MonkeyPatch:
    for key in [k for k in os.environ if k.upper().startswith("C3_MATCHER_")]:
        monkeypatch.delenv(key)
    return monkeypatch


def test_config_takes_the_factor_from_its_variable(
    clean_env: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    clean_env.setenv(UPSCALE, "3")
    clean_env.setenv("C3_MATCHER_MATCHER__STRATEGY", "xfeat")
    assert main(["config"]) == 0, capsys.readouterr().err
    assert tomllib.loads(capsys.readouterr().out)["matcher"]["options"]["xfeat"] == {"upscale": 3}


@pytest.mark.parametrize("value", ["2.5", "true", "0", "5"])
def test_a_variable_that_is_no_factor_is_refused_naming_the_option(
    clean_env: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], value: str
) -> None:
    clean_env.setenv(UPSCALE, value)
    assert main(["config"]) == 2
    assert "matcher.options.xfeat.upscale" in capsys.readouterr().err


def test_text_is_read_as_a_whole_number_and_a_boolean_refused() -> None:
    assert XFeatOptions.model_validate({"upscale": "3"}).upscale == 3
    for field, value in (("upscale", True), ("upscale", 2.5), ("min_cossim", False)):
        with pytest.raises(ValidationError) as refused:
            XFeatOptions.model_validate({field: value})
        assert refused.value.errors()[0]["loc"] == (field,)
