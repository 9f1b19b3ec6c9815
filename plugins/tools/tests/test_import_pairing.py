"""How ``dataset import`` pairs images with a recorded log, and what it refuses: photos and camera
triggers of different counts are never paired in order silently (each photo goes to the trigger
nearest its own UTC time, or the import is refused saying the way out), a video keeps its own clock,
a partly timed folder is told how many photos lack a time, ``--frame-step`` is for videos and bags
only, a missing IMAGES is called missing, and every path reads its images alike (a truncated JPEG is
refused, quietly). As many timed photos as triggers take them in capture order, not file-name order;
``--time-offset`` moves the images' own times, never a photo off its trigger; a copy of a photo is
imported once; a log without attitude (ULog, ArduPilot, ROS bag) is imported level and marked. Logs
and photos are written with the libraries' own writers (:mod:`c3_matcher_tools.testing.flightlogs`)
over the shipped demo flight."""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from c3_matcher.errors import InvalidInputError
from c3_matcher.serialize import load_calibration
from c3_matcher_tools.dataset.format import load_dataset
from c3_matcher_tools.dataset.importer import ImportSpec, import_csv_flight
from c3_matcher_tools.dataset.sources.images import folder_shots
from c3_matcher_tools.dataset.sources.options import ImportOptions, ProposalOptions
from c3_matcher_tools.dataset.sources.pairing import match_shots, times_apart
from c3_matcher_tools.dataset.sources.ulog import read_ulog
from c3_matcher_tools.testing import flightlogs as fl
from c3_matcher_tools.testing.flightlogs.exif import write_exif_photos
from c3_matcher_tools.testing.flightlogs.mavlink import write_tlog
from c3_matcher_tools.testing.flightlogs.rosbag import GEOID_HEIGHT_M, write_bag
from c3_matcher_tools.testing.flightlogs.ulog import write_ulog

from .conftest import DEMO
from .conftest import DEMO_CALIBRATION as CAL
from .conftest import DEMO_STORE as STORE
from .conftest import run_in_repo as c3


def _refused(proc: subprocess.CompletedProcess[str], *needles: str) -> str:
    """Exit 2 with one error line (nothing else on stderr) naming each needle; the line."""
    assert proc.returncode == 2, (proc.returncode, proc.stdout[-1000:], proc.stderr[-2000:])
    lines = [x for x in proc.stderr.splitlines() if x.strip()]
    assert len(lines) == 1, proc.stderr
    for needle in needles:
        assert needle in lines[0], lines[0]
    return lines[0]


def _imported(proc: subprocess.CompletedProcess[str]) -> dict:
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout)


def _plain(root: Path, poses: list[fl.Pose], name: str = "IMG_{:04d}.jpg") -> Path:
    """The frames as they were rendered: no EXIF (no capture time)."""
    root.mkdir(parents=True)
    for i, p in enumerate(poses):
        shutil.copyfile(p.image, root / name.format(i))
    return root


def _telemetry(kind: str, poses: list[fl.Pose], folder: Path) -> str:
    """TELEMETRY of ``kind``: a ULog of ``poses``, a CSV with its header only, or ``-`` (the
    photos are their own)."""
    if kind == "ulog":
        return str(write_ulog(folder / "flight.ulg", poses))
    if kind == "csv":
        csv = folder / "t.csv"
        csv.write_text("time_s,image,lat,lon,altitude_m,roll,pitch,yaw\n")
        return str(csv)
    return kind


@pytest.fixture(scope="module")
def poses() -> list[fl.Pose]:
    return fl.flight_poses(DEMO, range(5))


def test_a_missing_or_extra_photo_meets_its_own_trigger_by_time(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    log = write_ulog(tmp_path / "flight.ulg", poses)  # one camera trigger per frame
    photos = write_exif_photos(tmp_path / "photos", poses, xmp=False)
    full = _imported(c3("dataset", "import", photos, log, CAL, STORE, tmp_path / "a", "--json"))
    assert full["time_source"] == "camera trigger (5 in the log, 5 image(s))"  # as before
    (photos / "DJI_0002.JPG").rename(tmp_path / "DJI_0002.JPG")  # the camera missed one
    flight = tmp_path / "flight"
    summary = _imported(c3("dataset", "import", photos, log, CAL, STORE, flight, "--json"))
    assert summary["frames"] == 4 and summary["skipped"] == []
    assert summary["time_source"] == (
        "camera trigger nearest each image's own UTC time, the images' times moved +0.00 s (the"
        " camera's clock on the log's, found: that offset pairs 4 of them, the next best, -2.00 s,"
        " 3), within 1 s (5 in the log, 4 image(s): 1 trigger(s) left without an image)"
    )
    frames = load_dataset(flight).frames
    for f, k in zip(frames, (0, 1, 3, 4), strict=True):  # each photo on its own pose
        p = poses[k]
        assert f.telemetry["source_image"] == f"DJI_{k:04d}.JPG"
        assert f.telemetry["time_s"] == pytest.approx(fl.BOOT_S + p.t_s, abs=1e-6)
        assert (f.telemetry["lat"], f.telemetry["lon"]) == pytest.approx((p.lat, p.lon), abs=1e-7)
    # back in, and a stray photo half a second after the second one: 6 photos, 5 triggers
    (tmp_path / "DJI_0002.JPG").rename(photos / "DJI_0002.JPG")
    stray = dataclasses.replace(poses[1], t_s=poses[1].t_s + 0.5)
    write_exif_photos(tmp_path / "stray", [stray], names="DJI_0001b.JPG", xmp=False)
    shutil.copyfile(tmp_path / "stray" / "DJI_0001b.JPG", photos / "DJI_0001b.JPG")
    more = _imported(c3("dataset", "import", photos, log, CAL, STORE, tmp_path / "m", "--json"))
    assert more["frames"] == 5 and more["time_source"].endswith(
        "(5 in the log, 6 image(s): 1 image(s) left without a trigger)"
    )
    assert more["skipped"] == [
        {
            "image": "DJI_0001b.JPG",
            "reason": "its nearest camera trigger (102.00 s) is nearer the time of DJI_0001.JPG",
        }
    ]
    times = [f.telemetry["time_s"] for f in load_dataset(tmp_path / "m").frames]
    assert times == pytest.approx([fl.BOOT_S + p.t_s for p in poses])


def test_untimed_images_and_a_different_trigger_count_are_refused_or_paired_as_asked(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    log = write_ulog(tmp_path / "flight.ulg", poses[:4])  # 4 triggers
    images = _plain(tmp_path / "images", poses)  # 5 images, none with a capture time
    common = (images, log, CAL, STORE)
    _refused(
        c3("dataset", "import", *common, tmp_path / "x"),
        "--time-source: ", "4 camera trigger(s) in the log but 5 image(s)",
        "pairing them in order would put every image after a missing or extra one on another "
        "image's pose", "none of the 5 images states a capture time",
        "remove the images without a trigger", "--time-source trigger to pair them in order",
    )  # fmt: skip
    assert not (tmp_path / "x").exists()
    asked = _imported(
        c3("dataset", "import", *common, tmp_path / "a", "--time-source", "trigger", "--json")
    )
    assert asked["frames"] == 4 and asked["time_source"] == (
        "camera trigger in file order, as asked (4 in the log, 5 image(s): 1 image(s) left "
        "without a trigger)"
    )
    assert asked["skipped"] == [
        {"image": "IMG_0004.jpg", "reason": "no camera trigger left (4 in the log)"}
    ]
    (images / "IMG_0004.jpg").unlink()
    (images / "IMG_0001.jpg").unlink()  # 3 images, 4 triggers
    fewer = _imported(
        c3("dataset", "import", *common, tmp_path / "b", "--time-source", "trigger", "--json")
    )
    assert fewer["frames"] == 3 and fewer["time_source"].endswith(
        "(4 in the log, 3 image(s): 1 trigger(s) left without an image)"
    )


def test_the_refusal_names_exif_only_where_it_would_work(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    track = read_ulog(write_ulog(tmp_path / "flight.ulg", poses[:4]))
    photos = write_exif_photos(tmp_path / "photos", poses, xmp=False)  # 5 timed photos
    shutil.copyfile(poses[0].image, photos / "DJI_0001.JPG")  # its time gone
    options = ImportOptions(load_calibration(Path(CAL)), ProposalOptions(Path(STORE)))
    shots = folder_shots(photos)
    with pytest.raises(InvalidInputError) as partly:
        match_shots(track, shots, options)
    said = str(partly.value)
    assert "1 of the 5 images state no capture time (DJI_0001.JPG)" in said
    assert "give --time-source exif (the 4 that state one, each by its own time)" in said
    timed = [s for s in shots if s.t_s is not None][:3]
    no_utc = dataclasses.replace(track, utc_offset_s=None)
    with pytest.raises(InvalidInputError) as unknown:
        match_shots(no_utc, timed, options)
    said = str(unknown.value)
    assert "4 camera trigger(s) in the log but 3 image(s)" in said
    assert "(the log states no UTC time (no GNSS time))" in said
    assert "--time-source exif" not in said


def test_a_video_keeps_its_own_clock_beside_camera_triggers(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    import cv2

    log = write_ulog(tmp_path / "flight.ulg", poses[:4])  # 4 camera triggers
    video = tmp_path / "nav.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter.fourcc(*"MJPG"), 1.0, (320, 240))
    for p in poses[:4]:  # one frame a second, each frame twice (the frames are 2 s apart)
        for _ in range(2):
            writer.write(cv2.imread(str(p.image)))
    writer.release()
    flight = tmp_path / "flight"
    offset = ("--time-offset", str(fl.BOOT_S))  # the log time of the video's first frame
    summary = _imported(c3("dataset", "import", video, log, CAL, STORE, flight, *offset, "--json"))
    assert summary["frames"] == 8 and summary["skipped"] == []
    assert summary["time_source"].startswith("video clock (the log's 4 camera trigger(s)")
    times = [f.telemetry["time_s"] for f in load_dataset(flight).frames]
    assert times == pytest.approx([fl.BOOT_S + k for k in range(8)])
    stepped = _imported(
        c3("dataset", "import", video, log, CAL, STORE, tmp_path / "s", *offset,
           "--frame-step", "2", "--json")
    )  # fmt: skip
    assert stepped["frames"] == 4
    # without its offset the video starts at the log's clock origin, before the log
    _refused(
        c3("dataset", "import", video, log, CAL, STORE, tmp_path / "x"),
        "no image falls within the log's time span", "--time-offset",
    )  # fmt: skip


def test_a_partly_timed_folder_says_how_many_lack_a_time(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    log = write_ulog(tmp_path / "flight.ulg", poses, flaws=("no_trigger",))
    photos = write_exif_photos(tmp_path / "photos", poses, xmp=False)
    for k in (1, 3):  # two photos without EXIF
        shutil.copyfile(poses[k].image, photos / f"DJI_{k:04d}.JPG")
    _refused(
        c3("dataset", "import", photos, log, CAL, STORE, tmp_path / "x"),
        "no camera trigger in the log",
        "2 of the 5 images state no capture time (DJI_0001.JPG, DJI_0003.JPG)",
        "give --time-source exif to import the 3 that do", "--interval",
    )  # fmt: skip
    summary = _imported(
        c3("dataset", "import", photos, log, CAL, STORE, tmp_path / "f", "--time-source", "exif",
           "--json")
    )  # fmt: skip
    assert summary["frames"] == 3
    assert [s["image"] for s in summary["skipped"]] == ["DJI_0001.JPG", "DJI_0003.JPG"]


@pytest.mark.parametrize(
    ("telemetry", "step", "needle"),
    [
        ("ulog", "5", "takes every N-th frame of a video or of a bag's image topic"),
        ("ulog", "0", "must be >= 1, got 0"),
        ("csv", "-1", "must be >= 1, got -1"),
        ("csv", "5", "not of a folder of images (got 5)"),
        ("-", "2", "not of a folder of images (got 2)"),
    ],
)
def test_frame_step_with_a_folder_is_refused(
    poses: list[fl.Pose], tmp_path: Path, telemetry: str, step: str, needle: str
) -> None:
    photos = write_exif_photos(tmp_path / "photos", poses[:2])
    telemetry = _telemetry(telemetry, poses[:2], tmp_path)
    out = tmp_path / "x"
    _refused(
        c3("dataset", "import", photos, telemetry, CAL, STORE, out, f"--frame-step={step}"),
        "--frame-step: ", needle,
    )  # fmt: skip
    assert not out.exists()


@pytest.mark.parametrize("telemetry", ["ulog", "csv", "-"])
def test_missing_images_are_called_missing(
    poses: list[fl.Pose], tmp_path: Path, telemetry: str
) -> None:
    telemetry = _telemetry(telemetry, poses[:2], tmp_path)
    missing = tmp_path / "nothere.mp4"
    _refused(
        c3("dataset", "import", missing, telemetry, CAL, STORE, tmp_path / "x"),
        f"{missing}: no such file or folder",
    )


def test_a_truncated_jpeg_is_refused_by_every_path_quietly(
    poses: list[fl.Pose], tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    images = _plain(tmp_path / "images", poses[:2])
    whole = (images / "IMG_0001.jpg").read_bytes()
    (images / "IMG_0001.jpg").write_bytes(whole[: len(whole) // 4])  # a copy cut short
    rows = ["time_s,image,lat,lon,altitude_m,roll_deg,pitch_deg,yaw_deg"]
    rows += [
        f"{p.t_s},IMG_{i:04d}.jpg,{p.lat},{p.lon},{p.height_m},{p.roll},{p.pitch},{p.yaw}"
        for i, p in enumerate(poses[:2])
    ]
    csv = tmp_path / "telemetry.csv"
    csv.write_text("\n".join(rows) + "\n")
    spec = ImportSpec(images, csv, Path(CAL), ProposalOptions(Path(STORE)))
    with pytest.raises(InvalidInputError, match="line 3: IMG_0001.jpg: not a readable image"):
        import_csv_flight(spec, tmp_path / "a")
    assert capfd.readouterr().err == ""  # nothing printed beside the refusal
    log = write_ulog(tmp_path / "flight.ulg", poses[:2])
    (images / "IMG_0000.jpg").write_bytes(b"not a jpeg")  # exifread: "format not recognized"
    _refused(
        c3("dataset", "import", images, log, CAL, STORE, tmp_path / "b"),
        "IMAGES: IMG_0000.jpg: not a readable image",
    )


def test_a_photo_folder_skips_an_untimed_photo_among_timed_ones(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    """A photo folder as its own telemetry: a photo without a capture time among photos with
    one was placed at 1970 + its file index, first in the flight; it is skipped, saying why."""
    import piexif

    photos = write_exif_photos(tmp_path / "photos", poses)
    for k in (1, 3):  # their GPS kept, their capture time removed
        path = photos / f"DJI_{k:04d}.JPG"
        exif = piexif.load(str(path))
        exif["Exif"].pop(piexif.ExifIFD.DateTimeOriginal)
        piexif.insert(piexif.dump(exif), str(path))
    summary = _imported(c3("dataset", "import", photos, "-", CAL, STORE, tmp_path / "f", "--json"))
    assert summary["frames"] == 3
    assert [s["image"] for s in summary["skipped"]] == ["DJI_0001.JPG", "DJI_0003.JPG"]
    assert "no EXIF capture time" in summary["skipped"][0]["reason"]
    frames = load_dataset(tmp_path / "f").frames
    assert [f.image.rsplit("/", 1)[-1] for f in frames] == [
        "000000.jpg",
        "000001.jpg",
        "000002.jpg",
    ]
    times = [f.telemetry["time_s"] for f in frames]
    assert times == sorted(times) and times[0] > 1e9  # in flight order, on the UTC clock


def test_a_damaged_ulog_is_named_as_damaged_and_its_reader_keeps_off_stdout(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    """pyulog prints "File corruption detected ..." on stdout (where ``--json`` goes) and the
    refusal blamed a missing topic; stdout now stays clean and the refusal says what pyulog
    found."""
    log = write_ulog(tmp_path / "flight.ulg", poses)
    cut = tmp_path / "cut.ulg"
    cut.write_bytes(log.read_bytes()[:100])
    photos = _plain(tmp_path / "photos", poses)
    proc = c3("dataset", "import", photos, cut, CAL, STORE, tmp_path / "x", "--json")
    assert proc.stdout == ""
    _refused(proc, f"{cut}: the log is damaged or truncated (File corruption detected")


def _options(**kw: object) -> ImportOptions:
    proposal = ProposalOptions(Path(STORE))
    return ImportOptions(load_calibration(Path(CAL)), proposal, **kw)  # type: ignore[arg-type]


def test_a_ulog_without_attitude_is_imported_level_and_marked(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    """The help says frames without attitude are imported and marked: a log without any
    attitude topic was refused instead."""
    log = write_ulog(tmp_path / "flight.ulg", poses[:3], flaws=("no_attitude",))
    photos = write_exif_photos(tmp_path / "photos", poses[:3], xmp=False)
    flight = tmp_path / "flight"
    summary = _imported(c3("dataset", "import", photos, log, CAL, STORE, flight, "--json"))
    assert summary["frames"] == 3 and summary["attitude_assumed"] == [0, 1, 2]
    assert any(n.startswith("no vehicle_attitude topic: every frame's") for n in summary["notes"])
    frames = load_dataset(flight).frames
    assert all("attitude_assumed" in f.telemetry["flags"] for f in frames)
    assert all(f.attitude_deg[:2] == (0.0, 0.0) for f in frames)
    info = c3("dataset", "info", flight)  # says so later too, as the import said it
    assert info.returncode == 0, info.stderr
    assert "  attitude assumed level (no attitude sample): frames 0-2" in info.stdout.splitlines()
    assert json.loads(c3("dataset", "info", flight, "--json").stdout)["import"] == {
        k: v for k, v in summary.items() if k != "dataset"
    }


def test_an_ardupilot_log_without_attitude_is_read_and_says_so(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    from c3_matcher_tools.dataset.sources.mavlink import read_mavlink

    track = read_mavlink(write_tlog(tmp_path / "f.tlog", poses[:3], flaws=("no_attitude",)))
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
    bag = write_bag(tmp_path / "bag", poses[:3], calibration, flaws=("no_imu",))
    track, shots, _ = read_bag(bag)
    assert track.attitude is None and len(shots) == 3 and NO_ATTITUDE in track.notes
    flight = tmp_path / "flight"
    ground = ("--ground-elevation", "0", "--geoid-height", str(GEOID_HEIGHT_M))
    args = ("dataset", "import", "-", bag, "-", STORE, flight, *ground, "--json")
    summary = _imported(c3(*args))
    assert summary["frames"] == 3 and summary["attitude_assumed"] == [0, 1, 2]
    assert all("attitude_assumed" in f.telemetry["flags"] for f in load_dataset(flight).frames)


def test_a_bag_with_a_pose_topic_and_no_imu_takes_its_attitude_from_the_pose(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    """A bag whose only attitude is a ``geometry_msgs/PoseStamped`` (no Imu) is read with
    that attitude, no topic to choose (the test writer failed to write one)."""
    from c3_matcher_tools.dataset.sources.rosbag import read_bag

    calibration = load_calibration(Path(CAL))
    bag = write_bag(tmp_path / "bag", poses[:3], calibration, flaws=("no_imu",), pose_topic=True)
    track, shots, _ = read_bag(bag)
    assert track.attitude is not None and track.attitude.name == "/vehicle/pose"
    assert len(shots) == 3
    rpy = np.array([(p.roll, p.pitch, p.yaw) for p in poses[:3]])
    assert np.allclose(track.attitude.values[:3], rpy, atol=1e-4)


def test_time_offset_corrects_the_camera_clock_where_photos_meet_triggers_by_time(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    """Photos 30 s ahead of the log's clock, as many as the triggers: ``--time-offset -30``
    (seconds added to the images' times) moved the trigger times instead, off the log. Added to
    the photos' own times it leaves their order, so each keeps its trigger's time, and the
    import says so (the report showed the offset as if it had moved the frames)."""
    ahead = [dataclasses.replace(p, t_s=p.t_s + 30.0) for p in poses]
    photos = write_exif_photos(tmp_path / "photos", ahead, xmp=False)
    log = write_ulog(tmp_path / "flight.ulg", poses)
    flight = tmp_path / "f"
    args = ("dataset", "import", photos, log, CAL, STORE, flight, "--time-offset", "-30")
    summary = _imported(c3(*args, "--json"))
    assert summary["frames"] == 5 and summary["skipped"] == []
    assert summary["time_source"] == (
        "camera trigger (5 in the log, 5 image(s)); --time-offset moves the photos' own times, "
        "not their order: each keeps its trigger"
    )
    assert summary["time_offset_s"] == -30.0
    times = [f.telemetry["time_s"] for f in load_dataset(flight).frames]
    assert times == pytest.approx([fl.BOOT_S + p.t_s for p in poses])
    # without the offset the same: as many photos as triggers meet them in capture order, so
    # a camera clock off the log's moves no photo
    track, shots = read_ulog(log), folder_shots(photos)
    pairing = match_shots(track, shots, _options())
    assert [t for _, t in pairing.taken] == pytest.approx([fl.BOOT_S + p.t_s for p in poses])
    assert [s.name for s, _ in pairing.taken] == [s.name for s in shots]
    assert pairing.skipped == () and pairing.notes == ()


def test_an_image_outside_the_log_is_said_to_be_there_with_the_offset_added(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    ahead = [dataclasses.replace(p, t_s=p.t_s + 30.0) for p in poses]
    photos = write_exif_photos(tmp_path / "photos", ahead, xmp=False)
    track = read_ulog(write_ulog(tmp_path / "flight.ulg", poses, flaws=("no_trigger",)))
    pairing = match_shots(track, folder_shots(photos), _options(time_offset_s=-27.0))
    assert len(pairing.taken) == 4
    assert pairing.skipped == (
        (
            "DJI_0004.JPG",
            "at 111.0 s on the log's clock, --time-offset -27 s added, outside the log "
            "(100.0 .. 108.0 s)",
        ),
    )


def test_photos_meet_as_many_triggers_by_capture_time_not_file_name(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    """File names that do not sort in capture order (a camera's counter wrapped): the photos
    take the triggers in the order of their own times, with or without UTC in the log; in file
    order only when asked (``--time-source trigger``)."""
    photos = write_exif_photos(tmp_path / "photos", poses[::-1], xmp=False)  # 0000 is last
    log = write_ulog(tmp_path / "flight.ulg", poses)
    flight = tmp_path / "f"
    summary = _imported(c3("dataset", "import", photos, log, CAL, STORE, flight, "--json"))
    assert summary["frames"] == 5 and summary["skipped"] == []
    assert summary["time_source"].startswith("camera trigger in the images' capture order")
    for f, p, k in zip(load_dataset(flight).frames, poses, range(4, -1, -1), strict=True):
        assert f.telemetry["source_image"] == f"DJI_{k:04d}.JPG"
        assert (f.telemetry["lat"], f.telemetry["lon"]) == pytest.approx((p.lat, p.lon), abs=1e-7)
    track, shots = read_ulog(log), folder_shots(photos)
    asked = match_shots(track, shots, _options(time_source="trigger"))
    assert [s.name for s, _ in asked.taken] == [f"DJI_{k:04d}.JPG" for k in range(5)]  # as asked
    no_utc = dataclasses.replace(track, utc_offset_s=None)
    by_time = match_shots(no_utc, shots, _options())  # still by capture time
    assert [s.name for s, _ in by_time.taken] == [f"DJI_{k:04d}.JPG" for k in range(4, -1, -1)]
    assert "capture order" in by_time.how


def test_a_copied_photo_is_imported_once_naming_both(poses: list[fl.Pose], tmp_path: Path) -> None:
    photos = write_exif_photos(tmp_path / "photos", poses[:3])
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
    log = write_ulog(tmp_path / "flight.ulg", poses[:3])
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
    photos = write_exif_photos(tmp_path / "photos", poses[:2], xmp=False)
    log = write_ulog(tmp_path / "flight.ulg", poses[:2])
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


def test_a_store_folder_is_refused_as_one(tmp_path: Path) -> None:
    """An XYZ tile folder as STORE: said to be a folder, not to be missing."""
    with pytest.raises(InvalidInputError, match="a folder; a dataset's store is one MBTiles file"):
        ProposalOptions(tmp_path).check_store()
    with pytest.raises(InvalidInputError, match="no such tile store"):
        ProposalOptions(tmp_path / "none.mbtiles").check_store()


def test_an_empty_photo_is_refused_as_empty_not_skipped_for_its_gps(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    """It was skipped as "no GPS position in its EXIF", while a photo cut short is refused."""
    from c3_matcher_tools.dataset.sources.exif import read_photo_folder

    photos = write_exif_photos(tmp_path / "photos", poses[:3])
    victim = sorted(photos.iterdir())[1]
    victim.write_bytes(b"")
    with pytest.raises(InvalidInputError, match=f"{victim}: an empty file, not an image"):
        read_photo_folder(photos)


def _clock_reset(photo: Path, when: bytes = b"1970:01:01 00:00:03") -> None:
    """``photo``'s EXIF capture time set to ``when``, as a camera whose clock was reset says."""
    import piexif

    exif = piexif.load(str(photo))
    exif["Exif"][piexif.ExifIFD.DateTimeOriginal] = when
    piexif.insert(piexif.dump(exif), str(photo))


def test_times_apart_are_those_outside_the_largest_group() -> None:
    flight = [1.79e9 + 2 * k for k in range(4)]
    assert times_apart(flight, 10.0) == []
    assert times_apart([flight[0], 3.0, *flight[1:]], 10.0) == [1]
    assert times_apart([3.0, flight[0]], 10.0) == [0]  # of equal groups the later is kept
    assert times_apart([], 10.0) == []


def test_a_photo_whose_clock_was_reset_keeps_its_place_among_as_many_triggers(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    """As many timed photos as triggers take them in capture order: a photo stamped 1970 sorted
    first and moved every photo before it onto the pose of its neighbour's trigger, silently.
    It now keeps its place in file order, and the import's notes name it."""
    photos = write_exif_photos(tmp_path / "photos", poses[:4], xmp=False)
    _clock_reset(photos / "DJI_0002.JPG")
    log = write_ulog(tmp_path / "flight.ulg", poses[:4])
    flight = tmp_path / "f"
    summary = _imported(c3("dataset", "import", photos, log, CAL, STORE, flight, "--json"))
    assert summary["frames"] == 4 and summary["skipped"] == []
    assert summary["time_source"] == "camera trigger (4 in the log, 4 image(s))"
    frames = load_dataset(flight).frames
    for f, p, k in zip(frames, poses[:4], range(4), strict=True):
        assert f.telemetry["source_image"] == f"DJI_{k:04d}.JPG"
        assert (f.telemetry["lat"], f.telemetry["lon"]) == pytest.approx((p.lat, p.lon), abs=1e-7)
    note = (
        "DJI_0002.JPG at 1970-01-01 00:00:03 UTC: a capture time apart from the other photos' "
        "(2026-09-21 14:13:20 UTC .. 2026-09-21 14:13:26 UTC) by more than the camera triggers' "
        "span (a camera clock reset?): paired by its place in file order, the others by their "
        "capture times"
    )
    assert note in summary["notes"]
    record = json.loads((flight / "dataset.json").read_text())["import"]
    assert note in record["notes"]


def test_a_photo_whose_clock_was_reset_is_skipped_from_a_photo_folder(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    """A photo folder is its own telemetry: a photo stamped 1970 among photos of today became
    the flight's first frame, 56 years before the next, silently. Its place is unknown, as is
    that of a photo without a capture time among timed ones: it is skipped, saying why."""
    photos = write_exif_photos(tmp_path / "photos", poses[:4])
    _clock_reset(photos / "DJI_0002.JPG")
    flight = tmp_path / "f"
    summary = _imported(c3("dataset", "import", photos, "-", CAL, STORE, flight, "--json"))
    assert summary["frames"] == 3
    assert summary["skipped"] == [
        {
            "image": "DJI_0002.JPG",
            "reason": "its EXIF capture time (1970-01-01 00:00:03 UTC) lies more than a day apart "
            "from the other photos' (2026-09-21 14:13:20 UTC .. 2026-09-21 14:13:26 UTC): a "
            "camera clock reset, or another day's photo? Its place in the flight is unknown",
        }
    ]
    frames = load_dataset(flight).frames
    assert [f.telemetry["source_image"] for f in frames] == [
        "DJI_0000.JPG",
        "DJI_0001.JPG",
        "DJI_0003.JPG",
    ]


def test_a_time_offset_beyond_any_clock_is_refused_by_the_options() -> None:
    """The command line refuses it while parsing; the options refuse it alike."""
    with pytest.raises(InvalidInputError, match=r"--time-offset: must be in \[-4e\+09, 4e\+09\] s"):
        _options(time_offset_s=1e308)
    assert _options(time_offset_s=-4e9).time_offset_s == -4e9


def test_a_photo_name_that_is_not_utf8_is_refused_naming_it(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    """A photo named in another encoding (a byte that is no UTF-8) ended the import in
    "internal error" where its frame id is made from its name; it is refused, naming it."""
    photos = write_exif_photos(tmp_path / "photos", poses)
    (photos / "DJI_0001.JPG").rename(photos / os.fsdecode(b"DJI_\xe9001.JPG"))
    line = _refused(
        c3("dataset", "import", photos, "-", CAL, STORE, tmp_path / "f"),
        "IMAGES: ",
        "1 photo name(s) not UTF-8 text",
        "DJI_\\udce9001.JPG",
    )
    assert "internal error" not in line and not (tmp_path / "f").exists()
