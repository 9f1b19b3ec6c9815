"""A photo folder of a recorded flight holding files that are not readable images: the
``._NAME.jpg`` AppleDouble files macOS writes beside every photo on an SD card, a photo cut short
by a copy. Each is known before the photos meet the log's camera triggers: skipped, named with
its reason in the import's report, and not counted as a photo; where the counts still differ,
the refusal names the files left out. The flight: 4 frames of the shipped demo flight as a PX4
ULog (the project's own writer) with their photos."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import pytest

from c3_matcher_tools.dataset.format import load_dataset
from c3_matcher_tools.testing import flightlogs as fl
from c3_matcher_tools.testing.cli import run_cli
from c3_matcher_tools.testing.flightlogs.ulog import write_ulog

REPO = Path(__file__).resolve().parents[3]
DEMO = REPO / "data" / "flights" / "naip_demo"
CAL = str(DEMO / "calibration.json")
STORE = str(DEMO / "tiles.mbtiles")
PHOTOS = [f"IMG_{i:04d}.jpg" for i in range(4)]


def c3(*args: str | Path) -> subprocess.CompletedProcess[str]:
    return run_cli("dataset", "import", *args, cwd=REPO)


@pytest.fixture(scope="module")
def log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("log")
    return write_ulog(root / "flight.ulg", fl.flight_poses(DEMO, range(4)))


def _photos(root: Path) -> Path:
    folder = root / "photos"
    folder.mkdir()
    for name, p in zip(PHOTOS, fl.flight_poses(DEMO, range(4)), strict=True):
        shutil.copyfile(p.image, folder / name)
    return folder


def _apple_double(of: str) -> bytes:
    """An AppleDouble file as macOS writes it for ``of`` (its resource fork and Finder info):
    the magic, the version, 'Mac OS X', then the entries (their bytes differ by file)."""
    head = b"\x00\x05\x16\x07\x00\x02\x00\x00" + b"Mac OS X        " + b"\x00\x02"
    body = b"com.apple.quarantine\x00" + of.encode() + b"\x00"
    return (head + body).ljust(4096, b"\x00")


def _imported(proc: subprocess.CompletedProcess[str]) -> dict:
    assert proc.returncode == 0, proc.stderr[-2000:]
    return json.loads(proc.stdout)


def test_files_that_are_not_readable_images_are_skipped_and_named_not_counted(
    log: Path, tmp_path: Path
) -> None:
    photos = _photos(tmp_path)
    (photos / "._IMG_0000.jpg").write_bytes(_apple_double("IMG_0000.jpg"))
    whole = (photos / "IMG_0003.jpg").read_bytes()
    (photos / "IMG_0003 (1).jpg").write_bytes(whole[: len(whole) // 2])  # a copy cut short
    out = tmp_path / "flight"
    summary = _imported(c3(photos, log, CAL, STORE, out, "--json"))
    assert summary["frames"] == 4
    assert summary["time_source"] == "camera trigger (4 in the log, 4 image(s))"
    skipped = {s["image"]: s["reason"] for s in summary["skipped"]}
    assert sorted(skipped) == ["._IMG_0000.jpg", "IMG_0003 (1).jpg"]
    assert skipped["._IMG_0000.jpg"] == "not a readable image"
    assert skipped["IMG_0003 (1).jpg"].startswith("not a readable image: ")
    assert [f.telemetry["source_image"] for f in load_dataset(out).frames] == PHOTOS


def test_identical_appledouble_files_are_said_to_be_copies_of_one_that_is_not_an_image(
    log: Path, tmp_path: Path
) -> None:
    """Three ``._`` files of the same bytes: the copy check folds them into the first, which
    is not a readable image; the others are said to be its copies, not 'imported once' as it."""
    photos = _photos(tmp_path)
    junk = _apple_double("")
    for name in ("._IMG_0000.jpg", "._IMG_0001.jpg", "._IMG_0002.jpg"):
        (photos / name).write_bytes(junk)
    summary = _imported(c3(photos, log, CAL, STORE, tmp_path / "flight", "--json"))
    assert summary["frames"] == 4
    copy = "a copy of ._IMG_0000.jpg (the same bytes), not a readable image"
    assert summary["skipped"] == [
        {"image": "._IMG_0000.jpg", "reason": "not a readable image"},
        {"image": "._IMG_0001.jpg", "reason": copy},
        {"image": "._IMG_0002.jpg", "reason": copy},
    ]


def test_where_the_counts_still_differ_the_refusal_names_the_files_left_out(
    log: Path, tmp_path: Path
) -> None:
    photos = _photos(tmp_path)
    (photos / "IMG_0003.jpg").unlink()  # 3 photos for 4 triggers
    for name in ("._IMG_0000.jpg", "._IMG_0001.jpg"):
        (photos / name).write_bytes(_apple_double(name[2:]))
    proc = c3(photos, log, CAL, STORE, tmp_path / "flight")
    assert proc.returncode == 2, proc.stderr
    lines = [x for x in proc.stderr.splitlines() if x.strip()]
    assert len(lines) == 1, proc.stderr
    line = lines[0]
    assert "4 camera trigger(s) in the log but 3 image(s)" in line
    assert "._IMG_0000.jpg" in line and "._IMG_0001.jpg" in line
    assert "not a readable image" in line
    assert not (tmp_path / "flight").exists()
