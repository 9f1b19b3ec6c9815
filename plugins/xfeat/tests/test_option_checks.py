"""XFeat's options say what they do: ``min_cossim`` given with LighterGlue (which does not read
it) is refused naming it; a ``[matcher]`` keypoint budget above the engine's top-K is cut to it
with the warning every strategy gives (``c3.matcher.keypoints_capped``)."""

from __future__ import annotations

from typing import Any

import pytest
from pydantic import ValidationError

from c3_matcher.compose import build_default_helpers
from c3_matcher.config import C3Settings
from c3_matcher.engines.store import EngineStore
from c3_matcher.testing.strategy_kit import matcher_over_helpers
from c3_matcher_xfeat import XFeatConfig, XFeatMatcher, XFeatOptions


def test_min_cossim_given_with_lighterglue_is_refused_naming_the_option_and_the_matcher():
    with pytest.raises(ValidationError) as refused:
        XFeatOptions(matcher="lighterglue", min_cossim=0.99)
    (error,) = refused.value.errors()
    assert error["loc"] == ("min_cossim",) and "'lighterglue'" in error["msg"]
    assert XFeatOptions(matcher="lighterglue").matcher == "lighterglue"  # its default: fine
    assert XFeatOptions(matcher="mnn", min_cossim=0.99).min_cossim == 0.99
    assert XFeatOptions(min_cossim=-1).min_cossim == -1  # mnn by default


@pytest.mark.parametrize("matcher", ["mnn", "lighterglue"])
def test_a_keypoint_budget_above_the_engines_top_k_is_cut_to_it_and_said(
    engine_dir, tmp_path, matcher
):
    """``--max-keypoints 8000`` (``[matcher] max_keypoints``): DISK and ALIKED said they keep
    their engine's top-K; XFeat cut it to 4096 without a word."""
    from loguru import logger

    settings = C3Settings(
        matcher={"strategy": "xfeat", "max_keypoints": 8000},
        engines={"directory": engine_dir},
        fdr={"path": tmp_path / "fdr.jsonl"},
    )
    said: list[dict[str, Any]] = []
    sink = logger.add(lambda m: said.append(dict(m.record["extra"])), level="WARNING")
    try:
        config = XFeatConfig.from_c3_settings(
            settings, XFeatOptions(matcher=matcher), EngineStore(engine_dir)
        )
        built = matcher_over_helpers(XFeatMatcher, config, build_default_helpers(settings))
    finally:
        logger.remove(sink)
    assert config.max_keypoints == 8000 and built.backend.max_keypoints == 4096
    assert said.count({"kind": "c3.matcher.keypoints_capped", "strategy": "xfeat"}) == 1
