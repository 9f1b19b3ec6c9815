"""A frame may have up to 1024 candidates (``dataset import --candidates``): the picture's strip
draws as many as fit at ``MIN_CELL`` px each, the best and true ones always, and counts the rest
("+M more"), so the flight report is written for any number of them."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from c3_matcher.viz import MIN_CELL, CandidateView, _shown, render_match

DEMO = Path(__file__).resolve().parents[2] / "data" / "demo"


def _rgb(name: str) -> np.ndarray:
    image = cv2.imread(str(DEMO / name), cv2.IMREAD_COLOR)
    assert image is not None
    return np.ascontiguousarray(image[:, :, ::-1])


@pytest.mark.parametrize("best", [None, 120])
def test_a_frame_of_150_candidates_is_pictured(best: int | None) -> None:
    tiles = [_rgb(name) for name in ("tile_a.png", "tile_b.png", "tile_c.png")]
    candidates = [
        CandidateView(tiles[i % 3], f"tile {i}", i % 50, best=i == best, is_true=i == best)
        for i in range(150)
    ]
    picture = render_match(_rgb("frame.jpg"), candidates, title="150 candidates")
    width = 2 * 420 + 8
    cell = MIN_CELL
    assert picture.shape == (34 + 420 + cell + 8, width, 3) and picture.dtype == np.uint8
    shown = _shown(candidates, width // cell)
    assert len(shown) == width // cell - 1 and shown == sorted(shown)
    assert best is None or best in shown
    again = render_match(_rgb("frame.jpg"), candidates, title="150 candidates")
    assert np.array_equal(picture, again)


def test_candidates_that_fit_are_all_drawn_at_their_usual_size() -> None:
    tile = _rgb("tile_a.png")
    candidates = [CandidateView(tile, f"tile {i}", 10) for i in range(4)]
    picture = render_match(_rgb("frame.jpg"), candidates)
    assert picture.shape[0] == 34 + 420 + 200 + 8
    assert _shown(candidates, 4) == [0, 1, 2, 3]
