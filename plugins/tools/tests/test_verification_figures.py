"""A build's verification fails a figure that is not a finite number: a graph whose descriptors
or scores come out NaN (a 0/0 normalisation) or infinite passed it, since NaN is above no
tolerance, and its manifest recorded ``passed: true`` with a NaN in its JSON. Checked on the
real features of the XFeat engine on the Gorinchem orthophoto, through each comparison the
exporters use: the extractor kit's (DISK, XFeat), ALIKED's and LightGlue's."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray

from c3_matcher_tools.engines.export import ExportReport, tolerance_failures
from c3_matcher_tools.engines.export.extractor import KeypointSet, compare_keypoint_sets
from c3_matcher_xfeat.engines import XFEAT_TOLERANCES

POISONS: dict[str, Callable[[NDArray[np.float32]], None]] = {
    "every value NaN": lambda a: a.fill(np.nan),
    "one value NaN": lambda a: a.reshape(-1).__setitem__(0, np.nan),
    "one value infinite": lambda a: a.reshape(-1).__setitem__(0, np.inf),
}


@pytest.fixture(scope="module")
def real_set(engine_dir: Path, gorinchem: NDArray[np.uint8]) -> KeypointSet:
    """Keypoints, scores and descriptors of the XFeat engine on a 512x512 real crop."""
    from c3_matcher.engines.extract import run_extractor
    from c3_matcher.engines.runtime import OnnxInferenceRuntime
    from c3_matcher.engines.store import EngineStore

    runtime = OnnxInferenceRuntime(["CPUExecutionProvider"])
    engine_id = runtime.load_engine(EngineStore(engine_dir).require("xfeat", "default"))
    rgb = np.ascontiguousarray(gorinchem[:512, :512])
    features = run_extractor(runtime, engine_id, rgb, np.ones((512, 512), bool), 1024)
    assert len(features) > 100
    return (features.keypoints, features.keypoint_scores, features.descriptors)


def _poisoned(real: KeypointSet, which: int, poison: str) -> KeypointSet:
    copies = [a.copy() for a in real]
    POISONS[poison](copies[which])
    return (copies[0], copies[1], copies[2])


def test_the_real_set_against_itself_passes(real_set: KeypointSet) -> None:
    failures: list[str] = []
    check = compare_keypoint_sets("crop", real_set, real_set, XFEAT_TOLERANCES, failures)
    assert failures == [] and check["descriptors_max_abs"] == 0.0
    assert ExportReport.from_checks("self", XFEAT_TOLERANCES, [check], failures).passed


@pytest.mark.parametrize("poison", sorted(POISONS))
@pytest.mark.parametrize(("which", "figure"), [(1, "scores_max_abs"), (2, "descriptors_max_abs")])
def test_a_figure_that_is_not_finite_fails_the_extractor_verification(
    real_set: KeypointSet, poison: str, which: int, figure: str
) -> None:
    failures: list[str] = []
    got = _poisoned(real_set, which, poison)
    check = compare_keypoint_sets("crop", got, real_set, XFEAT_TOLERANCES, failures)
    assert not np.isfinite(check[figure])
    assert [f for f in failures if figure in f] == [
        f"crop: {figure} is {check[figure]} (not a finite number)"
    ]
    report = ExportReport.from_checks("reference", XFEAT_TOLERANCES, [check], failures)
    assert not report.passed


@pytest.mark.parametrize("poison", sorted(POISONS))
def test_a_figure_that_is_not_finite_fails_the_aliked_verification(
    real_set: KeypointSet, poison: str
) -> None:
    """ALIKED pairs sub-pixel keypoints by nearest neighbour before comparing."""
    from c3_matcher_aliked_lightglue.export import _paired_check

    failures: list[str] = []
    check = _paired_check("crop", _poisoned(real_set, 2, poison), real_set, failures)
    assert check["keypoints_mismatch"] == 0 and not np.isfinite(check["descriptors_max_abs"])
    assert failures == [
        f"crop: descriptors_max_abs is {check['descriptors_max_abs']} (not a finite number)"
    ]


@pytest.mark.parametrize("value", [float("nan"), float("inf")])
@pytest.mark.parametrize("figure", ["match_score_max_abs", "mscores0_max_abs"])
def test_a_figure_that_is_not_finite_fails_the_lightglue_verification(
    value: float, figure: str
) -> None:
    from c3_matcher_tools.engines.export.lightglue import _pair_failures

    check: dict[str, Any] = {
        "matches_identical": True,
        "matches_mismatch": 0,
        "match_score_max_abs": 0.0,
        "mscores0_max_abs": 0.0,
    }
    assert _pair_failures("pair", check) == []
    assert _pair_failures("pair", {**check, figure: value}) == [
        f"pair: {figure} is {value} (not a finite number)"
    ]


def test_tolerance_failures_compares_each_figure_named() -> None:
    tolerances = {"a": 1e-4, "b": 1e-4, "c": float("inf")}
    figures = {"a": 5e-5, "b": 2e-4, "c": float("inf"), "d": float("nan")}
    assert tolerance_failures("x", figures, tolerances, ["a", "b", "c"]) == [
        "x: b 0.0002 > 0.0001",
        "x: c is inf (not a finite number)",
    ]
    assert tolerance_failures("x", figures, tolerances, []) == []
