"""``dataset import`` and the dataset readers at their doors: a FIFO given as TELEMETRY,
CALIBRATION or a dataset's frames.jsonl is refused unread (reading it would wait forever); a
CSV field beyond csv's limit, a record nested 100,000 deep and a quoted line break in an image
name are refused naming the line (never an internal error, never a name silently changed);
line numbers after a record spanning two lines stay right; a row's image is the file it names
in IMAGES_DIR, so ``./IMG.jpg`` after ``IMG.jpg`` is the same photo, refused, and a name
outside IMAGES_DIR is refused. The flight is the shipped demo's frames with their telemetry
written out (real imagery)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import pytest

from c3_matcher.errors import InvalidInputError
from c3_matcher_tools.dataset.format import load_dataset
from c3_matcher_tools.dataset.importer import ImportSpec, import_csv_flight
from c3_matcher_tools.dataset.sources.options import ProposalOptions
from c3_matcher_tools.dataset.telemetry import read_telemetry_table
from c3_matcher_tools.testing.cli import run_cli

REPO = Path(__file__).resolve().parents[3]
DEMO = REPO / "data" / "flights" / "naip_demo"
HEADER = "time_s,image,lat,lon,altitude_m,roll_deg,pitch_deg,yaw_deg"


def _rows(images: Path, count: int = 3) -> list[str]:
    """The demo's first ``count`` frames copied into ``images`` as IMG_i.jpg, and their
    telemetry rows (the CSV's lines after the header)."""
    images.mkdir()
    rows = []
    for i, line in enumerate((DEMO / "frames.jsonl").read_text().splitlines()[:count]):
        f = json.loads(line)
        shutil.copyfile(DEMO / f["image"], images / f"IMG_{i}.jpg")
        p, (r, pi, y) = f["pose"], f["attitude_deg"]
        t, lat, lon = f["captured_at_ns"] / 1e9, p["nadir_lat"], p["nadir_lon"]
        rows.append(f"{t},IMG_{i}.jpg,{lat},{lon},{f['height_m']},{r},{pi},{y}")
    return rows


def _csv(path: Path, rows: list[str]) -> Path:
    path.write_text("\n".join([HEADER, *rows]) + "\n")
    return path


def _spec(images: Path, csv: Path, calibration: Path = DEMO / "calibration.json") -> ImportSpec:
    return ImportSpec(images, csv, calibration, ProposalOptions(DEMO / "tiles.mbtiles"))


def _refused(proc: subprocess.CompletedProcess[str], *needles: str) -> str:
    """Exit 2 with one error line naming each needle; the line."""
    assert proc.returncode == 2, (proc.returncode, proc.stderr[-2000:])
    lines = [x for x in proc.stderr.splitlines() if x.strip()]
    assert len(lines) == 1, proc.stderr
    assert all(n in lines[0] for n in needles), lines[0]
    return lines[0]


@pytest.mark.parametrize("which", ["telemetry", "calibration"])
def test_a_fifo_as_telemetry_or_calibration_is_refused_not_waited_on(
    tmp_path: Path, which: str
) -> None:
    images = tmp_path / "images"
    csv = _csv(tmp_path / "t.csv", _rows(images))
    calibration = DEMO / "calibration.json"
    fifo = tmp_path / ("t.csv" if which == "telemetry" else "cal.json")
    if which == "telemetry":
        csv.unlink()
    os.mkfifo(fifo)
    given = (fifo, calibration) if which == "telemetry" else (csv, fifo)
    proc = run_cli(
        "dataset", "import", images, *given, DEMO / "tiles.mbtiles", tmp_path / "out",
        cwd=tmp_path, timeout=60,
    )  # fmt: skip
    _refused(proc, which.upper(), f"{fifo} is a FIFO, not a file")
    assert not (tmp_path / "out").exists()


def test_a_field_beyond_the_csv_limit_is_refused_naming_its_line(tmp_path: Path) -> None:
    rows = _rows(tmp_path / "images")
    rows[1] = rows[1].replace("IMG_1.jpg", "x" * 200_000)
    with pytest.raises(
        InvalidInputError, match=r"t\.csv: line 3: unreadable record \(field larger"
    ):
        read_telemetry_table(_csv(tmp_path / "t.csv", rows))


def test_a_line_break_in_an_image_name_is_refused_and_later_lines_keep_their_numbers(
    tmp_path: Path,
) -> None:
    """The record on lines 3-4 is one row: its image name holds a line break (once silently
    dropped, ``IMG\\n_1.jpg`` read as ``IMG_1.jpg``); the bad height on line 5 is named line 5."""
    rows = _rows(tmp_path / "images")
    rows[1] = rows[1].replace("IMG_1.jpg", '"IMG\n_1.jpg"')
    rows[2] = rows[2].rsplit(",", 4)[0] + ",abc,0,0,0"  # its height
    with pytest.raises(InvalidInputError) as info:
        read_telemetry_table(_csv(tmp_path / "t.csv", rows))
    said = str(info.value)
    assert "line 3: image 'IMG\\n_1.jpg' holds a line break" in said
    assert "line 5: altitude_m 'abc' is not a number" in said


def test_a_photo_named_twice_however_spelled_is_refused_naming_both_lines(tmp_path: Path) -> None:
    images = tmp_path / "images"
    rows = _rows(images)
    rows[1] = rows[1].replace("IMG_1.jpg", "./IMG_0.jpg")
    with pytest.raises(InvalidInputError, match=r"line 3: image './IMG_0.jpg' already on line 2"):
        import_csv_flight(_spec(images, _csv(tmp_path / "t.csv", rows)), tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_a_symbolic_link_to_a_photo_named_is_the_same_photo(tmp_path: Path) -> None:
    images = tmp_path / "images"
    rows = _rows(images)
    (images / "again.jpg").symlink_to("IMG_0.jpg")
    rows[1] = rows[1].replace("IMG_1.jpg", "again.jpg")
    with pytest.raises(InvalidInputError, match=r"line 3: image 'again.jpg' already on line 2"):
        import_csv_flight(_spec(images, _csv(tmp_path / "t.csv", rows)), tmp_path / "out")


@pytest.mark.parametrize("name", ["../IMG_0.jpg", "{outside}", "sub/../../IMG_0.jpg"])
def test_an_image_outside_images_dir_is_refused_naming_its_line(tmp_path: Path, name: str) -> None:
    images = tmp_path / "images"
    rows = _rows(images)
    shutil.copyfile(images / "IMG_0.jpg", tmp_path / "IMG_0.jpg")
    name = name.format(outside=tmp_path / "IMG_0.jpg")
    rows[0] = rows[0].replace("IMG_0.jpg", name)
    with pytest.raises(InvalidInputError, match=r"line 2: image .* is outside IMAGES_DIR"):
        import_csv_flight(_spec(images, _csv(tmp_path / "t.csv", rows)), tmp_path / "out")


def test_names_spelled_otherwise_are_imported_as_the_files_they_are(tmp_path: Path) -> None:
    """``./IMG_0.jpg`` and an absolute path inside IMAGES_DIR name IMG_0.jpg and IMG_1.jpg:
    imported, recorded under their plain names and not listed as without a row."""
    images = tmp_path / "images"
    rows = _rows(images)
    rows[0] = rows[0].replace("IMG_0.jpg", "./IMG_0.jpg")
    rows[1] = rows[1].replace("IMG_1.jpg", str(images.absolute() / "IMG_1.jpg"))
    report = import_csv_flight(_spec(images, _csv(tmp_path / "t.csv", rows)), tmp_path / "out")
    assert report.frames == 3 and report.skipped == ()
    frames = load_dataset(tmp_path / "out").frames
    assert [f.telemetry["source_image"] for f in frames] == ["IMG_0.jpg", "IMG_1.jpg", "IMG_2.jpg"]


def _dataset(root: Path) -> Path:
    """The demo's dataset.json, calibration, store and first two frame records."""
    root.mkdir()
    for name in ("dataset.json", "calibration.json", "tiles.mbtiles"):
        shutil.copyfile(DEMO / name, root / name)
    lines = (DEMO / "frames.jsonl").read_text().splitlines()[:2]
    (root / "frames.jsonl").write_text("\n".join(lines) + "\n")
    return root


def test_a_frame_record_nested_too_deeply_is_refused_naming_its_line(tmp_path: Path) -> None:
    root = _dataset(tmp_path / "flight")
    with (root / "frames.jsonl").open("a") as f:
        f.write("[" * 100_000 + "]" * 100_000 + "\n")
    with pytest.raises(
        InvalidInputError, match=r"frames.jsonl:3: bad frame record: .*nested too deep to read"
    ):
        load_dataset(root)
    proc = run_cli("dataset", "info", root, cwd=tmp_path, timeout=120)
    _refused(proc, "frames.jsonl:3: bad frame record", "nested too deep to read")


def test_a_dataset_json_nested_too_deeply_is_refused_naming_it(tmp_path: Path) -> None:
    root = _dataset(tmp_path / "flight")
    (root / "dataset.json").write_text("{" + '"a":{' * 100_000 + "}" * 100_001)
    with pytest.raises(InvalidInputError, match=r"dataset.json: .*nested too deep to read"):
        load_dataset(root)


def test_a_fifo_as_frames_jsonl_is_refused_not_waited_on(tmp_path: Path) -> None:
    root = _dataset(tmp_path / "flight")
    (root / "frames.jsonl").unlink()
    os.mkfifo(root / "frames.jsonl")
    proc = run_cli("dataset", "info", root, cwd=tmp_path, timeout=60)
    _refused(proc, "frames.jsonl: is a FIFO, not a file of frame records")
