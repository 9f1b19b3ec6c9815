"""The flight report's pictures: a matched frame replayed without its inlier correspondences
(``replay --no-correspondences``) is still drawn as matched, on its best tile; the gallery's
"worst" frames are frames that went wrong (never a right match, never an absent-tile frame that
rightly raised) and its "best" ones frames that went right, neither empty when the flight has
both kinds, no frame in both."""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from c3_matcher.config import C3Settings
from c3_matcher.viz import FOOT
from c3_matcher_tools.dataset.format import FlightDataset, load_dataset
from c3_matcher_tools.report import pictures
from c3_matcher_tools.run import FlightOptions, open_matcher, run_flight
from c3_matcher_tools.run.records import FrameOutcome, FrameStatus
from c3_matcher_tools.testing.outcomes import frame_outcome

REPO = Path(__file__).resolve().parents[3]
DEMO = REPO / "data" / "flights" / "naip_demo"


@pytest.fixture(scope="module")
def dataset() -> FlightDataset:
    return load_dataset(DEMO)


def test_a_match_replayed_without_correspondences_is_drawn_on_its_best_tile(
    dataset: FlightDataset, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    frames = [f for f in dataset.frames if f.index in (11, 12)]  # SIFT matches both
    with open_matcher(C3Settings(), "sift_magsac", tmp_path / "run") as matcher:
        outcomes = run_flight(matcher, dataset, FlightOptions(frames, with_correspondences=False))
    matched = [o for o in outcomes if o.status == FrameStatus.OK]
    assert matched, [o.error for o in outcomes]
    with dataset.open_store() as store:
        for o in matched:  # the best tile with the query's footprint (yellow) drawn on it
            picture = pictures.frame_picture(dataset, o, store).astype(np.int16)
            footprint = np.abs(picture - np.array(FOOT, np.int16)).max(axis=2) <= 30
            assert footprint.sum() > 100, o.index
    drawn: list[dict[str, Any]] = []

    def render_match(query: Any, views: Any, **kwargs: Any) -> np.ndarray:
        drawn.append(kwargs)
        return np.zeros((8, 8, 3), np.uint8)

    monkeypatch.setattr(pictures, "render_match", render_match)
    with dataset.open_store() as store:
        for o in matched:
            assert o.result is not None
            assert "inlier_correspondences" not in o.result["per_candidate"][0]
            pictures.frame_picture(dataset, o, store)
    for o, kwargs in zip(matched, drawn, strict=True):
        assert o.result is not None
        assert kwargs["best_index"] == o.best_input_index is not None, o.index
        hom = np.asarray(o.result["best_homography"], np.float64).reshape(3, 3)
        assert kwargs["h_query_to_tile"] is not None, o.index
        np.testing.assert_allclose(kwargs["h_query_to_tile"], hom)


def _gallery(
    dataset: FlightDataset,
    outcomes: Sequence[FrameOutcome],
    monkeypatch: pytest.MonkeyPatch,
    n: int = 3,
) -> tuple[list[int], list[int]]:
    """(worst, best) frame indices of the gallery of ``outcomes`` (pictures not drawn)."""
    monkeypatch.setattr(pictures, "frame_picture", lambda *a, **k: np.zeros((8, 8, 3), np.uint8))
    groups: dict[str, list[int]] = {"worst": [], "best": []}
    for caption, _ in pictures.gallery_pictures(dataset, outcomes, n):
        found = re.fullmatch(r"(worst|best): frame (\d+)", caption)
        assert found is not None, caption
        groups[found[1]].append(int(found[2]))
    return groups["worst"], groups["best"]


def _raised(index: int, *, true_present: bool, best: int = 20) -> FrameOutcome:
    o = frame_outcome(index, status=FrameStatus.INSUFFICIENT, true_present=true_present)
    return dataclasses.replace(o, insufficient_best=best)


def test_right_matches_and_rightly_raised_frames_are_never_worst(
    dataset: FlightDataset, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The review's flight: two right matches, two absent-tile frames that raised. Nothing
    went wrong: no worst frame, all four among the best (three shown)."""
    outcomes = [
        frame_outcome(11, error_px=0.2),
        frame_outcome(12, error_px=0.4),
        _raised(13, true_present=False),
        _raised(14, true_present=False),
    ]
    worst, best = _gallery(dataset, outcomes, monkeypatch)
    assert worst == []
    assert best[:2] == [11, 12] and len(best) == 3 and set(best) <= {11, 12, 13, 14}


def test_worst_are_what_went_wrong_and_best_what_went_right(
    dataset: FlightDataset, monkeypatch: pytest.MonkeyPatch
) -> None:
    outcomes = [
        frame_outcome(0, error_px=0.3),  # right
        frame_outcome(1, error_px=1.5),  # right
        frame_outcome(2, error_px=0.8),  # right
        frame_outcome(3, correct=False, error_px=math.nan),  # a wrong tile
        _raised(4, true_present=True),  # missed
        _raised(5, true_present=False),  # rightly raised
        frame_outcome(6, error_px=40.0),  # the true tile, placed 40 px off: a wrong fix
        frame_outcome(7, status=FrameStatus.UNREADABLE),  # no picture
    ]
    worst, best = _gallery(dataset, outcomes, monkeypatch)
    assert set(worst) == {3, 4, 6} and not set(worst) & set(best)
    assert best == [0, 2, 1]
    worst, best = _gallery(dataset, outcomes, monkeypatch, n=5)
    assert set(worst) == {3, 4, 6} and best == [0, 2, 1, 5]


def test_a_flight_with_one_right_and_many_wrong_frames_shows_both(
    dataset: FlightDataset, monkeypatch: pytest.MonkeyPatch
) -> None:
    outcomes = [
        *(_raised(i, true_present=True, best=i) for i in range(4)),
        frame_outcome(4, error_px=0.5),
    ]
    worst, best = _gallery(dataset, outcomes, monkeypatch)
    assert len(worst) == 3 and 4 not in worst and best == [4]


@pytest.mark.parametrize(
    ("captions", "note"), [(["best: frame 1"], True), (["worst: frame 2", "best: frame 1"], False)]
)
def test_the_page_says_when_no_frame_went_wrong(captions: list[str], note: bool) -> None:
    from c3_matcher_tools.report.html import _Page

    page = _Page(
        "flight", "xfeat", [], "data:,", "data:,", [(c, "data:,") for c in captions], "", {}, {}, {}
    ).html()
    assert ("No frame went wrong." in page) is note
    assert "more than 10 px off the ground truth" in page
