"""A section given to ``C3Settings(...)`` as its model is read as its dict form: the fields the
caller set are kept beside the ``C3_MATCHER_`` variables of that section, and a variable still
overrides the field it names (defaults < keyword arguments < environment). The model was
replaced whole by the environment's table as soon as one variable of its section was set: every
field the caller set fell back to its default, silently."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from pydantic import ValidationError

from c3_matcher.config import C3Settings, EngineSettings, LightGlueSettings, MatcherSettings

ENGINES = {"providers": ("CPU",), "intra_op_threads": 2, "cpu_mem_arena": False}


def test_an_engines_model_keeps_its_fields_beside_a_variable_of_its_section(
    clean_env: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    clean_env.setenv("C3_MATCHER_ENGINES__DIRECTORY", str(tmp_path))
    engines = C3Settings(engines=EngineSettings(**ENGINES)).engines
    assert engines.providers == ("CPUExecutionProvider",)
    assert (engines.intra_op_threads, engines.cpu_mem_arena) == (2, False)
    assert engines.directory == tmp_path  # the variable's
    assert engines == C3Settings(engines=ENGINES).engines  # as the dict form


def test_a_matcher_model_keeps_its_threshold_beside_the_strategy_variable(
    clean_env: pytest.MonkeyPatch,
) -> None:
    clean_env.setenv("C3_MATCHER_MATCHER__STRATEGY", "xfeat")
    matcher = C3Settings(matcher=MatcherSettings(min_inliers_threshold=80)).matcher
    assert (matcher.strategy, matcher.min_inliers_threshold) == ("xfeat", 80)


@pytest.mark.parametrize(
    "given",
    [
        {"lightglue": LightGlueSettings(mode="full", filter_threshold=0.2)},
        {"lightglue": {"mode": "full", "filter_threshold": 0.2}},
    ],
    ids=["model", "dict"],
)
def test_a_variable_still_overrides_the_field_it_names(
    clean_env: pytest.MonkeyPatch, given: dict[str, Any]
) -> None:
    """The documented order, the same for the model and its dict form."""
    clean_env.setenv("C3_MATCHER_LIGHTGLUE__FILTER_THRESHOLD", "0.3")
    lightglue = C3Settings(**given).lightglue
    assert (lightglue.mode, lightglue.filter_threshold) == ("full", 0.3)


def test_a_model_is_kept_as_given_without_the_environment(clean_env: pytest.MonkeyPatch) -> None:
    given = MatcherSettings(ransac_seed=7, options={"xfeat": {"upscale": 2}})
    assert C3Settings(matcher=given).matcher == given


def test_a_model_of_another_section_is_still_refused(clean_env: pytest.MonkeyPatch) -> None:
    """Read as its fields, a ``MatcherSettings()`` with none set would pass as ``[engines]``."""
    with pytest.raises(ValidationError, match="engines"):
        C3Settings(engines=MatcherSettings())  # type: ignore[arg-type]
