"""A run's files (the results, the GeoJSON and the HTML report) are written through
``c3_matcher.atomic`` (its own tests: core/tests/test_atomic.py), leaving other writers'
temporary files alone; a dataset's name names one output directory."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from c3_matcher.config import C3Settings
from c3_matcher.errors import InvalidInputError
from c3_matcher_tools.dataset.format import load_dataset
from c3_matcher_tools.run import (
    FlightOptions,
    FlightRun,
    exclusive_output_dir,
    flight_report,
    fly,
    output_dir_name,
    write_flight_outputs,
)

DEMO = Path(__file__).resolve().parents[3] / "data" / "flights" / "naip_demo"


@pytest.fixture(scope="module")
def flown(tmp_path_factory: pytest.TempPathFactory) -> FlightRun:
    """Two frames of the demo flight through the ``sift_magsac`` baseline (no engines)."""
    from c3_matcher.compose import build_plugin_host

    flight = load_dataset(DEMO)
    out = tmp_path_factory.mktemp("flown")
    return fly(
        C3Settings(),
        "sift_magsac",
        flight,
        out,
        plugin_host=build_plugin_host(),
        options=FlightOptions(flight.frames[:2]),
    )


def test_the_geojson_and_the_report_leave_another_writers_temporary_files_alone(
    flown: FlightRun, tmp_path: Path
) -> None:
    others = {"flight.geojson.tmp": "another writer's", "report.html.tmp": "another writer's"}
    for name, text in others.items():
        (tmp_path / name).write_text(text)
    dataset = load_dataset(DEMO)
    write_flight_outputs(tmp_path, dataset, flown, flight_report(dataset, flown))
    assert json.loads((tmp_path / "flight.geojson").read_text())["type"] == "FeatureCollection"
    assert (tmp_path / "report.html").read_text().startswith("<!DOCTYPE html>")
    assert {name: (tmp_path / name).read_text() for name in others} == others
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        ["flight.geojson", "report.html", "results.jsonl", *others]
    )


@pytest.mark.parametrize("name", ["../x", "/tmp/x", "a/b", "..", ".", "", "a\\b", "a\0b"])
def test_a_dataset_name_that_is_not_one_path_component_names_no_directory(name: str) -> None:
    import dataclasses

    flight = load_dataset(DEMO)
    with pytest.raises(InvalidInputError, match="one path component"):
        output_dir_name(dataclasses.replace(flight, meta={**flight.meta, "name": name}))


def test_a_plain_dataset_name_names_its_directory() -> None:
    assert output_dir_name(load_dataset(DEMO)) == "naip_demo"


def test_an_output_directory_is_held_by_one_run_at_a_time_and_leaves_no_lock_file(
    tmp_path: Path,
) -> None:
    first, second = tmp_path / "first", tmp_path / "second"
    with exclusive_output_dir(first):
        refusal = pytest.raises(InvalidInputError, match="another replay or eval")
        with refusal as refused, exclusive_output_dir(second, first):
            pass
        assert str(first) in str(refused.value)
        with exclusive_output_dir(second):  # the refused claim let go of what it had taken
            pass
    with exclusive_output_dir(first, second):  # released when the block ends
        pass
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["first", "second"]


def test_a_run_without_matplotlib_removes_the_report_an_earlier_run_left(
    flown: FlightRun, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The airborne install has no matplotlib: the report of an earlier run in the directory
    would sit beside results it does not describe."""
    dataset = load_dataset(DEMO)
    write_flight_outputs(tmp_path, dataset, flown, flight_report(dataset, flown))
    assert (tmp_path / "report.html").exists()
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib: ImportError
    files = write_flight_outputs(tmp_path, dataset, flown, flight_report(dataset, flown))
    assert files.html is None and files.geojson == str(tmp_path / "flight.geojson")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["flight.geojson", "results.jsonl"]


def test_a_frame_that_raised_shows_its_best_candidates_inliers_in_every_output(
    flown: FlightRun, tmp_path: Path
) -> None:
    """The GeoJSON, the report and the eval chart read one count (``candidate_inliers``): a
    frame below the threshold shows the count it fell short with, not 0."""
    import dataclasses

    from c3_matcher_tools.geojson import flight_geojson

    short = dataclasses.replace(
        flown.outcomes[0], status="insufficient", best_inliers=0, insufficient_best=59
    )
    assert short.candidate_inliers == 59 and short.best_inliers == 0
    points = [
        f["properties"]
        for f in flight_geojson([short, *flown.outcomes[1:]], "sift_magsac")["features"]
        if f["properties"]["kind"] == "truth"
    ]
    assert points[0]["inliers"] == 59 and points[0]["status"] == "insufficient"
    assert points[1]["inliers"] == flown.outcomes[1].candidate_inliers


def test_a_track_across_180_deg_is_cut_there_not_drawn_round_the_world(flown: FlightRun) -> None:
    import dataclasses

    from c3_matcher_tools.geojson import flight_geojson

    a, b = flown.outcomes[:2]
    c = b
    across = [
        dataclasses.replace(
            a, est_lon=179.9999, est_lat=-17.0, truth_lon=-179.9999, truth_lat=-17.0
        ),
        dataclasses.replace(b, est_lon=-179.9997, est_lat=-17.0002, truth_lon=179.9995),
        dataclasses.replace(c, est_lon=-179.9990, est_lat=-17.0004),
    ]
    feats = flight_geojson(across, "xfeat")["features"]
    (track,) = [f["geometry"] for f in feats if f["properties"]["kind"] == "estimate_track"]
    assert track["type"] == "MultiLineString"
    west, east = track["coordinates"]
    assert west[0] == [179.9999, -17.0] and west[-1][0] == 180.0
    assert east[0][0] == -180.0 and east[-1] == [-179.999, -17.0004]
    assert west[-1][1] == east[0][1] == pytest.approx(-17.00005)
    errors = [f["geometry"] for f in feats if f["properties"]["kind"] == "error"]
    assert errors[0]["type"] == "MultiLineString"  # truth west of the line, estimate east
    whole = flight_geojson(flown.outcomes, "xfeat")["features"]
    assert all(f["geometry"]["type"] != "MultiLineString" for f in whole)
