"""A run's files are replaced atomically: a write that fails part-way (an error, a file size
limit) leaves the previous file whole and no temporary file behind, and two writers of one file
never share a temporary file (the GeoJSON and the HTML report included)."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from c3_matcher.config import C3Settings
from c3_matcher.errors import InvalidInputError
from c3_matcher_tools.dataset.format import load_dataset
from c3_matcher_tools.run import (
    FlightRun,
    atomic_writer,
    flight_report,
    fly,
    output_dir_name,
    write_flight_outputs,
    write_text_atomically,
)

DEMO = Path(__file__).resolve().parents[3] / "data" / "flights" / "naip_demo"


def test_a_write_that_fails_part_way_leaves_the_previous_file_whole(tmp_path: Path) -> None:
    path = write_text_atomically(tmp_path / "results.jsonl", "the previous run\n")
    with pytest.raises(RuntimeError), atomic_writer(path) as fh:
        fh.write("half of this run")
        raise RuntimeError("interrupted")
    assert path.read_text() == "the previous run\n"
    assert [p.name for p in tmp_path.iterdir()] == ["results.jsonl"]


def test_a_write_past_the_file_size_limit_leaves_the_previous_file_whole(tmp_path: Path) -> None:
    path = write_text_atomically(tmp_path / "eval.json", "{}\n")
    script = textwrap.dedent(f"""
        import resource
        from pathlib import Path
        from c3_matcher_tools.run import write_text_atomically
        resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))
        try:
            write_text_atomically(Path({str(path)!r}), "x" * 100_000)
        except OSError as exc:
            print("REFUSED", exc)
    """)
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert "REFUSED" in proc.stdout, proc.stderr
    assert path.read_text() == "{}\n"
    assert [p.name for p in tmp_path.iterdir()] == ["eval.json"]


def test_nested_writers_of_one_file_each_have_their_own_temporary_file(tmp_path: Path) -> None:
    path = tmp_path / "report.json"
    with atomic_writer(path) as outer:
        outer.write("outer")
        with atomic_writer(path) as inner:
            inner.write("inner")
        assert path.read_text() == "inner"
    assert path.read_text() == "outer"


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
        frames=flight.frames[:2],
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
