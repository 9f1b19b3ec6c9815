"""A frame with truth but no ground-truth homography (a dataset that gives poses alone) is
scored against where its principal point looks, the point the matcher's frame centre
estimates: where the optical axis meets flat ground from the pose's nadir, attitude and
height. It was the pose's footprint centre, the mean of the footprint's corners: 1.8 to 59 m
from that point on the shipped demo flight (20 deg of tilt at 780 m)."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import pytest

from c3_matcher_tools.dataset.format import load_dataset
from c3_matcher_tools.run.scoring import truth_position

FLIGHTS = Path(__file__).resolve().parents[3] / "data" / "flights"


def _metres(a: tuple[float, float], b: tuple[float, float]) -> float:
    north = (a[0] - b[0]) * 111_320.0
    east = (a[1] - b[1]) * 111_320.0 * math.cos(math.radians(a[0]))
    return math.hypot(north, east)


@pytest.mark.parametrize("flight", ["naip_demo", "zurich_z16"])
def test_a_frame_without_homographies_is_scored_where_its_principal_point_looks(
    flight: str,
) -> None:
    dataset = load_dataset(FLIGHTS / flight)
    for frame in dataset.frames:
        by_homography = truth_position(dataset, frame)
        assert by_homography is not None
        bare = dataclasses.replace(
            frame,
            candidates=tuple(
                dataclasses.replace(c, h_tile_to_undistorted=None) for c in frame.candidates
            ),
        )
        by_pose = truth_position(dataset, bare)
        assert by_pose is not None
        assert _metres(by_pose, by_homography) < 1.0, frame.index  # Mercator vs flat earth
