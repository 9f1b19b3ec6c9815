"""``c3-matcher config`` refuses the settings the strategy's keypoint budget cannot meet, as
start-up does and in the same words: ``[matcher] min_inliers_threshold`` or ``[lightglue]
exit_matches`` above the keypoints per image the strategy keeps. ``config`` passed them (exit 0)
and every flight command then refused the same file at start-up (exit 2). ``config`` loads no
engine: the budget is the one the strategy declares (its options, ``[matcher] max_keypoints``,
its extractor engine's declared top-K)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from c3_matcher.cli import main
from c3_matcher.compose import build_default_helpers
from c3_matcher.config import load_settings
from c3_matcher.errors import ConfigurationError
from c3_matcher.testing.strategy_kit import compose_ready

LIGHTERGLUE = json.dumps({"xfeat": {"matcher": "lighterglue"}})


def _config(env: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], **values: str) -> int:
    for key, value in values.items():
        env.setenv(f"C3_MATCHER_{key.upper()}", value)
    capsys.readouterr()
    return main(["config"])


@pytest.mark.parametrize(
    ("values", "key", "budget"),
    [
        ({"matcher__min_inliers_threshold": "3000"}, "matcher.min_inliers_threshold", 2048),
        ({"lightglue__exit_matches": "3000"}, "lightglue.exit_matches", 2048),
        (  # above the engine's top-K: cut to it, as start-up cuts it
            {"matcher__min_inliers_threshold": "3000", "matcher__max_keypoints": "4096"},
            "matcher.min_inliers_threshold",
            2048,
        ),
        (
            {"matcher__strategy": "aliked_lightglue", "matcher__min_inliers_threshold": "3000"},
            "matcher.min_inliers_threshold",
            2048,
        ),
        (
            {"matcher__strategy": "aliked_lightglue", "lightglue__exit_matches": "3000"},
            "lightglue.exit_matches",
            2048,
        ),
        (
            {"matcher__strategy": "xfeat", "matcher__min_inliers_threshold": "5000"},
            "matcher.min_inliers_threshold",
            4096,
        ),
        (
            {"matcher__strategy": "xfeat", "matcher__options": LIGHTERGLUE}
            | {"matcher__min_inliers_threshold": "3000"},
            "matcher.min_inliers_threshold",
            2048,
        ),
        (
            {"matcher__strategy": "xfeat", "matcher__options": LIGHTERGLUE}
            | {"lightglue__exit_matches": "3000"},
            "lightglue.exit_matches",
            2048,
        ),
    ],
)
def test_config_refuses_what_the_keypoint_budget_cannot_meet(
    clean_env: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    values: dict[str, str],
    key: str,
    budget: int,
) -> None:
    assert _config(clean_env, capsys, **values) == 2
    err = capsys.readouterr().err
    assert f"{key}: " in err and f"exceeds the {budget} keypoints per image" in err, err


@pytest.mark.parametrize(
    "values",
    [
        {},
        {"matcher__min_inliers_threshold": "2048", "lightglue__exit_matches": "2048"},
        {"matcher__strategy": "aliked_lightglue", "matcher__min_inliers_threshold": "2048"},
        {"matcher__strategy": "xfeat", "matcher__min_inliers_threshold": "3000"},  # mnn: 4096
        {"lightglue__mode": "full", "lightglue__exit_matches": "3000"},  # full: no exit
        # mnn runs no LightGlue: [lightglue] does not concern it, as at start-up
        {"matcher__strategy": "xfeat", "lightglue__exit_matches": "6000"},
    ],
)
def test_config_passes_what_the_budget_meets(
    clean_env: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], values: dict[str, str]
) -> None:
    assert _config(clean_env, capsys, **values) == 0, capsys.readouterr().err


@pytest.mark.parametrize(
    "values",
    [{"matcher__min_inliers_threshold": "3000"}, {"lightglue__exit_matches": "3000"}],
)
def test_config_and_start_up_refuse_in_the_same_words(
    clean_env: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    engine_dir: Path,
    tmp_path: Path,
    values: dict[str, str],
) -> None:
    """The real DISK + LightGlue strategy composed on its built engines (CPU: adaptive mode)."""
    values |= {"engines__directory": str(engine_dir), "fdr__path": str(tmp_path / "f.jsonl")}
    assert _config(clean_env, capsys, **values) == 2
    said = capsys.readouterr().err.strip().splitlines()[-1]
    settings = load_settings()
    with pytest.raises(ConfigurationError) as refused:
        root, _ = compose_ready(settings, build_default_helpers(settings))
        root.close()
    assert said == f"c3-matcher: {' '.join(str(refused.value).split())}"
