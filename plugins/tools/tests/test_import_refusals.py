"""``dataset import`` from a telemetry CSV drops nothing silently and refuses nonsense by line:
every image without a row and every row without an image is reported, heights are above ground
(an altitude above sea level needs the ground's elevation or a DEM), every refused value names
its CSV line, and a missing output parent is created. The flight is the shipped demo's frames
with their telemetry written out (real imagery)."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
import rasterio
from rasterio.transform import from_origin

from c3_matcher.errors import InvalidInputError
from c3_matcher_tools.dataset.format import load_dataset
from c3_matcher_tools.dataset.importer import ImportSpec, import_csv_flight
from c3_matcher_tools.dataset.sources.options import (
    MAX_CANDIDATES,
    MAX_SEARCH_TILES,
    ProposalOptions,
    max_uncertainty_m,
)
from c3_matcher_tools.dataset.telemetry import read_telemetry_table

REPO = Path(__file__).resolve().parents[3]
DEMO = REPO / "data" / "flights" / "naip_demo"
GROUND_M = 450.0  # a ground elevation for the altitude-above-sea-level cases


def recorded(root: Path, frames: range = range(4), *, msl: bool = False) -> tuple[Path, Path]:
    """IMG_*.jpg and telemetry.csv of the demo's frames (altitude above sea level when
    ``msl``: height + GROUND_M in a column altitude_msl_m)."""
    images = root / "images"
    images.mkdir()
    records = [json.loads(x) for x in (DEMO / "frames.jsonl").read_text().splitlines()]
    height = "altitude_msl_m" if msl else "altitude_m"
    rows = [f"time_s,image,lat,lon,{height},roll_deg,pitch_deg,yaw_deg"]
    for i in frames:
        f = records[i]
        name = f"IMG_{i:04d}.jpg"
        (images / name).write_bytes((DEMO / f["image"]).read_bytes())
        p, (r, pi, y) = f["pose"], f["attitude_deg"]
        h = f["height_m"] + (GROUND_M if msl else 0.0)
        rows.append(
            f"{f['captured_at_ns'] / 1e9},{name},{p['nadir_lat']},{p['nadir_lon']},{h},{r},{pi},{y}"
        )
    csv = root / "telemetry.csv"
    csv.write_text("\n".join(rows) + "\n")
    return images, csv


def spec(
    images: Path,
    csv: Path,
    *,
    ground_elevation_m: float | None = None,
    dem: Path | None = None,
    **proposal: object,
) -> ImportSpec:
    """The demo's calibration and store; ``proposal``: how candidates are proposed."""
    options = ProposalOptions(DEMO / "tiles.mbtiles", **proposal)  # type: ignore[arg-type]
    return ImportSpec(images, csv, DEMO / "calibration.json", options, ground_elevation_m, dem)


def edit_line(csv: Path, line: int, column: int, value: str) -> None:
    lines = csv.read_text().splitlines()
    cells = lines[line - 1].split(",")
    cells[column] = value
    lines[line - 1] = ",".join(cells)
    csv.write_text("\n".join(lines) + "\n")


def test_images_without_rows_and_rows_without_images_are_reported(tmp_path: Path) -> None:
    images, csv = recorded(tmp_path, range(5))
    lines = csv.read_text().splitlines()
    csv.write_text("\n".join(lines[:3] + lines[4:]) + "\n")  # IMG_0002's row gone
    (images / "IMG_0004.jpg").unlink()  # line 5 names it (IMG_0002's row is gone)
    (images / "extra.png").write_bytes((images / "IMG_0000.jpg").read_bytes())
    (images / "notes.txt").write_text("not an image")
    report = import_csv_flight(spec(images, csv), tmp_path / "flight")
    assert report.frames == 3
    assert report.skipped == (
        ("IMG_0002.jpg", "no telemetry row"),
        ("extra.png", "no telemetry row"),
        ("IMG_0004.jpg", "line 5: no such image"),
    )
    text = "\n".join(report.lines())
    assert "skipped 3 image(s)" in text and "IMG_0004.jpg: line 5: no such image" in text
    assert "column 'altitude_m' read as height above ground" in text
    assert len(load_dataset(tmp_path / "flight").frames) == 3


def test_altitude_above_sea_level_needs_the_ground(tmp_path: Path) -> None:
    images, csv = recorded(tmp_path, msl=True)
    with pytest.raises(InvalidInputError, match=r"altitude above sea level.*--ground-elevation"):
        import_csv_flight(spec(images, csv), tmp_path / "a")
    report = import_csv_flight(spec(images, csv, ground_elevation_m=GROUND_M), tmp_path / "b")
    assert list(report.height_sources) == ["column 'altitude_msl_m' minus ground elevation 450 m"]
    assert "sea level go in a column" not in report.notes[0]
    agl = read_telemetry_table(csv, ground_elevation_m=GROUND_M).rows
    (tmp_path / "plain").mkdir()
    _, plain_csv = recorded(tmp_path / "plain", msl=False)
    truth = read_telemetry_table(plain_csv).rows
    assert [round(r.altitude_m, 6) for r in agl] == [round(r.altitude_m, 6) for r in truth]
    frame = load_dataset(tmp_path / "b").frames[0]
    assert frame.telemetry["altitude_msl_m"] == pytest.approx(truth[0].altitude_m + GROUND_M)
    # the ground above the aircraft: refused with the line
    with pytest.raises(InvalidInputError, match=r"line 2: altitude_msl_m .* not above the ground"):
        read_telemetry_table(csv, ground_elevation_m=5000.0)
    # a ground elevation with a column that already is height above ground: contradictory
    with pytest.raises(InvalidInputError, match="already is the height above ground"):
        read_telemetry_table(plain_csv, ground_elevation_m=GROUND_M)


def test_both_altitudes_without_the_ground_take_the_height_unchecked(tmp_path: Path) -> None:
    """A log with the height above ground and the altitude above sea level, and no ground
    elevation to check one against the other: the height is taken as it is (every row was
    refused with 'the DEM has no ground elevation', with no DEM given)."""
    images, csv = recorded(tmp_path)
    lines = csv.read_text().splitlines()
    cells = [line.split(",") for line in lines]
    lines = [",".join([*c, "altitude_msl_m" if i == 0 else str(float(c[4]) + GROUND_M)])
             for i, c in enumerate(cells)]  # fmt: skip
    csv.write_text("\n".join(lines) + "\n")
    report = import_csv_flight(spec(images, csv), tmp_path / "flight")
    assert report.frames == 4 and not report.skipped
    assert list(report.height_sources) == ["column 'altitude_m' read as height above ground"]
    # the note says the sea-level column was not used and why (it told them to add it)
    assert "'altitude_msl_m' (above sea level) not used: no --ground-elevation" in report.notes[0]
    checked = import_csv_flight(spec(images, csv, ground_elevation_m=GROUND_M), tmp_path / "b")
    assert checked.frames == 4 and "checked against" in next(iter(checked.height_sources))
    assert "'altitude_msl_m' read against the ground elevation" in checked.notes[0]
    with pytest.raises(InvalidInputError, match=r"line 2: .* but the ground is at 0 m"):
        read_telemetry_table(csv, ground_elevation_m=0.0)


def test_altitude_above_sea_level_minus_a_dem(tmp_path: Path) -> None:
    images, csv = recorded(tmp_path, msl=True)
    rows = read_telemetry_table(csv, ground_elevation_m=GROUND_M).rows
    dem = tmp_path / "dem.tif"
    lat, lon = rows[0].lat, rows[0].lon
    with rasterio.open(
        dem, "w", driver="GTiff", width=40, height=40, count=1, dtype="float32",
        crs="EPSG:4326", transform=from_origin(lon - 0.02, lat + 0.02, 0.001, 0.001),
    ) as out:  # fmt: skip
        out.write(np.full((1, 40, 40), GROUND_M, np.float32))
    report = import_csv_flight(spec(images, csv, dem=dem), tmp_path / "flight")
    assert list(report.height_sources) == ["column 'altitude_msl_m' minus the DEM dem.tif"]
    by_dem = read_telemetry_table(csv, dem=dem).rows
    assert [r.altitude_m for r in by_dem] == pytest.approx([r.altitude_m for r in rows])


@pytest.mark.parametrize(
    ("line", "column", "value", "needle"),
    [
        (3, 0, "1e308", r"line 3: time_s 1e\+308 is not a capture time"),
        (2, 7, "720", r"line 2: yaw_deg 720 outside \[-360, 360\]"),
        (4, 4, "250000", r"line 4: altitude_m 250000 m above ground is not a UAV's height"),
        (5, 4, "-3", r"line 5: altitude_m -3 must be > 0 m"),
        (2, 2, "91", r"line 2: lat 91 outside"),
        (3, 5, "1.2e2", r"line 3: roll_deg 120: \|roll\| and \|pitch\| must be < 90"),
        (4, 6, "abc", r"line 4: pitch_deg 'abc' is not a number"),
        (5, 3, "inf", r"line 5: lon inf is not finite"),
    ],
)
def test_every_refused_value_names_its_line(
    tmp_path: Path, line: int, column: int, value: str, needle: str
) -> None:
    images, csv = recorded(tmp_path)
    edit_line(csv, line, column, value)
    with pytest.raises(InvalidInputError, match=needle):
        import_csv_flight(spec(images, csv), tmp_path / "flight")
    assert not (tmp_path / "flight").exists()


def test_many_refused_lines_are_all_named(tmp_path: Path) -> None:
    _, csv = recorded(tmp_path, range(14))
    for line in range(2, 16):
        edit_line(csv, line, 7, "999")
    with pytest.raises(InvalidInputError, match=r"line 2: yaw_deg .*and 4 more, on lines 12-15\)"):
        read_telemetry_table(csv)


def test_missing_output_parent_is_created(tmp_path: Path) -> None:
    images, csv = recorded(tmp_path, range(2))
    out = tmp_path / "new" / "deeper" / "flight"
    report = import_csv_flight(spec(images, csv), out)
    assert report.frames == 2 and (out / "dataset.json").is_file()
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(InvalidInputError, match="not a directory"):
        import_csv_flight(spec(images, csv), blocker / "flight")


@pytest.mark.parametrize("uncertainty_m", [30_000.0, 1e300])
def test_an_uncertainty_beyond_the_tiles_searched_is_refused_naming_the_reach(
    tmp_path: Path, uncertainty_m: float
) -> None:
    images, csv = recorded(tmp_path, range(2))
    needle = (
        rf"--uncertainty-m: .* beyond {MAX_SEARCH_TILES} tiles of the store's zoom 15 \((\d+) m"
    )
    with pytest.raises(InvalidInputError, match=needle) as refused:
        import_csv_flight(spec(images, csv, uncertainty_m=uncertainty_m), tmp_path / "flight")
    reach = re.search(needle, str(refused.value))
    assert reach is not None  # the reach at the demo's latitude
    assert float(reach.group(1)) == pytest.approx(max_uncertainty_m(15, 47.0), rel=0.01)
    assert not (tmp_path / "flight").exists()
    within = import_csv_flight(spec(images, csv, uncertainty_m=20_000.0), tmp_path / "flight")
    assert within.frames == 2


@pytest.mark.parametrize(
    ("header", "needle"),
    [
        ("time_s,image,lat,lon,altitude_m,roll_deg,pitch_deg,yaw_deg,LAT", "'lat' twice"),
        ("time_s,image,lat,lon,altitude_m,roll_deg,pitch_deg,yaw_deg,altitude", "'altitude_m' and"),
    ],
)
def test_a_column_given_twice_is_refused_rather_than_guessed(
    tmp_path: Path, header: str, needle: str
) -> None:
    _, csv = recorded(tmp_path, range(2))
    lines = csv.read_text().splitlines()
    rows = [header] + [f"{row},0" for row in lines[1:]]
    csv.write_text("\n".join(rows) + "\n")
    with pytest.raises(InvalidInputError, match=f"gives a column more than once \\({needle}"):
        read_telemetry_table(csv)


@pytest.mark.parametrize("candidates", [0, MAX_CANDIDATES + 1])
def test_candidates_beyond_what_the_search_reaches_are_refused(
    tmp_path: Path, candidates: int
) -> None:
    images, csv = recorded(tmp_path, range(2))
    with pytest.raises(InvalidInputError, match=rf"--candidates.*\[1, {MAX_CANDIDATES}\]"):
        spec(images, csv, candidates=candidates)


@pytest.mark.parametrize(
    ("bad", "refusal"),
    [
        ({"uncertainty_m": -1.0}, "--uncertainty-m: must be >= 0, got -1.0"),
        ({"uncertainty_m": math.nan}, "--uncertainty-m: must be >= 0, got nan"),
        ({"candidates": 0}, f"--candidates: must be in [1, {MAX_CANDIDATES}], got 0"),
        (
            {"candidates": MAX_CANDIDATES + 1},
            f"--candidates: must be in [1, {MAX_CANDIDATES}], got {MAX_CANDIDATES + 1}",
        ),
        ({"candidate_size_px": 32}, "--candidate-size: must be in [64, 4096] px, got 32"),
    ],
)
def test_the_proposal_options_refuse_a_bad_value_naming_the_option(
    bad: dict[str, float], refusal: str
) -> None:
    """How every import proposes candidates is one record, checked when made: a bad value is
    refused naming the option that gave it, before any input is read."""
    with pytest.raises(InvalidInputError) as refused:
        ProposalOptions(DEMO / "tiles.mbtiles", **bad)  # type: ignore[arg-type]
    assert str(refused.value) == refusal
    assert refused.value.field == refusal.split(":")[0]


def test_frames_outside_the_store_beyond_those_shown_are_counted_not_hidden() -> None:
    from c3_matcher_tools.dataset.proposals import StoreProposals
    from c3_matcher_tools.dataset.telemetry import TelemetryRow

    rows = [TelemetryRow(i, float(i), f"IMG_{i}.jpg", 63.4, 10.4, 80.0, 0, 0, 0) for i in range(6)]
    proposals = StoreProposals(18, [((10.4, 63.4), None)] * 6, rows, "", "")
    with pytest.raises(InvalidInputError) as refused:
        proposals.refuse_outside("flight.ulg", lambda r: r.image, shown=5)
    message = str(refused.value)
    assert message.startswith("flight.ulg: 6 frame(s) look outside")
    assert "IMG_4.jpg" in message and "IMG_5.jpg" not in message
    assert message.endswith(" and 1 more")


def test_a_bad_calibration_file_is_named_as_the_argument_given(tmp_path: Path) -> None:
    """``dataset import``'s CALIBRATION is a positional argument: a missing or malformed file
    is named so (it read ``--calibration PATH``, an option the command does not have)."""
    images, csv = recorded(tmp_path)
    proposal = ProposalOptions(DEMO / "tiles.mbtiles")
    missing = ImportSpec(images, csv, tmp_path / "none.json", proposal)
    with pytest.raises(InvalidInputError) as info:
        import_csv_flight(missing, tmp_path / "flight")
    assert info.value.field == "CALIBRATION" and "none.json: no such file" in str(info.value)
    assert not (tmp_path / "flight").exists()


def test_a_row_with_more_fields_than_the_header_is_refused_not_shifted(tmp_path: Path) -> None:
    """A decimal comma splits a value in two: the values after it would land in the wrong
    columns (a roll of 1,5 read as roll 1, pitch 5, yaw the pitch). Refused, naming the line."""
    _, csv = recorded(tmp_path)
    lines = csv.read_text().splitlines()
    lines[2] = lines[2] + ",5"  # line 3 of the file
    csv.write_text("\n".join(lines) + "\n")
    with pytest.raises(InvalidInputError, match=r"line 3: 9 fields, the header names 8"):
        read_telemetry_table(csv)


def test_a_refused_value_names_its_own_line_after_blank_lines(tmp_path: Path) -> None:
    _, csv = recorded(tmp_path)
    header, *rows = csv.read_text().splitlines()
    cells = rows[1].split(",")
    rows[1] = ",".join([*cells[:4], "abc", *cells[5:]])  # the altitude of the second row
    csv.write_text("\n".join([header, "", rows[0], "", "", rows[1], *rows[2:]]) + "\n")
    with pytest.raises(InvalidInputError, match=r"line 6: altitude_m 'abc' is not a number"):
        read_telemetry_table(csv)


def test_empty_trailing_header_columns_are_extra_columns(tmp_path: Path) -> None:
    """A spreadsheet's export ends each line with empty columns: ignored as extra columns are."""
    _, csv = recorded(tmp_path)
    csv.write_text("".join(f"{line},,\n" for line in csv.read_text().splitlines()))
    assert len(read_telemetry_table(csv).rows) == 4


def test_an_empty_image_is_refused_as_one_not_an_internal_error(tmp_path: Path) -> None:
    """OpenCV raises on an empty buffer where it returns nothing for a damaged one."""
    images, csv = recorded(tmp_path)
    (images / "IMG_0002.jpg").write_bytes(b"")
    with pytest.raises(InvalidInputError, match=r"IMG_0002.jpg: an empty file, not an image"):
        import_csv_flight(spec(images, csv), tmp_path / "out")
    assert not (tmp_path / "out").exists()


# --- options that a source would not use; the ground given twice; attitude in radians -------


@pytest.mark.parametrize(
    ("telemetry", "options", "refused"),
    [
        ("t.csv", ["--time-offset", "5"], "--time-offset: not used by an import from a telemetry "
         "CSV (its rows name their images and state each frame's telemetry): leave it out"),
        ("t.csv", ["--max-gap", "0.01", "--time-source", "order", "--interval", "3"],
         "--time-source, --interval, --max-gap: not used by an import from a telemetry CSV"),
        ("t.csv", ["--gnss-degraded-m", "0.1", "--image-topic", "/cam"],
         "--gnss-degraded-m, --image-topic: not used by an import from a telemetry CSV"),
        ("t.csv", ["--max-gap", "1"], "--max-gap: not used by an import from a telemetry CSV"),
        ("f.ulg", ["--navsat-topic", "/fix"], "--navsat-topic: not used by an import from a PX4 "
         "ULog (only a ROS bag has topics)"),
        ("-", ["--time-source", "trigger"], "--time-source: not used by an import from a photo "
         "folder"),
    ],
    ids=["csv-offset", "csv-pairing", "csv-gnss-topic", "csv-default-value", "ulog-topic", "exif"],
)  # fmt: skip
def test_options_a_source_would_not_use_are_refused_naming_them(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], telemetry: str, options: list[str],
    refused: str,
) -> None:  # fmt: skip
    """A telemetry CSV import took every recorded-log option and used none (its report even
    said "offset +0.000 s" after --time-offset 5); a bag's topic options were taken by any
    import. Refused before any input is read (the inputs here are placeholders)."""
    from c3_matcher.cli import main

    out = tmp_path / "out"
    argv = ["dataset", "import", "images", telemetry, "cal.json", "tiles.mbtiles", str(out)]
    assert main([*argv, *options]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"c3-matcher: {refused}") and "\n" not in err, err
    assert not out.exists()


def test_a_ground_elevation_and_a_dem_are_refused_together_for_a_log_as_for_a_csv(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A log import took both and used the DEM alone, giving frames where the DEM has no value
    another frame's height (flagged) instead of the elevation given; a CSV import refused the
    pair. One rule now, before the log is read."""
    from c3_matcher.cli import main
    from c3_matcher_tools.testing import flightlogs as fl
    from c3_matcher_tools.testing.flightlogs.ulog import write_ulog

    poses = fl.flight_poses(DEMO, range(4))
    images = tmp_path / "images"
    images.mkdir()
    for i, p in enumerate(poses):
        (images / f"IMG_{i:04d}.jpg").write_bytes(p.image.read_bytes())
    log = write_ulog(tmp_path / "flight.ulg", poses)
    dem = tmp_path / "dem.tif"
    with rasterio.open(
        dem, "w", driver="GTiff", width=40, height=40, count=1, dtype="float32",
        crs="EPSG:4326", transform=from_origin(poses[0].lon - 0.02, poses[0].lat + 0.02, 0.001,
                                               0.001),
    ) as raster:  # fmt: skip
        raster.write(np.full((1, 40, 40), fl.GROUND_M, np.float32))
    out = tmp_path / "flight"
    cal, store = DEMO / "calibration.json", DEMO / "tiles.mbtiles"
    argv = ["dataset", "import", images, log, cal, store, out, "--dem", dem]
    assert main([*map(str, argv), "--ground-elevation", "500"]) == 2
    assert capsys.readouterr().err.strip() == (
        "c3-matcher: --ground-elevation: give it or --dem, not both"
    )
    assert not out.exists()
    with pytest.raises(InvalidInputError, match="give it or --dem, not both"):  # a CSV's spec
        spec(images, tmp_path / "t.csv", ground_elevation_m=GROUND_M, dem=dem)
    assert main([*map(str, argv), "--json"]) == 0  # the DEM alone
    assert capsys.readouterr().out and len(load_dataset(out).frames) == 4


def _radians(csv: Path) -> None:
    """``csv`` with its roll, pitch and yaw (columns 5-7) in radians."""
    lines = csv.read_text().splitlines()
    for n in range(1, len(lines)):
        cells = lines[n].split(",")
        cells[5:8] = [f"{math.radians(float(c)):.5f}" for c in cells[5:8]]
        lines[n] = ",".join(cells)
    csv.write_text("\n".join(lines) + "\n")


def test_attitude_that_may_be_radians_is_said_naming_the_columns(tmp_path: Path) -> None:
    """A CSV of radians imported silently as degrees (roll 0.2 for 11.7 deg); the only hint,
    "(radians?)", came at |roll| >= 90, which radians never reach. Every roll, pitch and yaw
    within +-pi is said in the report, not refused: a flight heading within 3 deg of north with
    a steady camera gives such degrees too, and no CSV tells the two apart."""
    images, csv = recorded(tmp_path)
    report = import_csv_flight(spec(images, csv), tmp_path / "degrees")
    assert not any("radians" in n for n in report.notes)
    _radians(csv)
    report = import_csv_flight(spec(images, csv), tmp_path / "radians")
    said = [n for n in report.notes if "radians" in n]
    assert len(said) == 1, report.notes
    assert said[0].startswith("every 'roll_deg', 'pitch_deg', 'yaw_deg' value lies within +-3.1416")
    assert "convert them to degrees" in said[0]
    assert any("radians" in line for line in report.lines())
    edit_line(csv, 2, 7, "4.0")  # a yaw beyond pi: degrees
    report = import_csv_flight(spec(images, csv), tmp_path / "beyond-pi")
    assert not any("radians" in n for n in report.notes)
