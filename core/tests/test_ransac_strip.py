"""Texture along one strip only (a road through bare fields): the matches lie in a band a
twentieth as wide as it is long, and the homography fitted to them is fixed only along the band.
Without attitude and height (no geometric prior to pin the rest) the matcher refuses it on
geometry, naming the spread, instead of reporting a fix nothing vouches for; with them the
prior's check decides and the same frame is matched, its homography the true one. The same
frame with texture everywhere is matched either way.

The real path: ``c3-matcher match`` (SIFT + MAGSAC, no engine needed) on the README's demo
tile, the query a shifted view of it (at the tile's scale: a 400 px focal at 120 m is 0.3 m/px)."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from .demo_match import DEMO, run_match

SHIFT = (40.0, 30.0)  # the query's top-left corner in tile px: a pure shift
QUERY_SIZE = (400, 300)
STRIP_PX = 24
GREY = 128


def _strip_only(tile: np.ndarray, width_px: int, angle_deg: float = 30.0) -> np.ndarray:
    """``tile`` flat grey except a ``width_px`` band through its centre at ``angle_deg``."""
    h, w = tile.shape[:2]
    yy, xx = np.mgrid[0:h, 0:w]
    a = np.radians(angle_deg)
    across = (xx - (w - 1) / 2) * -np.sin(a) + (yy - (h - 1) / 2) * np.cos(a)
    out = np.full_like(tile, GREY)
    band = np.abs(across) <= width_px / 2
    out[band] = tile[band]
    return out


def _match(tmp_path: Path, tile: np.ndarray, prior: bool = False) -> tuple[int, dict[str, object]]:
    """The shifted view of ``tile`` matched against it (with attitude and height when
    ``prior``): exit status and the printed result."""
    to_query = np.array([[1.0, 0.0, -SHIFT[0]], [0.0, 1.0, -SHIFT[1]], [0.0, 0.0, 1.0]])
    query = cv2.warpPerspective(tile, to_query, QUERY_SIZE, borderValue=(GREY, GREY, GREY))
    cv2.imwrite(str(tmp_path / "tile.png"), tile)
    cv2.imwrite(str(tmp_path / "query.png"), query)
    argv = [
        *("match", "--query", str(tmp_path / "query.png"), "--tile", str(tmp_path / "tile.png")),
        *("--tile-id", "19,47.0,8.0", "--tile-gsd", "0.3", "--strategy", "sift_magsac"),
        *("--no-correspondences", "--fdr", str(tmp_path / "fdr.jsonl")),
        *(("--attitude", "0,0,0", "--height", "120") if prior else ()),
    ]
    proc = run_match(argv=argv)
    return proc.returncode, dict(json.loads(proc.stdout))


@pytest.fixture(scope="module")
def demo_tile() -> np.ndarray:
    return cv2.imread(str(DEMO / "tile_b.png"), cv2.IMREAD_COLOR)


def test_matches_along_one_strip_are_refused_without_a_prior(
    tmp_path: Path, demo_tile: np.ndarray
) -> None:
    code, result = _match(tmp_path, _strip_only(demo_tile, STRIP_PX))
    assert code != 0, result
    assert result["error"] == "InsufficientInliersError"
    (dropped,) = result["dropped"]  # type: ignore[misc]
    assert "refused on geometry: inliers on one line (spread 0." in dropped["reason"], dropped


@pytest.mark.parametrize("prior", [False, True])
def test_the_same_frame_is_matched_where_its_geometry_is_pinned(
    tmp_path: Path, demo_tile: np.ndarray, prior: bool
) -> None:
    """Texture everywhere (with or without a prior), or the strip with attitude and height:
    matched, the homography the true shift."""
    tile = _strip_only(demo_tile, STRIP_PX) if prior else demo_tile
    code, result = _match(tmp_path, tile, prior=prior)
    assert code == 0, result
    found = np.asarray(result["best_homography"], dtype=np.float64)
    corners = np.array([[[0.0, 0.0]], [[399.0, 0.0]], [[399.0, 299.0]], [[0.0, 299.0]]])
    got = cv2.perspectiveTransform(corners, found).reshape(-1, 2)
    assert np.abs(got - (corners.reshape(-1, 2) + SHIFT)).max() < (3.0 if prior else 1.0)
