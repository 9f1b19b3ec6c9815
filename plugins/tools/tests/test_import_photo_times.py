"""What a recorded-log import does with a folder of photos beside the log: a log without attitude
(ULog, ArduPilot, ROS bag) is imported level and marked (as the help says), ``--time-offset``
corrects the camera's clock where photos meet camera triggers by their own time (and says what it
was added to when they fall outside the log), a byte-for-byte copy of a photo is imported once,
photos meet as many camera triggers by their capture time rather than their file names, and
``--frame-step`` is checked once. Logs and photos are written with the libraries' own writers
(:mod:`c3_matcher_tools.testing.flightlogs`) over the shipped demo flight."""

from __future__ import annotations

import argparse
import dataclasses
import json
import shutil
import subprocess
from pathlib import Path

import pytest

from c3_matcher.serialize import load_calibration
from c3_matcher_tools.dataset.format import load_dataset
from c3_matcher_tools.dataset.sources.images import folder_shots
from c3_matcher_tools.dataset.sources.options import ImportOptions
from c3_matcher_tools.dataset.sources.pairing import match_shots
from c3_matcher_tools.dataset.sources.ulog import read_ulog
from c3_matcher_tools.testing import flightlogs as fl
from c3_matcher_tools.testing.cli import run_cli

REPO = Path(__file__).resolve().parents[3]
DEMO = REPO / "data" / "flights" / "naip_demo"
CAL = str(DEMO / "calibration.json")
STORE = str(DEMO / "tiles.mbtiles")


def c3(*args: str | Path) -> subprocess.CompletedProcess[str]:
    return run_cli(*args, cwd=REPO)


def _imported(proc: subprocess.CompletedProcess[str]) -> dict:
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout)


@pytest.fixture(scope="module")
def poses() -> list[fl.Pose]:
    return fl.flight_poses(DEMO, range(5))


def _options(**kw: object) -> ImportOptions:
    return ImportOptions(load_calibration(Path(CAL)), Path(STORE), **kw)  # type: ignore[arg-type]


def test_a_ulog_without_attitude_is_imported_level_and_marked(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    """The help says frames without attitude are imported and marked: a log without any
    attitude topic was refused instead."""
    log = fl.write_ulog(tmp_path / "flight.ulg", poses[:3], flaws=("no_attitude",))
    photos = fl.write_exif_photos(tmp_path / "photos", poses[:3], xmp=False)
    flight = tmp_path / "flight"
    summary = _imported(c3("dataset", "import", photos, log, CAL, STORE, flight, "--json"))
    assert summary["frames"] == 3 and summary["attitude_assumed"] == [0, 1, 2]
    assert any(n.startswith("no vehicle_attitude topic: every frame's") for n in summary["notes"])
    frames = load_dataset(flight).frames
    assert all("attitude_assumed" in f.telemetry["flags"] for f in frames)
    assert all(f.attitude_deg[:2] == (0.0, 0.0) for f in frames)


def test_an_ardupilot_log_without_attitude_is_read_and_says_so(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    from c3_matcher_tools.dataset.sources.mavlink import read_mavlink

    track = read_mavlink(fl.write_tlog(tmp_path / "f.tlog", poses[:3], flaws=("no_attitude",)))
    assert track.attitude is None and track.gnss is not None
    assert track.notes[0].startswith("no ATT / ATTITUDE message: every frame's attitude")


def test_a_bag_without_attitude_is_read_level_and_says_so(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    """As a ULog or an ArduPilot log without attitude: read, said in its notes, each frame
    imported level and marked (a bag without an Imu, PoseStamped or Odometry topic was
    refused)."""
    from c3_matcher_tools.dataset.sources.rosbag import NO_ATTITUDE, read_bag

    calibration = load_calibration(Path(CAL))
    bag = fl.write_bag(tmp_path / "bag", poses[:3], calibration, flaws=("no_imu",))
    track, shots, _ = read_bag(bag)
    assert track.attitude is None and len(shots) == 3 and NO_ATTITUDE in track.notes
    flight = tmp_path / "flight"
    args = ("dataset", "import", "-", bag, "-", STORE, flight, "--ground-elevation", "0", "--json")
    summary = _imported(c3(*args))
    assert summary["frames"] == 3 and summary["attitude_assumed"] == [0, 1, 2]
    assert all("attitude_assumed" in f.telemetry["flags"] for f in load_dataset(flight).frames)


def test_time_offset_corrects_the_camera_clock_where_photos_meet_triggers_by_time(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    """Photos 30 s ahead of the log's clock, as many as the triggers: ``--time-offset -30``
    (seconds added to the images' times) moved the trigger times instead, off the log."""
    ahead = [dataclasses.replace(p, t_s=p.t_s + 30.0) for p in poses]
    photos = fl.write_exif_photos(tmp_path / "photos", ahead, xmp=False)
    log = fl.write_ulog(tmp_path / "flight.ulg", poses)
    flight = tmp_path / "f"
    args = ("dataset", "import", photos, log, CAL, STORE, flight, "--time-offset", "-30")
    summary = _imported(c3(*args, "--json"))
    assert summary["frames"] == 5 and summary["skipped"] == []
    assert summary["time_source"] == "camera trigger (5 in the log, 5 image(s))"
    times = [f.telemetry["time_s"] for f in load_dataset(flight).frames]
    assert times == pytest.approx([fl.BOOT_S + p.t_s for p in poses])
    # without the offset the same: as many photos as triggers meet them in capture order, so
    # a camera clock off the log's moves no photo
    track, shots = read_ulog(log), folder_shots(photos)
    taken, skipped, _ = match_shots(track, shots, _options())
    assert [t for _, t in taken] == pytest.approx([fl.BOOT_S + p.t_s for p in poses])
    assert [s.name for s, _ in taken] == [s.name for s in shots] and skipped == []


def test_an_image_outside_the_log_is_said_to_be_there_with_the_offset_added(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    ahead = [dataclasses.replace(p, t_s=p.t_s + 30.0) for p in poses]
    photos = fl.write_exif_photos(tmp_path / "photos", ahead, xmp=False)
    track = read_ulog(fl.write_ulog(tmp_path / "flight.ulg", poses, flaws=("no_trigger",)))
    taken, skipped, _ = match_shots(track, folder_shots(photos), _options(time_offset_s=-27.0))
    assert len(taken) == 4
    assert skipped == [
        (
            "DJI_0004.JPG",
            "at 111.0 s on the log's clock, --time-offset -27 s added, outside the log "
            "(100.0 .. 108.0 s)",
        )
    ]


def test_photos_meet_as_many_triggers_by_capture_time_not_file_name(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    """File names that do not sort in capture order (a camera's counter wrapped): the photos
    take the triggers in the order of their own times, with or without UTC in the log; in file
    order only when asked (``--time-source trigger``)."""
    photos = fl.write_exif_photos(tmp_path / "photos", poses[::-1], xmp=False)  # 0000 is last
    log = fl.write_ulog(tmp_path / "flight.ulg", poses)
    flight = tmp_path / "f"
    summary = _imported(c3("dataset", "import", photos, log, CAL, STORE, flight, "--json"))
    assert summary["frames"] == 5 and summary["skipped"] == []
    assert summary["time_source"].startswith("camera trigger in the images' capture order")
    for f, p, k in zip(load_dataset(flight).frames, poses, range(4, -1, -1), strict=True):
        assert f.telemetry["source_image"] == f"DJI_{k:04d}.JPG"
        assert (f.telemetry["lat"], f.telemetry["lon"]) == pytest.approx((p.lat, p.lon), abs=1e-7)
    track, shots = read_ulog(log), folder_shots(photos)
    asked, _, how = match_shots(track, shots, _options(time_source="trigger"))
    assert [s.name for s, _ in asked] == [f"DJI_{k:04d}.JPG" for k in range(5)]  # as asked
    no_utc = dataclasses.replace(track, utc_offset_s=None)
    taken, _, how = match_shots(no_utc, shots, _options())  # still by capture time
    assert [s.name for s, _ in taken] == [f"DJI_{k:04d}.JPG" for k in range(4, -1, -1)]
    assert "capture order" in how


def test_a_copied_photo_is_imported_once_naming_both(poses: list[fl.Pose], tmp_path: Path) -> None:
    photos = fl.write_exif_photos(tmp_path / "photos", poses[:3])
    shutil.copyfile(photos / "DJI_0001.JPG", photos / "DJI_0001_copy.JPG")
    reason = "a copy of DJI_0001.JPG (the same bytes): imported once, as DJI_0001.JPG"
    own = _imported(c3("dataset", "import", photos, "-", CAL, STORE, tmp_path / "a", "--json"))
    assert own["frames"] == 3
    assert own["skipped"] == [{"image": "DJI_0001_copy.JPG", "reason": reason}]
    plain = tmp_path / "plain"  # no capture time: 3 triggers meet 3 photos, not 4
    plain.mkdir()
    for i, p in enumerate(poses[:3]):
        shutil.copyfile(p.image, plain / f"IMG_{i:04d}.jpg")
    shutil.copyfile(plain / "IMG_0002.jpg", plain / "IMG_0002b.jpg")
    log = fl.write_ulog(tmp_path / "flight.ulg", poses[:3])
    got = _imported(c3("dataset", "import", plain, log, CAL, STORE, tmp_path / "b", "--json"))
    assert got["frames"] == 3 and got["time_source"] == "camera trigger (3 in the log, 3 image(s))"
    assert got["skipped"] == [
        {
            "image": "IMG_0002b.jpg",
            "reason": "a copy of IMG_0002.jpg (the same bytes): imported once, as IMG_0002.jpg",
        }
    ]


def test_frame_step_is_checked_once_on_the_photo_folder_path(
    poses: list[fl.Pose], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from c3_matcher_tools.dataset.sources import cli, images

    calls: list[tuple[int, bool]] = []
    check = images.check_frame_step

    def counted(step: int, *, video: bool) -> None:
        calls.append((step, video))
        check(step, video=video)

    monkeypatch.setattr(images, "check_frame_step", counted)
    photos = fl.write_exif_photos(tmp_path / "photos", poses[:2], xmp=False)
    log = fl.write_ulog(tmp_path / "flight.ulg", poses[:2])
    said: list[str] = []
    args = argparse.Namespace(
        images_dir=photos, telemetry=log, calibration=Path(CAL), store=Path(STORE),
        out=tmp_path / "f", source="auto", frame_step=1, force=False, dem=None, name=None,
        time_source="auto", time_offset=0.0, interval=None, max_gap=1.0, gnss_degraded_m=5.0,
        ground_elevation=None, uncertainty_m=50.0, candidates=3, zoom=None, candidate_size=512,
        seed=0, json=True, image_topic=None, attitude_topic=None, navsat_topic=None,
        camera_info_topic=None,
    )  # fmt: skip
    ctx = argparse.Namespace(out=said.append)
    assert cli.run_log_import(args, ctx) == 0  # type: ignore[arg-type]
    assert calls == [(1, False)] and json.loads(said[0])["frames"] == 2
