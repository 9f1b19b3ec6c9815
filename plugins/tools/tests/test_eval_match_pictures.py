"""eval's match pictures (``plots/matches/<strategy>_<frame>.png``) read the correspondences
as the matcher gives them, in the frame's ORIGINAL pixels: the footprint and the rectified
query go through the flight's calibration, lens distortion included, as in replay's report."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from c3_matcher import viz
from c3_matcher_tools import plots
from c3_matcher_tools.dataset.format import FlightDataset, load_dataset
from c3_matcher_tools.run import FlightRun
from c3_matcher_tools.testing.outcomes import frame_outcome

REPO = Path(__file__).resolve().parents[3]
DEMO = REPO / "data" / "flights" / "naip_demo"


def _run(frame_index: int) -> FlightRun:
    """One matched frame whose best candidate holds a grid of inliers (query px, tile px)."""
    xs, ys = np.meshgrid(np.linspace(20, 300, 6), np.linspace(20, 220, 5))
    query = np.stack([xs.ravel(), ys.ravel()], axis=1)
    tile = query * 1.2 + np.array([30.0, 50.0])
    corr = np.concatenate([query, tile], axis=1)
    outcome = dataclasses.replace(
        frame_outcome(frame_index),
        result={"per_candidate": [{"inlier_correspondences": corr.tolist()}]},
    )
    return FlightRun("xfeat", {}, (outcome,), 0.0, 0.0)


def _footprint(
    dataset: FlightDataset, out: Path, monkeypatch: pytest.MonkeyPatch
) -> tuple[Any, Path]:
    """(the footprint eval draws on the best tile, its match picture) for ``dataset``."""
    drawn: list[Any] = []
    polylines = viz.cv2.polylines

    def record(image: Any, pts: Any, closed: bool, colour: Any, *args: Any) -> Any:
        if tuple(colour) == viz.FOOT:
            drawn.append(np.asarray(pts[0]).reshape(-1, 2).copy())
        return polylines(image, pts, closed, colour, *args)

    monkeypatch.setattr(viz.cv2, "polylines", record)
    frame = next(f for f in dataset.frames if f.true_tile_present)
    (picture,) = plots.eval_plots(dataset, [_run(frame.index)], out, samples=1)[2:]
    monkeypatch.undo()
    (ring,) = drawn
    return ring, Path(picture)


def test_match_pictures_draw_through_the_flights_lens_distortion(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    dataset = load_dataset(DEMO)
    assert np.any(dataset.calibration.distortion)  # the demo camera's lens distorts
    pinhole = dataclasses.replace(
        dataset,
        calibration=dataclasses.replace(
            dataset.calibration, distortion=np.zeros_like(dataset.calibration.distortion)
        ),
    )
    distorted, picture = _footprint(dataset, tmp_path / "distorted", monkeypatch)
    straight, _ = _footprint(pinhole, tmp_path / "pinhole", monkeypatch)
    assert distorted.shape == straight.shape
    assert np.abs(distorted - straight).max() >= 3  # px on the picture: the lens is drawn
    # the picture is the one draw_matches makes with the flight's calibration
    frame = next(f for f in dataset.frames if f.true_tile_present)
    run = _run(frame.index)
    assert run.outcomes[0].result is not None
    corr = np.asarray(run.outcomes[0].result["per_candidate"][0]["inlier_correspondences"])
    with dataset.open_store() as store:
        tile = store.handle(frame.candidates[0].tile_id, dataset.candidate_size_px).decode()
    expected = viz.draw_matches(
        dataset.nav_frame(frame).image,
        tile,
        corr.astype(np.float32),
        tmp_path / "expected.png",
        title=f"xfeat frame {frame.index}: 100 inliers, true tile, err 1.00px",
        height=480,
        calibration=dataset.calibration,
    )
    got, want = cv2.imread(str(picture)), cv2.imread(str(expected))
    assert got is not None and want is not None and np.array_equal(got, want)
