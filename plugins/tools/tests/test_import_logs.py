"""``c3-matcher dataset import`` from recorded logs: a PX4 ULog, an ArduPilot telemetry log and
DataFlash log, ROS 2 bags (sqlite3 and MCAP) and a photo folder with EXIF/XMP, each written by
the libraries' own writers (:mod:`c3_matcher_tools.testing.flightlogs`) over frames of the
shipped demo flight, whose poses are known. Each imports, replays through xfeat and comes back
within a few metres of where its GNSS says the frame looks; bad logs exit 2 with one line; a
real PX4 log (tests/data/logs, see its ATTRIBUTION.md) is read with its units and topics."""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from c3_matcher.errors import InvalidInputError
from c3_matcher.serialize import load_calibration
from c3_matcher_tools.dataset.format import load_dataset
from c3_matcher_tools.dataset.sources.mavlink import read_mavlink
from c3_matcher_tools.dataset.sources.rosbag import read_bag
from c3_matcher_tools.dataset.sources.track import (
    body_attitude_for_camera,
    gimbal_camera_matrix,
    logs_library,
)
from c3_matcher_tools.dataset.sources.ulog import read_ulog
from c3_matcher_tools.testing import flightlogs as fl
from c3_matcher_tools.testing.cli import run_cli
from c3_matcher_tools.testing.flightlogs.dataflash import write_dataflash
from c3_matcher_tools.testing.flightlogs.exif import write_exif_photos
from c3_matcher_tools.testing.flightlogs.mavlink import write_tlog
from c3_matcher_tools.testing.flightlogs.rosbag import GEOID_HEIGHT_M, write_bag
from c3_matcher_tools.testing.flightlogs.ulog import write_ulog

REPO = Path(__file__).resolve().parents[3]
DEMO = REPO / "data" / "flights" / "naip_demo"
CAL = str(DEMO / "calibration.json")
STORE = str(DEMO / "tiles.mbtiles")
REAL_ULOG = Path(__file__).parent / "data" / "logs" / "px4_cubeorange_sample_log_small.ulg"
FRAMES = range(4)


def c3(*args: str, engine_dir: Path | None = None) -> subprocess.CompletedProcess[str]:
    return run_cli(*args, cwd=REPO, engine_dir=engine_dir)


def _refused(proc: subprocess.CompletedProcess[str], *needles: str) -> None:
    """Exit 2 with one error line naming each needle."""
    assert proc.returncode == 2, (proc.returncode, proc.stderr[-2000:])
    lines = [x for x in proc.stderr.splitlines() if x.strip()]
    assert len(lines) == 1, proc.stderr
    for needle in needles:
        assert needle in lines[0], lines[0]


def _replay_near_gnss(flight: Path, out: Path, engine_dir: Path, bound_m: float = 8.0) -> dict:
    """Replay ``flight`` with xfeat; every frame matches within ``bound_m`` of its telemetry
    look point; returns the report."""
    proc = c3(
        "replay", str(flight), "--strategy", "xfeat", "--out", str(out), "--json",
        engine_dir=engine_dir,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    report = json.loads(proc.stdout)
    results = [json.loads(x) for x in (out / "results.jsonl").read_text().splitlines()]
    errors = [r["telemetry_error_m"] for r in results]
    print(f"{flight.name}: estimate - telemetry m {[round(e or -1, 2) for e in errors]}")
    assert all(r["status"] == "ok" for r in results), [r["status"] for r in results]
    assert all(e is not None and e < bound_m for e in errors), errors
    assert report["with_telemetry"] == len(results)
    assert report["telemetry_error_m_p95"] < bound_m
    html = (out / "report.html").read_text()
    assert "estimate - telemetry" in html
    return report


@pytest.fixture(scope="module")
def poses() -> list[fl.Pose]:
    return fl.flight_poses(DEMO, FRAMES)


def test_ulog_imports_replays_and_reports_error_against_gnss(
    poses: list[fl.Pose], engine_dir: Path, tmp_path: Path
) -> None:
    log = write_ulog(tmp_path / "flight.ulg", poses, flaws=("gnss_loss",))
    images = fl.pose_images(tmp_path, poses)
    flight = tmp_path / "flight"
    proc = c3("dataset", "import", str(images), str(log), CAL, STORE, str(flight))
    assert proc.returncode == 0, proc.stderr
    said = proc.stdout
    assert "imported 4 frame(s) from flight.ulg (PX4 ULog)" in said
    assert "camera trigger (4 in the log, 4 image(s)), offset +0.000 s" in said
    assert "height above ground: altitude - home altitude 500.0 m (4)" in said
    assert "GNSS absent or degraded: frames 1" in said and "skipped: none" in said
    d = load_dataset(flight)
    for f, p in zip(d.frames, poses, strict=True):
        t = f.telemetry
        assert f.height_m == pytest.approx(p.height_m, abs=0.01)
        assert np.allclose(f.attitude_deg, (p.roll, p.pitch, p.yaw), atol=1e-3)
        assert (t["lat"], t["lon"]) == pytest.approx((p.lat, p.lon), abs=1e-7)
        assert t["gnss_degraded"] is (f.index == 1)
    assert d.frames[0].telemetry["gnss_accuracy_m"] == pytest.approx(1.5)
    report = _replay_near_gnss(flight, tmp_path / "replay", engine_dir)
    assert report["gnss_degraded_frames"] == [1]
    assert report["with_truth"] == 0


def test_ulog_frames_without_attitude_are_imported_and_marked(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    log = write_ulog(tmp_path / "flight.ulg", poses)
    images = fl.pose_images(tmp_path, poses)
    flight = tmp_path / "flight"
    # one second after each trigger the attitude (one sample per frame) is 1 s away
    args = ["--time-offset", "1.0", "--max-gap", "0.5", "--json"]
    proc = c3("dataset", "import", str(images), str(log), CAL, STORE, str(flight), *args)
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    assert summary["frames"] == 3 and summary["attitude_assumed"] == [0, 1, 2]
    assert summary["time_offset_s"] == 1.0
    # the last image falls after the log ends: skipped, and said why
    [skipped] = summary["skipped"]
    assert skipped["image"] == "IMG_0003.jpg" and "outside the log" in skipped["reason"]
    d = load_dataset(flight)
    assert all("attitude_assumed" in f.telemetry["flags"] for f in d.frames)
    assert all(f.attitude_deg[:2] == (0.0, 0.0) for f in d.frames)


@pytest.mark.parametrize(
    ("flaws", "extra", "needles"),
    [
        (
            ("no_trigger",),
            ("--time-source", "order", "--interval", "2", "--time-offset", "5000"),
            ("no image falls within the log's time span", "different flights"),
        ),
        (("no_trigger",), (), ("no camera trigger", "--interval")),
    ],
)
def test_bad_ulog_is_refused_with_one_line(
    poses: list[fl.Pose], tmp_path: Path, flaws: tuple[str, ...], extra: tuple[str, ...],
    needles: tuple[str, ...],
) -> None:  # fmt: skip
    log = write_ulog(tmp_path / "flight.ulg", poses, flaws=flaws)
    images = fl.pose_images(tmp_path, poses)
    out = tmp_path / "flight"
    _refused(c3("dataset", "import", str(images), str(log), CAL, STORE, str(out), *extra), *needles)
    assert not out.exists()


def test_real_px4_log_is_read_with_its_topics_and_units() -> None:
    track = read_ulog(REAL_ULOG)
    assert track.kind == "PX4 ULog" and track.position is None  # no vehicle_global_position
    assert "positions from vehicle_gps_position" in track.notes[0]
    assert len(track.attitude or ()) == 1298 and track.gnss is not None and len(track.gnss) == 32
    lat, lon, alt, eph, fix = track.gnss.values[0]
    assert (lat, lon) == pytest.approx((63.4170622, 10.4082151))  # Trondheim, 1e-7 deg ints
    assert alt == pytest.approx(66.814) and eph == pytest.approx(3.26, abs=1e-3) and fix == 3
    assert track.utc_offset_s is not None
    utc = track.gnss.t_s[0] + track.utc_offset_s
    assert 1_618_900_000 < utc < 1_619_100_000  # 2021-04-21, from time_utc_usec
    roll, pitch, yaw = track.attitude.values[0]  # type: ignore[union-attr]
    assert abs(roll) < 5 and abs(pitch) < 5 and -180 <= yaw <= 180  # on the ground
    assert track.height is not None and track.triggers_s is None


@pytest.mark.parametrize("kind", ["tlog", "bin"])
def test_ardupilot_logs_import_and_replay(
    kind: str, poses: list[fl.Pose], engine_dir: Path, tmp_path: Path
) -> None:
    writer = write_tlog if kind == "tlog" else write_dataflash
    log = writer(tmp_path / f"flight.{kind}", poses)
    images = fl.pose_images(tmp_path, poses)
    flight = tmp_path / "flight"
    proc = c3("dataset", "import", str(images), str(log), CAL, STORE, str(flight), "--json")
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    assert summary["frames"] == 4 and summary["skipped"] == []
    assert summary["time_source"].startswith("camera trigger")
    assert summary["height_sources"] == {"altitude - home altitude 500.0 m": 4}
    d = load_dataset(flight)
    assert [f.height_m for f in d.frames] == pytest.approx([p.height_m for p in poses], abs=0.01)
    again = tmp_path / "again"  # the same inputs give the same dataset, bit for bit
    args = ("dataset", "import", str(images), str(log), CAL, STORE, str(again), "--name", "flight")
    assert c3(*args).returncode == 0
    for name in ("frames.jsonl", "dataset.json", "calibration.json"):
        assert (again / name).read_bytes() == (flight / name).read_bytes(), name
    if kind == "tlog":  # one replay per log family keeps the suite short
        _replay_near_gnss(flight, tmp_path / "replay", engine_dir)
    bad = writer(tmp_path / f"bad.{kind}", poses, flaws=("no_attitude",))
    proc = c3("dataset", "import", str(images), str(bad), CAL, STORE, str(tmp_path / "b"), "--json")
    assert proc.returncode == 0, proc.stderr  # imported level, each frame marked, as help says
    assert json.loads(proc.stdout)["attitude_assumed"] == [0, 1, 2, 3]
    if kind == "bin":  # a log cut and joined: its clock steps back
        jump = writer(tmp_path / "jump.bin", poses, flaws=("time_jump",))
        _refused(
            c3("dataset", "import", str(images), str(jump), CAL, STORE, str(tmp_path / "j")),
            "jump.bin",
            "time jumps back 5.000 s",
            "in ATT",
        )


@pytest.mark.parametrize(("storage", "compressed"), [("sqlite3", True), ("mcap", False)])
def test_ros2_bags_import_with_recorded_intrinsics(
    storage: str, compressed: bool, poses: list[fl.Pose], engine_dir: Path, tmp_path: Path
) -> None:
    calibration = load_calibration(DEMO / "calibration.json")
    bag = write_bag(tmp_path / "bag", poses, calibration, storage=storage, compressed=compressed)
    flight = tmp_path / "flight"
    common = ["-", str(bag), "-", STORE]
    _refused(c3("dataset", "import", *common, str(flight)), "--ground-elevation")
    ground = ("--ground-elevation", str(fl.GROUND_M), "--geoid-height", str(GEOID_HEIGHT_M))
    proc = c3("dataset", "import", *common, str(flight), *ground, "--json")
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    assert summary["frames"] == 4 and summary["kind"] == "ROS bag"
    assert summary["height_sources"] == {
        "altitude above the ellipsoid - geoid height -15 m - ground elevation 500 m": 4
    }
    assert [f.height_m for f in load_dataset(flight).frames] == pytest.approx(
        [p.height_m for p in poses], abs=0.01
    )
    d = load_dataset(flight)
    assert np.allclose(d.calibration.K, calibration.K)
    assert np.allclose(d.calibration.distortion, calibration.distortion)
    for f, p in zip(d.frames, poses, strict=True):
        assert np.allclose(f.attitude_deg, (p.roll, p.pitch, p.yaw), atol=1e-4)  # ENU -> NED
        assert f.telemetry["gnss_accuracy_m"] == pytest.approx(1.5)
    suffix = ".jpg" if compressed else ".png"
    assert all(f.image.endswith(suffix) for f in d.frames)
    _, every_other, _ = read_bag(bag, step=2)  # --frame-step: every N-th image of the topic
    assert [s.t_s for s in every_other] == pytest.approx([fl.UTC0 + p.t_s for p in poses[::2]])
    if storage == "mcap":
        _replay_near_gnss(flight, tmp_path / "replay", engine_dir)
    no_gps = write_bag(tmp_path / "nogps", poses, calibration, storage=storage, flaws=("no_gps",))
    _refused(
        c3("dataset", "import", "-", str(no_gps), "-", STORE, str(tmp_path / "x")),
        "no sensor_msgs/NavSatFix topic",
    )


def test_exif_photo_folder_imports_and_replays(
    poses: list[fl.Pose], engine_dir: Path, tmp_path: Path
) -> None:
    photos = write_exif_photos(tmp_path / "photos", poses)
    shutil.copyfile(poses[0].image, photos / "ZZZ_no_gps.jpg")
    flight = tmp_path / "flight"
    proc = c3("dataset", "import", str(photos), "-", CAL, STORE, str(flight))
    assert proc.returncode == 0, proc.stderr
    assert "skipped 1 image(s):" in proc.stdout
    assert "ZZZ_no_gps.jpg: no GPS position in its EXIF" in proc.stdout
    assert "XMP RelativeAltitude (above the take-off point) (4)" in proc.stdout
    d = load_dataset(flight)
    assert len(d.frames) == 4
    for f, p in zip(d.frames, poses, strict=True):
        assert np.allclose(f.attitude_deg, (p.roll, p.pitch, p.yaw), atol=0.01)  # from the gimbal
        assert f.height_m == pytest.approx(p.height_m, abs=1e-3)
        assert (f.telemetry["lat"], f.telemetry["lon"]) == pytest.approx((p.lat, p.lon), abs=1e-6)
    _replay_near_gnss(flight, tmp_path / "replay", engine_dir)


def test_gimbal_straight_down_is_the_default_mount_level() -> None:
    calibration = load_calibration(DEMO / "calibration.json")
    r = gimbal_camera_matrix(0.0, -90.0, 30.0)
    roll, pitch, yaw = body_attitude_for_camera(r, calibration)
    assert (roll, pitch) == pytest.approx((0.0, 0.0), abs=1e-9)
    assert yaw == pytest.approx(30.0)
    assert math.isfinite(roll)


def test_ulog_with_a_video_and_a_rangefinder(poses: list[fl.Pose], tmp_path: Path) -> None:
    import cv2

    log = write_ulog(tmp_path / "flight.ulg", poses, flaws=("no_trigger",), rangefinder=True)
    video = tmp_path / "nav.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 0.5, (320, 240))
    for p in poses:  # one frame every 2 s, as the demo flight's frames
        writer.write(cv2.imread(str(p.image)))
    writer.release()
    flight = tmp_path / "flight"
    offset = str(fl.BOOT_S)  # the log time of the video's first frame
    proc = c3(
        "dataset", "import", str(video), str(log), CAL, STORE, str(flight), "--time-offset",
        offset, "--json",
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    assert summary["frames"] == 4 and summary["time_source"] == "video clock"
    # the rangefinder wins over altitude - home (which would say 20 m more)
    assert summary["height_sources"] == {"vehicle_local_position.dist_bottom (above ground)": 4}
    d = load_dataset(flight)
    for f, p in zip(d.frames, poses, strict=True):
        assert f.height_m == pytest.approx(p.height_m, abs=0.01)
        assert (f.telemetry["lat"], f.telemetry["lon"]) == pytest.approx((p.lat, p.lon), abs=1e-7)
        assert f.telemetry["source_image"] == f"nav.avi#{f.index}"


def test_ulog_with_photos_matched_by_exif_time(poses: list[fl.Pose], tmp_path: Path) -> None:
    import dataclasses

    log = write_ulog(tmp_path / "flight.ulg", poses, flaws=("no_trigger",))
    photos = write_exif_photos(tmp_path / "photos", poses, xmp=False)
    flight = tmp_path / "flight"
    proc = c3("dataset", "import", str(photos), str(log), CAL, STORE, str(flight), "--json")
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    assert summary["frames"] == 4 and "own UTC time" in summary["time_source"]
    d = load_dataset(flight)
    for f, p in zip(d.frames, poses, strict=True):  # attitude from the log, times from EXIF
        assert np.allclose(f.attitude_deg, (p.roll, p.pitch, p.yaw), atol=1e-3)
        assert f.telemetry["time_s"] == pytest.approx(fl.BOOT_S + p.t_s, abs=1e-3)
    # photos of another flight 5 km away, at the same times: refused
    away = [dataclasses.replace(p, lat=p.lat + 0.045) for p in poses]
    other = write_exif_photos(tmp_path / "other", away, xmp=False)
    _refused(
        c3("dataset", "import", str(other), str(log), CAL, STORE, str(tmp_path / "x")),
        "images and log of different flights",
        "km",
    )


def test_height_from_a_dem(poses: list[fl.Pose], tmp_path: Path) -> None:
    import rasterio
    from affine import Affine

    def dem(path: Path, west: float, north: float, nodata_from_col: int = 200) -> Path:
        """200 x 200 px of 0.0002 deg at GROUND_M, nodata from column ``nodata_from_col``."""
        grid = Affine.translation(west, north) @ Affine.scale(0.0002, -0.0002)
        values = np.full((1, 200, 200), fl.GROUND_M, np.float32)
        values[:, :, nodata_from_col:] = -9999.0
        with rasterio.open(
            path, "w", driver="GTiff", width=200, height=200, count=1, dtype="float32",
            crs="EPSG:4326", transform=grid, nodata=-9999.0,
        ) as ds:  # fmt: skip
            ds.write(values)
        return path

    log = write_ulog(tmp_path / "flight.ulg", poses)
    images = fl.pose_images(tmp_path, poses)
    west, north = poses[0].lon - 0.015, poses[0].lat + 0.02
    here = dem(tmp_path / "dem.tif", west, north)
    flight = tmp_path / "flight"
    args = ["--dem", str(here), "--json"]
    proc = c3("dataset", "import", str(images), str(log), CAL, STORE, str(flight), *args)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["height_sources"] == {"altitude above sea level - DEM": 4}
    assert [f.height_m for f in load_dataset(flight).frames] == pytest.approx(
        [p.height_m for p in poses], abs=0.01
    )
    # nodata over the last two frames (between frames 1 and 2 in longitude): imported, marked
    col = round(((poses[1].lon + poses[2].lon) / 2 - west) / 0.0002)
    part = dem(tmp_path / "part.tif", west, north, nodata_from_col=col)
    proc = c3(
        "dataset", "import", str(images), str(log), CAL, STORE, str(tmp_path / "p"), "--dem",
        str(part), "--json",
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    assert summary["frames"] == 4 and summary["height_assumed"] == [2, 3]
    marked = load_dataset(tmp_path / "p").frames[3]
    assert "height_assumed" in marked.telemetry["flags"]
    assert marked.telemetry["height_source"] == "nearest frame's height (the DEM has no value here)"
    elsewhere = dem(tmp_path / "far.tif", 10.0, 60.0)
    _refused(
        c3("dataset", "import", str(images), str(log), CAL, STORE, str(tmp_path / "x"),
           "--dem", str(elsewhere)),
        "no height above ground for any frame",
    )  # fmt: skip


@pytest.mark.parametrize(
    ("name", "needle"),
    [
        ("bad.ulg", "not a readable PX4 ULog"),
        ("bad.bin", "not an ArduPilot DataFlash log"),
        ("bad.tlog", "not a readable MAVLink telemetry log"),
        ("bad.mcap", "not a readable ROS bag"),
    ],
)
def test_damaged_logs_are_refused_with_one_line(
    name: str, needle: str, poses: list[fl.Pose], tmp_path: Path
) -> None:
    log = tmp_path / name
    log.write_bytes(np.random.default_rng(7).integers(0, 256, 4000, dtype=np.uint8).tobytes())
    images = "-" if name.endswith(".mcap") else str(fl.pose_images(tmp_path, poses))
    cal = "-" if name.endswith(".mcap") else CAL
    _refused(c3("dataset", "import", images, str(log), cal, STORE, str(tmp_path / "x")), needle)


def test_bag_attitude_from_a_chosen_pose_topic(poses: list[fl.Pose], tmp_path: Path) -> None:
    calibration = load_calibration(DEMO / "calibration.json")
    bag = write_bag(tmp_path / "bag", poses, calibration, pose_topic=True)
    ground = ["--ground-elevation", str(fl.GROUND_M), "--geoid-height", str(GEOID_HEIGHT_M)]
    # an Imu and a PoseStamped: which one is the attitude must be said
    _refused(
        c3("dataset", "import", "-", str(bag), "-", STORE, str(tmp_path / "x"), *ground),
        "several attitude topics (/imu/data, /vehicle/pose)",
    )
    flight = tmp_path / "flight"
    proc = c3(
        "dataset", "import", "-", str(bag), "-", STORE, str(flight), *ground,
        "--attitude-topic", "/vehicle/pose",
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert "attitude /vehicle/pose" in proc.stdout
    for f, p in zip(load_dataset(flight).frames, poses, strict=True):
        assert np.allclose(f.attitude_deg, (p.roll, p.pitch, p.yaw), atol=1e-4)
    _refused(
        c3("dataset", "import", "-", str(bag), "-", STORE, str(tmp_path / "y"), *ground,
           "--attitude-topic", "/gps/fix"),
        "/gps/fix is sensor_msgs/msg/NavSatFix",
    )  # fmt: skip


@pytest.mark.parametrize("module", ["pyulog", "rosbags.highlevel", "pymavlink.mavutil", "exifread"])
def test_a_missing_logs_library_names_the_extra(
    module: str, monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    monkeypatch.setitem(sys.modules, module, None)  # as if not installed: importing it fails
    with pytest.raises(InvalidInputError) as refused:
        logs_library(module, tmp_path / "flight.log", "a recorded log")
    assert str(tmp_path / "flight.log") in str(refused.value)
    assert "pip install 'c3-matcher-tools[logs]'" in str(refused.value)


def test_ulog_reader_without_its_library_is_refused_naming_the_extra(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    monkeypatch.setitem(sys.modules, "pyulog", None)
    with pytest.raises(InvalidInputError, match=r"reading a ULog needs the logs extra"):
        read_ulog(tmp_path / "flight.ulg")


def test_a_damaged_dataflash_log_is_read_past_its_damage_quietly_and_says_so(
    poses: list[fl.Pose], tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    """pymavlink's compiled indexer writes a line per damaged header to the process's stderr
    (thousands on a damaged log): they are counted into the track's damage, never printed."""
    log = write_dataflash(tmp_path / "flight.bin", poses)
    data = bytearray(log.read_bytes())
    data[len(data) // 2 : len(data) // 2 + 10] = bytes(10)  # headers in the middle zeroed
    log.write_bytes(bytes(data))
    track = read_mavlink(log)
    assert capfd.readouterr().err == ""
    assert track.damage is not None and "damaged message headers skipped" in track.damage
    assert track.notes[0].startswith("the log is damaged")


def test_a_dot_log_file_is_read_as_what_it_holds_binary_or_text(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    """``.log`` names both kinds of DataFlash log: a binary one (pymavlink would read it as
    text by its name) and a text one (``FMT, ...`` lines). Both read as the ``.bin`` does."""
    binary = write_dataflash(tmp_path / "flight.bin", poses)
    named_log = tmp_path / "binary.log"
    shutil.copyfile(binary, named_log)
    text = _as_text_dataflash(binary, tmp_path / "text.log")
    want = read_mavlink(binary)
    for path in (named_log, text):
        got = read_mavlink(path)
        assert got.position is not None and want.position is not None
        np.testing.assert_allclose(got.position.values, want.position.values, rtol=1e-6)
        assert got.triggers_s is not None and want.triggers_s is not None
        np.testing.assert_allclose(got.triggers_s, want.triggers_s, atol=1e-3)


def _as_text_dataflash(binary: Path, out: Path) -> Path:
    """The binary DataFlash log ``binary`` written as a text one (``FMT, ...`` lines)."""
    from pymavlink import DFReader

    reader, lines = DFReader.DFReader_binary(str(binary)), []
    while (msg := reader.recv_msg()) is not None:
        values = [getattr(msg, c) for c in msg.fmt.columns]
        shown = [v.decode().rstrip("\0") if isinstance(v, bytes) else str(v) for v in values]
        lines.append(", ".join([msg.get_type(), *shown]))
    out.write_text("\n".join(lines) + "\n")
    return out


@pytest.mark.parametrize("lost", [1, 6], ids=["newline", "mid-line"])
def test_a_text_dataflash_log_cut_in_its_last_line_says_so(
    lost: int, poses: list[fl.Pose], tmp_path: Path
) -> None:
    """pymavlink reads a text DataFlash line once its newline is there: a log cut in its last
    line (its last camera trigger here) lost that line and said nothing; now it says so."""
    whole = _as_text_dataflash(write_dataflash(tmp_path / "flight.bin", poses), tmp_path / "w.log")
    complete = read_mavlink(whole)
    assert complete.damage is None and not any("mid-message" in n for n in complete.notes)
    data = whole.read_bytes()
    log = tmp_path / "cut.log"
    log.write_bytes(data[:-lost])
    start = data.rstrip(b"\n").rfind(b"\n") + 1
    track = read_mavlink(log)
    said = f"ends mid-message, cut short at byte {len(data) - lost} in a CAM line from byte {start}"
    assert track.damage == f"it {said}", track.damage
    assert f"the log {said}; the samples before it are kept" in track.notes
    assert complete.triggers_s is not None and track.triggers_s is not None
    np.testing.assert_array_equal(track.triggers_s, complete.triggers_s[:-1])
    log.write_bytes(data + b"x" * 5000)  # damage after the last line: named as a line
    said = f"ends mid-message, cut short at byte {len(data) + 5000} in a line from byte {len(data)}"
    assert read_mavlink(log).damage == f"it {said}"


def _first_data_message(log: bytes) -> int:
    """The byte where a ULog's definitions section ends: its first message of another type
    than B, F, I, M, P, Q (each message: size u16, type u8, then its bytes)."""
    at = 16
    while log[at + 2 : at + 3] in (b"B", b"F", b"I", b"M", b"P", b"Q"):
        at += 3 + int.from_bytes(log[at : at + 2], "little")
    return at


@pytest.mark.parametrize("which", ["shipped", "written"])
def test_a_ulog_whose_definitions_are_zeroed_is_refused_as_such(
    which: str, poses: list[fl.Pose], tmp_path: Path
) -> None:
    """Zeroed definitions (the formats of the topics): the shipped log was refused with every
    warning pyulog printed (some 5,000 characters), a short one with pyulog's ``[Errno 22]
    Invalid argument``; both now say the definitions are damaged, naming the file."""
    source = REAL_ULOG if which == "shipped" else write_ulog(tmp_path / "flight.ulg", poses)
    data = bytearray(source.read_bytes())
    end = _first_data_message(bytes(data))
    assert data[end + 2] == ord("A")
    data[16:end] = bytes(end - 16)
    log = tmp_path / "zeroed.ulg"
    log.write_bytes(bytes(data))
    images, out = fl.pose_images(tmp_path, poses), tmp_path / "x"
    proc = c3("dataset", "import", str(images), str(log), CAL, STORE, str(out))
    _refused(
        proc,
        f"{log}: not a readable PX4 ULog: its message definitions (the formats of its topics) "
        "are damaged from byte 16 on, so none of its topics can be read",
    )
    assert len(proc.stderr) < 300 and not out.exists()


def test_a_ulog_cut_mid_message_says_so_and_keeps_the_samples_before(tmp_path: Path) -> None:
    """pyulog reads a log cut mid-message up to the cut and says nothing (its
    ``file_corruption`` stays false): the track's notes and damage now say where it ends."""
    whole = read_ulog(REAL_ULOG)
    assert not any("mid-message" in n for n in whole.notes) and whole.damage is None
    data = REAL_ULOG.read_bytes()
    cut = tmp_path / "cut.ulg"
    cut.write_bytes(data[:700001])
    track = read_ulog(cut)
    said = "ends mid-message, cut short at byte 700001 in a message from byte "
    assert any(n.startswith(f"the log {said}") for n in track.notes), track.notes
    assert any(n.endswith("; the samples before it are kept") for n in track.notes)
    assert track.damage is not None and track.damage.startswith(f"it {said}")
    assert whole.gnss is not None and track.gnss is not None
    kept = len(track.gnss)
    assert 0 < kept < len(whole.gnss)
    np.testing.assert_array_equal(track.gnss.t_s, whole.gnss.t_s[:kept])
    np.testing.assert_array_equal(track.gnss.values, whole.gnss.values[:kept])


def test_a_dataflash_log_cut_mid_message_says_so_in_the_record(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    """Cut in its last camera trigger: the refusal of 3 triggers for 4 images called the log
    whole; it now says the log ends mid-message, and so does the record of an import made."""
    whole = write_dataflash(tmp_path / "flight.bin", poses)
    log = tmp_path / "cut.bin"
    log.write_bytes(whole.read_bytes()[:-1])
    images = fl.pose_images(tmp_path, poses)
    args = ["dataset", "import", str(images), str(log), CAL, STORE]
    said = f"ends mid-message, cut short at byte {log.stat().st_size} in a CAM message from byte "
    _refused(c3(*args, str(tmp_path / "x")), "3 camera trigger(s) in the log", f"it {said}")
    flight = tmp_path / "f"
    proc = c3(*args, str(flight), "--time-source", "trigger", "--json")
    assert proc.returncode == 0, proc.stderr
    record = json.loads((flight / "dataset.json").read_text())["import"]
    assert record["frames"] == 3
    assert any(n.startswith(f"the log {said}") for n in record["notes"]), record["notes"]
    assert not any("mid-message" in n for n in read_mavlink(whole).notes)


def test_a_telemetry_log_cut_mid_packet_says_so_and_keeps_the_packets_before(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    """pymavlink reads a ``.tlog`` cut mid-packet up to the cut and says nothing: the track's
    notes and damage now say where it ends, as for a DataFlash log or a ULog."""
    whole = write_tlog(tmp_path / "flight.tlog", poses)
    data = whole.read_bytes()
    complete = read_mavlink(whole)
    assert complete.damage is None and not any("mid-message" in n for n in complete.notes)
    log = tmp_path / "cut.tlog"
    log.write_bytes(data[:-5])
    track = read_mavlink(log)
    said = f"ends mid-message, cut short at byte {len(data) - 5} in a MAVLink packet from byte "
    assert any(n.startswith(f"the log {said}") for n in track.notes), track.notes
    assert track.damage is not None and track.damage.startswith(f"it {said}")
    assert complete.position is not None and track.position is not None
    assert 0 < len(track.position) <= len(complete.position)


@pytest.mark.parametrize("source", [("--source", "rosbag"), ()], ids=["rosbag", "told-by-files"])
def test_a_bag_folder_without_metadata_names_what_it_lacks(
    poses: list[fl.Pose], tmp_path: Path, source: tuple[str, ...]
) -> None:
    """rosbags said "Expected metadata file '<the folder>' does not exist", naming the folder
    as the missing file; without --source, "cannot tell the log's kind from its name"."""
    calibration = load_calibration(DEMO / "calibration.json")
    bag = write_bag(tmp_path / "bag", poses[:1], calibration)
    (bag / "metadata.yaml").unlink()
    out = tmp_path / "x"
    proc = c3("dataset", "import", "-", str(bag), "-", STORE, str(out), *source)
    _refused(
        proc,
        f"{bag}: a folder without metadata.yaml, which a ROS 2 bag's folder holds (beside its "
        ".db3 or .mcap files)",
    )
    assert not out.exists()


def test_a_log_imports_store_is_a_hard_link_to_the_users_store(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    store = tmp_path / "maps" / "area.mbtiles"
    store.parent.mkdir()
    shutil.copyfile(STORE, store)
    log = write_ulog(tmp_path / "flight.ulg", poses)
    flight = tmp_path / "flight"
    proc = c3(
        "dataset",
        "import",
        str(fl.pose_images(tmp_path, poses)),
        str(log),
        CAL,
        str(store),
        str(flight),
    )
    assert proc.returncode == 0, proc.stderr
    assert (flight / "tiles.mbtiles").stat().st_ino == store.stat().st_ino
    assert f"tiles.mbtiles: a hard link to {store}" in proc.stdout
