"""The ground commands refuse nonsense on the command line: exit 2 and one line naming what was
wrong (no traceback, no library warning), nothing written; and they say what they did. Real
imagery: the shipped NAIP sheet (rewritten with a wrong CRS or no data) and the demo flight's
frames with their telemetry."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import rasterio

from c3_matcher_tools.testing.cli import run_cli

REPO = Path(__file__).resolve().parents[1]
NAIP_2020 = REPO / "data" / "imagery" / "naip_timeseries" / "m_4709963_se_14_1_20200831.tif"
FLIGHT = REPO / "data" / "flights" / "naip_demo"


def c3(*args: str | Path, cwd: Path = REPO) -> subprocess.CompletedProcess[str]:
    return run_cli(*args, cwd=cwd, timeout=300)


def refused(proc: subprocess.CompletedProcess[str], needle: str) -> str:
    """Exit 2, and the one error line (progress and JSON log lines aside) contains ``needle``."""
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert "Traceback" not in proc.stderr and "Warning" not in proc.stderr, proc.stderr[-2000:]
    errors = [line for line in proc.stderr.splitlines() if line.startswith("c3-matcher")]
    assert len(errors) == 1 and needle in errors[0], proc.stderr[-2000:]
    return errors[0]


def naip_copy(path: Path, **profile: object) -> Path:
    with rasterio.open(NAIP_2020) as ds:
        data, base = ds.read([1, 2, 3]), dict(ds.profile, count=3)
    base.pop("photometric", None)
    zero = profile.pop("zero", False)
    with rasterio.open(path, "w", **{**base, **profile}) as out:
        out.write(np.zeros_like(data) if zero else data)
    return path


def test_tiles_build_refusals(tmp_path: Path) -> None:
    out = tmp_path / "o.mbtiles"
    wrong = naip_copy(tmp_path / "utm_as_degrees.tif", crs="EPSG:4326")
    refused(c3("tiles", "build", wrong, out), "do not fit EPSG:4326")
    png = tmp_path / "plain.png"
    cv2.imwrite(str(png), cv2.imread(str(REPO / "data" / "demo" / "tile_a.png")))
    refused(c3("tiles", "build", png, out), "no georeference")
    refused(c3("tiles", "build", NAIP_2020, out, "--zoom", "22"), "400,644 tiles planned")
    empty = naip_copy(tmp_path / "zeros.tif", zero=True)
    refused(c3("tiles", "build", empty, out), "no tile holds data")
    refused(c3("tiles", "build", NAIP_2020, out, "--value-range", "9,1"), "LO < HI")
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "plain.png",
        "utm_as_degrees.tif",
        "zeros.tif",
    ]


def test_tiles_build_states_its_value_mapping(tmp_path: Path) -> None:
    done = c3("tiles", "build", NAIP_2020, tmp_path / "o.mbtiles", "--zoom", "14")
    assert done.returncode == 0, done.stderr[-2000:]
    assert "pixel values uint8 as is" in done.stdout


def flight_inputs(root: Path, frames: int = 4) -> tuple[Path, Path]:
    images = root / "images"
    images.mkdir(parents=True)
    rows = ["time_s,image,lat,lon,altitude_m,roll_deg,pitch_deg,yaw_deg"]
    for line in (FLIGHT / "frames.jsonl").read_text().splitlines()[:frames]:
        f = json.loads(line)
        name = Path(f["image"]).name
        (images / name).write_bytes((FLIGHT / f["image"]).read_bytes())
        pose = f["pose"]
        cells = (f["captured_at_ns"] / 1e9, name, pose["nadir_lat"], pose["nadir_lon"])
        rows.append(",".join(map(str, (*cells, f["height_m"], *f["attitude_deg"]))))
    csv = root / "telemetry.csv"
    csv.write_text("\n".join(rows) + "\n")
    return images, csv


def test_dataset_import_refusals_name_the_csv_line(tmp_path: Path) -> None:
    images, csv = flight_inputs(tmp_path)
    lines = csv.read_text().splitlines()
    common = (images, csv, FLIGHT / "calibration.json", FLIGHT / "tiles.mbtiles")
    for line, column, value, needle in (
        (3, 0, "1e308", "line 3: time_s 1e+308"),
        (2, 7, "400", "line 2: yaw_deg 400"),
        (4, 4, "1e6", "line 4: altitude_m 1e+06"),
    ):
        cells = lines[line - 1].split(",")
        cells[column] = value
        csv.write_text("\n".join([*lines[: line - 1], ",".join(cells), *lines[line:]]) + "\n")
        refused(c3("dataset", "import", *common, tmp_path / "out"), needle)
    csv.write_text("\n".join(lines) + "\n")
    refused(
        c3("dataset", "import", *common, tmp_path / "out", "--ground-elevation", "450"),
        "already is the height above ground",
    )
    assert not (tmp_path / "out").exists()


def test_dataset_import_summary_reports_skips_and_creates_the_parent(tmp_path: Path) -> None:
    images, csv = flight_inputs(tmp_path / "in")
    extra = images / "IMG_extra.jpg"
    extra.write_bytes(next(images.iterdir()).read_bytes())
    out = tmp_path / "new" / "flight"
    common = (images, csv, FLIGHT / "calibration.json", FLIGHT / "tiles.mbtiles")
    done = c3("dataset", "import", *common, out, cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-2000:]
    text = done.stdout
    assert text.startswith(f"imported 4 frame(s) from telemetry.csv (telemetry CSV) into {out}")
    assert "IMG_extra.jpg: no telemetry row" in text
    assert "read as height above ground" in text
    info = c3("dataset", "info", out, "--json")
    assert info.returncode == 0, info.stderr[-2000:]
    facts = json.loads(info.stdout)
    assert facts["frames"] == 4 and facts["absent_frames"] is None
    assert facts["ground_truth_frames"] == 0


def test_stopped_tiles_build_leaves_nothing(tmp_path: Path) -> None:
    """SIGTERM (or Ctrl-C) once the build has started: no store, no temporary file, no journal."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "c3_matcher.cli", "tiles", "build", str(NAIP_2020),
         str(tmp_path / "o.mbtiles"), "--zooms", "13-16"],
        stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True, cwd=REPO,
    )  # fmt: skip
    assert proc.stderr is not None
    for line in proc.stderr:  # the first progress line: tiles are being written
        if line.startswith("tiles build o.mbtiles"):
            break
    proc.terminate()
    rest = proc.stderr.read()
    assert proc.wait(timeout=120) == 143, rest
    assert rest.strip().splitlines()[-1] == "c3-matcher: terminated"
    assert list(tmp_path.iterdir()) == []


def test_a_terminated_render_leaves_no_temporary_flight(tmp_path: Path) -> None:
    """SIGTERM is Ctrl-C for every command: the render's temporary directory is given back."""
    store = tmp_path / "naip.mbtiles"
    assert c3("tiles", "build", NAIP_2020, store).returncode == 0
    proc = subprocess.Popen(
        [sys.executable, "-m", "c3_matcher.cli", "dataset", "render", str(NAIP_2020), str(store),
         str(tmp_path / "flight"), "--frames", "400"],
        stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True, cwd=REPO,
    )  # fmt: skip
    assert proc.stderr is not None
    for line in proc.stderr:  # the first progress line: frames are being rendered
        if "render" in line:
            break
    proc.terminate()
    rest = proc.stderr.read()
    assert proc.wait(timeout=120) == 143, rest
    assert rest.strip().splitlines()[-1] == "c3-matcher: terminated"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["naip.mbtiles"]


def test_dataset_render_creates_a_missing_output_parent(tmp_path: Path) -> None:
    store = tmp_path / "naip.mbtiles"
    assert c3("tiles", "build", NAIP_2020, store).returncode == 0
    out = tmp_path / "new" / "deeper" / "flight"
    done = c3("dataset", "render", NAIP_2020, store, out, "--frames", "2")
    assert done.returncode == 0, done.stderr[-2000:]
    assert (out / "dataset.json").is_file()


def test_an_output_under_a_file_is_refused_in_one_line_naming_the_option(tmp_path: Path) -> None:
    """``--out`` a file (replay, eval) or a store path under a file (tiles build): exit 2, the
    option named, before anything runs (it was ``afile File exists``, or an internal error)."""
    a_file = tmp_path / "a_file"
    a_file.write_text("the user's\n")
    for argv, option in [
        (("replay", FLIGHT, "--strategy", "sift_magsac", "--out", a_file), "--out"),
        (("eval", FLIGHT, "--strategy", "sift_magsac", "--out", a_file), "--out"),
        (("tiles", "build", NAIP_2020, a_file / "x.mbtiles"), "mbtiles"),
    ]:
        proc = c3(*argv)
        assert proc.returncode == 2, proc.stderr[-2000:]
        (line,) = proc.stderr.strip().splitlines()
        assert line.startswith(f"c3-matcher: {option}: ") and "a_file is not a directory" in line
    assert a_file.read_text() == "the user's\n" and sorted(tmp_path.iterdir()) == [a_file]
