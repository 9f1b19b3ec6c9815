"""The report's trajectory of a flight across 180 deg is drawn in one piece: its window is
centred between the points (not at 0 deg, half a world away, where a store has no tiles) and,
without imagery there, its longitudes run on past 180 deg rather than back across the world."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
from matplotlib.figure import Figure

from c3_matcher_tools.dataset.format import load_dataset
from c3_matcher_tools.dataset.importer import import_csv_flight
from c3_matcher_tools.report import trajectory
from c3_matcher_tools.testing.outcomes import frame_outcome

from .test_import_antimeridian import _moved_flight, across  # noqa: F401 (a fixture)

LONS = (179.993, 179.996, 179.999, -179.999, -179.996, -179.993)
"""A flight across 180 deg at 52 N: 14 m of lat per frame, 0.003 deg (206 m) of lon."""


def test_the_window_of_a_flight_across_180_deg_is_centred_on_it() -> None:
    pts = [(lon, 52.0) for lon in LONS]
    centre, size = trajectory._window(pts, 15, 256)
    assert abs(centre.lon) == pytest.approx(180.0, abs=1e-9) and centre.lat == 52.0
    # 0.014 deg of longitude is 326 px at zoom 15: the window holds it with its margin
    assert 256 + 326 <= size < 700


def test_a_flight_across_180_deg_without_imagery_is_drawn_in_one_piece() -> None:
    outcomes = []
    for i, lon in enumerate(LONS):
        where = {"truth_lat": 52.0 + 1e-4 * i, "truth_lon": lon}
        estimate = {"est_lat": 52.0 + 1e-4 * i, "est_lon": lon + 1e-5}
        outcomes.append(dataclasses.replace(frame_outcome(i), **where, **estimate))
    no_store: Any = SimpleNamespace(frames=[])
    ax = Figure().add_subplot()
    trajectory.draw_trajectory(ax, no_store, outcomes, "across 180 deg")
    xs = np.concatenate([line.get_xdata() for line in ax.get_lines()]).astype(float)
    assert xs.max() - xs.min() < 0.02  # 1.4 km, not 360 deg
    assert xs.min() == pytest.approx(179.993) and xs.max() == pytest.approx(180.007 + 1e-5)


def test_an_imported_flight_across_180_deg_is_drawn_on_its_store_imagery(
    tmp_path: Path,
    across: Path,  # noqa: F811 (the fixture imported above)
) -> None:
    """The demo flight and store moved across 180 deg and imported: the trajectory is drawn on
    the store's imagery there, every point within the mosaic."""
    import_csv_flight(_moved_flight(tmp_path / "line", across), tmp_path / "f", name="f")
    dataset = load_dataset(tmp_path / "f")
    outcomes = []
    for frame in dataset.frames:
        look = {"lat": frame.telemetry["look_lat"], "lon": frame.telemetry["look_lon"]}
        where = {"telemetry_lat": look["lat"], "telemetry_lon": look["lon"]}
        estimate = {"est_lat": look["lat"] + 1e-5, "est_lon": look["lon"]}
        outcomes.append(dataclasses.replace(frame_outcome(frame.index), **where, **estimate))
    assert {o.est_lon > 0 for o in outcomes} == {True, False}  # both sides of the line
    ax = Figure().add_subplot()
    trajectory.draw_trajectory(ax, dataset, outcomes, "across 180 deg")
    (image,) = ax.get_images()
    size = image.get_array().shape[0]
    xs = np.concatenate([line.get_xdata() for line in ax.get_lines()]).astype(float)
    assert xs.min() > 0 and xs.max() < size
