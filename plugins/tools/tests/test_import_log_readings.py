"""What the log importers take from a log and what they leave: a ULog topic whose definition lost
a field is refused naming both; a ROS ``sensor_msgs/Imu`` that states no orientation is not an
attitude, and a CameraInfo of a distortion model other than OpenCV's is refused when its
intrinsics are wanted; a rangefinder that does not face down (or reads out of its range, or not
good) is no height above ground; a DataFlash log's second GNSS receiver or rangefinder is not
mixed with the first; a telemetry log holding several vehicles is read for the camera vehicle's
messages; an older RFND layout is read and a layout not known ignored and said; each frame's
height is above the home in force at its time; a ROS 1 bag's CameraInfo is read in its own
spelling and images stamped alike are frames of their own; a series sampled exactly on a
sample gives that sample. Logs are written with the
libraries' own writers (:mod:`c3_matcher_tools.testing.flightlogs`, a DataFlash log in the
documented FMT layout here) over frames of the shipped demo flight, and read back by them."""

from __future__ import annotations

import dataclasses
import json
import math
import shutil
import struct
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from c3_matcher.errors import InvalidInputError
from c3_matcher.serialize import load_calibration
from c3_matcher_tools.dataset.format import load_dataset
from c3_matcher_tools.dataset.sources.mavlink import read_mavlink
from c3_matcher_tools.dataset.sources.rosbag import read_bag
from c3_matcher_tools.dataset.sources.track import Series
from c3_matcher_tools.dataset.sources.ulog import read_ulog
from c3_matcher_tools.testing import flightlogs as fl
from c3_matcher_tools.testing.cli import run_cli
from c3_matcher_tools.testing.flightlogs import rosbag as rb
from c3_matcher_tools.testing.flightlogs.dataflash import write_dataflash
from c3_matcher_tools.testing.flightlogs.mavlink import _tlog_frames, _tlog_positions, write_tlog
from c3_matcher_tools.testing.flightlogs.ulog import write_ulog

REPO = Path(__file__).resolve().parents[3]
DEMO = REPO / "data" / "flights" / "naip_demo"
STORE = str(DEMO / "tiles.mbtiles")
ASSUMED_LEVEL = "every frame's attitude assumed level, its yaw from the GNSS course"


@pytest.fixture(scope="module")
def poses() -> list[fl.Pose]:
    return fl.flight_poses(DEMO, range(4))


# --- ULog: a damaged field definition -------------------------------------------------------


@pytest.mark.parametrize(
    ("good", "bad", "field"),
    [
        (
            b"vehicle_attitude:uint64_t timestamp;",
            b"vehicle_attitude:uint64_t timestamq;",
            "timestamp",
        ),
        (b"float[4] q;", b"float[4] r;", "q[0]"),
    ],
    ids=["timestamp", "q"],
)
def test_a_ulog_topic_whose_definition_lost_a_field_is_refused_naming_both(
    poses: list[fl.Pose], tmp_path: Path, good: bytes, bad: bytes, field: str
) -> None:
    """One byte damaged in ``vehicle_attitude``'s format definition: an uncaught KeyError
    (an internal error on the command line) before."""
    log = write_ulog(tmp_path / "flight.ulg", poses)
    data = log.read_bytes()
    assert data.count(good) == 1
    log.write_bytes(data.replace(good, bad))
    with pytest.raises(InvalidInputError) as refused:
        read_ulog(log)
    assert f"vehicle_attitude lacks its field {field!r}" in str(refused.value)


def test_ulog_attitude_samples_that_state_no_orientation_are_skipped(
    poses: list[fl.Pose], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """PX4 logs ``q`` = 0 before its estimator runs: such a sample is skipped (a division by
    zero stopped the import before), and a topic of nothing else states no attitude."""
    from c3_matcher_tools.testing.flightlogs import ulog as writer

    made = writer._ulog_attitude

    def zeroed(first: int) -> Any:
        def attitude(p: Sequence[fl.Pose], us: list[int]) -> Any:
            name, fields, data = made(p, us)
            for k in range(4):
                data[f"q[{k}]"][:first] = [0.0] * first
            return name, fields, data

        return attitude

    monkeypatch.setattr(writer, "_ulog_attitude", zeroed(1))
    track = read_ulog(write_ulog(tmp_path / "first.ulg", poses))
    assert track.attitude is not None and len(track.attitude) == len(poses) - 1
    monkeypatch.setattr(writer, "_ulog_attitude", zeroed(len(poses)))
    assert read_ulog(write_ulog(tmp_path / "all.ulg", poses)).attitude is None


# --- ROS bags: an Imu without orientation, a CameraInfo's distortion model ------------------


def _bag(
    path: Path,
    poses: Sequence[fl.Pose],
    *,
    no_orientation: Sequence[int] = (),
    quaternion: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0),
    flagged: bool = True,
    model: str = "plumb_bob",
    d: Sequence[float] | None = None,
) -> Path:
    """A bag as :func:`write_bag` writes it, but its Imu samples of frames ``no_orientation``
    state none (``quaternion`` (w, x, y, z) with ``orientation_covariance[0]`` = -1 when
    ``flagged``) and its CameraInfo has distortion ``model`` (coefficients ``d``)."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    types = store.types
    cal = load_calibration(DEMO / "calibration.json")
    with Writer(path, version=8, storage_plugin=StoragePlugin.SQLITE3) as writer:
        conns = rb._bag_connections(writer, store, True, (), False)
        msgs = rb._bag_frame_messages(types, poses, cal.image_size, True, (), False)
        for i, (_, _, imu) in enumerate(m for m in msgs if m[1] == "imu"):
            if i in no_orientation:
                w, x, y, z = quaternion
                imu.orientation = types["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w)
                imu.orientation_covariance[0] = -1.0 if flagged else 0.0
        info = rb._camera_info(types, cal, poses[0].t_s - 0.5)
        info.distortion_model = model
        info.d = np.asarray(cal.distortion if d is None else d, dtype=np.float64)
        msgs += [(poses[0].t_s - 0.5, "info", info), *rb._gps_fixes(types, poses)]
        for t, key, msg in sorted(msgs, key=lambda x: (x[0], x[1])):
            writer.write(conns[key], rb._utc_ns(t), store.serialize_cdr(msg, msg.__msgtype__))
    return path


@pytest.mark.parametrize(
    ("quaternion", "flagged"),
    [((1.0, 0.0, 0.0, 0.0), True), ((0.0, 0.0, 0.0, 0.0), True), ((0.0, 0.0, 0.0, 0.0), False)],
    ids=["ros2-default-flagged", "ros1-default-flagged", "zero-quaternion"],
)
def test_an_imu_that_states_no_orientation_gives_no_attitude(
    poses: list[fl.Pose],
    tmp_path: Path,
    quaternion: tuple[float, float, float, float],
    flagged: bool,
) -> None:
    """sensor_msgs/Imu marks a missing orientation with ``orientation_covariance[0]`` = -1:
    its identity quaternion was taken as the attitude (roll 0, pitch 0, yaw 90) and its zero
    one refused the bag with "float division by zero". Now the bag has no attitude: each frame
    is imported level and marked, as from a bag without an attitude topic."""
    bag = _bag(
        tmp_path / "bag", poses, no_orientation=range(4), quaternion=quaternion, flagged=flagged
    )
    track, shots, _ = read_bag(bag)
    assert track.attitude is None and len(shots) == 4
    said = [n for n in track.notes if "state no orientation" in n]
    assert len(said) == 1 and said[0].startswith("4 /imu/data sample(s)")
    assert ASSUMED_LEVEL in said[0]


def test_imu_samples_without_orientation_are_skipped_among_those_with_one(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    bag = _bag(tmp_path / "bag", poses, no_orientation=(1,))
    track, _, _ = read_bag(bag)
    assert track.attitude is not None and len(track.attitude) == 3
    kept = [p for i, p in enumerate(poses) if i != 1]
    assert np.allclose(track.attitude.values, [(p.roll, p.pitch, p.yaw) for p in kept], atol=1e-4)
    assert any(n.startswith("1 /imu/data sample(s) state no orientation") for n in track.notes)
    assert not any(ASSUMED_LEVEL in n for n in track.notes)


@pytest.mark.parametrize(
    ("model", "d"),
    [
        ("rational_polynomial", [0.01, -0.02, 0.0, 0.0, 0.003, 0.0, 0.0, 0.0]),
        ("", [0.0] * 5),
        ("", []),
    ],
    ids=["rational_polynomial", "none-zeros", "none-empty"],
)
def test_camera_info_of_opencv_models_or_no_distortion_is_read(
    poses: list[fl.Pose], tmp_path: Path, model: str, d: list[float]
) -> None:
    _, _, recorded = read_bag(_bag(tmp_path / "bag", poses[:2], model=model, d=d))
    assert recorded is not None and recorded.distortion.tolist() == d


@pytest.mark.parametrize(
    ("model", "d"),
    [("equidistant", [0.1, -0.05, 0.01, -0.002]), ("", [0.1, 0.0, 0.0, 0.0, 0.0])],
    ids=["equidistant", "unnamed-with-distortion"],
)
def test_camera_info_of_another_distortion_model_is_refused_when_its_intrinsics_are_wanted(
    poses: list[fl.Pose], tmp_path: Path, model: str, d: list[float]
) -> None:
    """A fisheye ``equidistant`` CameraInfo was read as OpenCV's k1, k2, p1, p2 (a corner
    pixel undistorted some 27 px off). Refused naming the model when CALIBRATION is '-';
    with the camera's calibration file given, the bag's CameraInfo is not used, nor refused."""
    bag = _bag(tmp_path / "bag", poses[:2], model=model, d=d)
    with pytest.raises(InvalidInputError) as refused:
        read_bag(bag)
    assert f"CameraInfo distortion model {model!r} is not supported" in str(refused.value)
    track, shots, recorded = read_bag(bag, intrinsics=False)
    assert recorded is None and len(shots) == 2 and track.attitude is not None
    proc = run_cli("dataset", "import", "-", str(bag), "-", STORE, str(tmp_path / "out"), cwd=REPO)
    lines = [x for x in proc.stderr.splitlines() if x.strip()]
    assert proc.returncode == 2 and len(lines) == 1, proc.stderr
    assert f"distortion model {model!r}" in lines[0]
    # a fisheye model is not mended by a calibration JSON of the same 4 numbers: what to do
    fisheye = model == "equidistant"
    assert ("calibration JSON" in lines[0]) != fisheye, lines[0]
    assert ("a fisheye lens model" in lines[0]) == fisheye, lines[0]
    assert ("undistort the frames first" in lines[0]) == fisheye, lines[0]


@pytest.mark.parametrize(
    ("given", "kept"), [(6, 8), (7, 8), (9, 12), (11, 12), (13, 14), (14, 14), (3, 4)]
)
def test_camera_info_distortion_is_padded_to_a_count_opencv_takes(
    poses: list[fl.Pose], tmp_path: Path, given: int, kept: int
) -> None:
    """A rational_polynomial D of 6 or 7 numbers kept only the first 5 (k4, k5 dropped): now
    it is padded with zeros to the next count OpenCV takes, no coefficient lost."""
    d = [0.01 * (i + 1) * (-1) ** i for i in range(given)]
    _, _, recorded = read_bag(_bag(tmp_path / "bag", poses[:2], model="rational_polynomial", d=d))
    assert recorded is not None
    assert recorded.distortion.tolist() == [*d, *[0.0] * (kept - given)]


def test_camera_info_of_more_distortion_numbers_than_opencv_takes_is_refused(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    bag = _bag(tmp_path / "bag", poses[:2], model="rational_polynomial", d=[0.001] * 15)
    with pytest.raises(InvalidInputError) as refused:
        read_bag(bag)
    assert "its CameraInfo gives 15 distortion coefficients: OpenCV's model takes at most 14" in (
        str(refused.value)
    )


# --- MAVLink / DataFlash: rangefinders, receiver instances, several vehicles ----------------


def _distance(orientation: int, cm: int, max_cm: int = 40_000) -> Any:
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    return mavlink.MAVLink_distance_sensor_message(0, 20, max_cm, cm, 0, 0, orientation, 0)


def test_only_downward_distance_sensor_readings_within_range_are_heights(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    """Every DISTANCE_SENSOR was taken as the height above ground: a forward sensor's 12 m to
    an obstacle became each frame's height (true 780 m). Kept: facing down (PITCH_270), within
    [min_distance, max_distance)."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    log = write_tlog(tmp_path / "flight.tlog", poses)
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    down = mavlink.MAV_SENSOR_ROTATION_PITCH_270
    readings = [_distance(0, 1200), _distance(down, 40_000), _distance(down, 30_000)]
    extra = b"".join(
        struct.pack(">Q", int((fl.UTC0 + p.t_s) * 1e6)) + m.pack(mav)
        for p in poses
        for m in readings
    )
    log.write_bytes(log.read_bytes() + extra)
    track = read_mavlink(log)
    assert track.height is not None and track.height.name == "DISTANCE_SENSOR"
    assert track.height.values[:, 0].tolist() == [300.0] * len(poses)


_FORMATS = {  # name: (struct chars, columns, FMTU units: '#' marks the instance column)
    "ATT": ("Qfff", "TimeUS,Roll,Pitch,Yaw", "sddd"),
    "POS": ("QLLff", "TimeUS,Lat,Lng,Alt,RelHomeAlt", "sDUmm"),
    "GPS": ("QBBIHLLf", "TimeUS,I,Status,GMS,GWk,Lat,Lng,Alt", "s#---DUm"),
    "GPA": ("QBf", "TimeUS,I,HAcc", "s#m"),
    "CAM": ("QH", "TimeUS,Img", "s-"),
    "RFND": ("QBfBB", "TimeUS,Instance,Dist,Stat,Orient", "s#m--"),
    "FMTU": ("QBNN", "TimeUS,FmtType,UnitIds,MultIds", "s---"),
}


def _layout(chars: str) -> str:
    """The struct layout of DataFlash format characters (L: 1e-7 deg int32, N: char[16])."""
    return "<" + "".join({"L": "i", "N": "16s"}.get(c, c) for c in chars)


def _pack(chars: str, *values: Any) -> bytes:
    return struct.pack(_layout(chars), *values)


def _dataflash(path: Path, formats: dict[str, tuple[str, str, str]], rows: list[tuple]) -> Path:
    """A DataFlash log of ``formats`` (each with its FMTU) and ``rows`` (name, TimeUS, the
    other values), in time order after the formats, as ArduPilot lays one out."""
    ids = {name: i + 1 for i, name in enumerate(formats)}
    out = [
        b"\xa3\x95\x80"
        + _pack("BB4s16s64s", 128, 89, b"FMT", b"BBnNZ", b"Type,Length,Name,Format,Columns")
    ]
    for name, (chars, columns, _) in formats.items():
        size = 3 + struct.calcsize(_layout(chars))
        fmt = _pack("BB4s16s64s", ids[name], size, name.encode(), chars.encode(), columns.encode())
        out.append(b"\xa3\x95\x80" + fmt)
    for name, (_, _, units) in formats.items():
        unit = _pack("QBNN", 0, ids[name], units.encode(), b"-" * len(units))
        out.append(b"\xa3\x95" + bytes([ids["FMTU"]]) + unit)
    for name, *values in sorted(rows, key=lambda r: r[1]):
        out.append(b"\xa3\x95" + bytes([ids[name]]) + _pack(formats[name][0], *values))
    path.write_bytes(b"".join(out))
    return path


def _flight_rows(poses: Sequence[fl.Pose]) -> list[tuple]:
    """POS, GPS and GPA of receiver 0 (3D fix, 1.5 m) along the poses, each frame's ATT, CAM
    and a downward rangefinder 0's good reading of 300 m."""
    rows: list[tuple] = []
    for t, lat, lon, alt in fl.dense_track(poses):
        tus = int((fl.BOOT_S + t) * 1e6)
        gps_s = fl.UTC0 + t - 315_964_800.0 + 18.0
        week, ms = int(gps_s // 604800), round((gps_s % 604800) * 1e3)
        lat_e7, lon_e7 = round(lat * 1e7), round(lon * 1e7)
        rows += [("POS", tus, lat_e7, lon_e7, alt, alt - fl.GROUND_M), ("GPA", tus, 0, 1.5)]
        rows.append(("GPS", tus, 0, 3, ms, week, lat_e7, lon_e7, alt))
    for i, p in enumerate(poses):
        tus = int((fl.BOOT_S + p.t_s) * 1e6)
        rows += [("ATT", tus, p.roll, p.pitch, p.yaw % 360.0), ("CAM", tus, i)]
        rows.append(("RFND", tus, 0, 300.0, 4, 25))
    return rows


def test_a_dataflash_log_reads_its_first_receiver_alone(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    """A second receiver (I = 1) without a fix was mixed into the first's series: every frame
    flagged gnss_degraded, though receiver 0 had a 3D fix at each."""
    rows = _flight_rows(poses)
    for _, tus, *_ in [r for r in rows if r[0] == "GPS"]:
        rows += [("GPS", tus + 50_000, 1, 1, 0, 0, 0, 0, 0.0), ("GPA", tus + 50_000, 1, 99.0)]
    track = read_mavlink(_dataflash(tmp_path / "flight.bin", _FORMATS, rows))
    assert track.gnss is not None and set(track.gnss.values[:, 4].tolist()) == {3.0}
    assert set(track.gnss.values[:, 3].tolist()) == {1.5}
    assert len(track.gnss) == len(fl.dense_track(poses))


def test_rfnd_heights_are_the_first_downward_rangefinder_s_good_readings(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    """Every RFND was taken as the height above ground. Left now: another rangefinder's
    (Instance 1, facing forward, 12 m to an obstacle), a later downward one's (Instance 2) and
    rangefinder 0's readings that are not good (Stat 1, no data)."""
    rows = _flight_rows(poses)
    for _, tus, *_ in [r for r in rows if r[0] == "RFND"]:
        rows += [("RFND", tus + 20_000, 1, 12.0, 4, 0), ("RFND", tus + 40_000, 0, 0.0, 1, 25)]
        rows.append(("RFND", tus + 60_000, 2, 280.0, 4, 25))
    track = read_mavlink(_dataflash(tmp_path / "flight.bin", _FORMATS, rows))
    assert track.height is not None and track.height.values[:, 0].tolist() == [300.0] * 4


def test_the_first_downward_rangefinder_need_not_be_rangefinder_0(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    """ArduPilot takes its height from the first rangefinder facing down: with a forward one
    as rangefinder 0, rangefinder 1's readings were all set aside (no height at all)."""
    rows = [r if r[0] != "RFND" else ("RFND", r[1], 1, *r[3:]) for r in _flight_rows(poses)]
    rows += [("RFND", r[1] + 20_000, 0, 12.0, 4, 0) for r in rows if r[0] == "RFND"]
    track = read_mavlink(_dataflash(tmp_path / "flight.bin", _FORMATS, rows))
    assert track.height is not None and track.height.values[:, 0].tolist() == [300.0] * 4


def test_a_photo_logged_as_both_cam_and_trig_is_one_trigger(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    """With a feedback pin ArduPilot logs TRIG at the trigger and CAM at the shutter: each
    photo was counted twice (8 triggers for 4 images). CAM is read, TRIG set aside."""
    formats = {**_FORMATS, "TRIG": ("QH", "TimeUS,Img", "s-")}
    rows = _flight_rows(poses)
    rows += [("TRIG", r[1] - 30_000, r[2]) for r in rows if r[0] == "CAM"]
    track = read_mavlink(_dataflash(tmp_path / "flight.bin", formats, rows))
    cams = [fl.BOOT_S + p.t_s for p in poses]
    assert track.triggers_s is not None and len(track.triggers_s) == len(poses)
    assert np.allclose(np.diff(track.triggers_s), np.diff(cams))
    assert "4 camera trigger(s) from CAM; TRIG of the same photos set aside" in track.notes
    only_trig = [r if r[0] != "CAM" else ("TRIG", *r[1:]) for r in _flight_rows(poses)]
    track = read_mavlink(_dataflash(tmp_path / "trig.bin", formats, only_trig))
    assert "4 camera trigger(s) from TRIG" in track.notes


def test_a_global_position_at_zero_zero_before_the_origin_is_no_position(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    """ArduPilot sends GLOBAL_POSITION_INT at latitude and longitude 0 until its estimator has
    an origin: it was a position sample, 6,000 km from the flight."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    no_origin = mavlink.MAVLink_global_position_int_message(0, 0, 0, 0, 0, 0, 0, 0, 0)
    records = [(-1.0, no_origin), *_tlog_positions(poses), *_tlog_frames(poses, ())]
    link = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    log = tmp_path / "flight.tlog"
    with log.open("wb") as fh:
        for t, msg in sorted(records, key=lambda r: r[0]):
            fh.write(struct.pack(">Q", int((fl.UTC0 + t) * 1e6)) + msg.pack(link))
    track = read_mavlink(log)
    assert track.position is not None and len(track.position) == len(fl.dense_track(poses))
    assert np.all(np.abs(track.position.values[:, 0]) > 1.0)


def test_an_rfnd_format_without_instance_status_or_orientation_is_read_as_a_height(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    formats = {**_FORMATS, "RFND": ("Qf", "TimeUS,Dist", "sm")}
    rows = [r if r[0] != "RFND" else ("RFND", r[1], r[3]) for r in _flight_rows(poses)]
    track = read_mavlink(_dataflash(tmp_path / "flight.bin", formats, rows))
    assert track.height is not None and track.height.values[:, 0].tolist() == [300.0] * 4


@pytest.mark.parametrize(
    ("chars", "columns", "readings", "height"),
    [
        ("QfBfB", "TimeUS,Dist1,Orient1,Dist2,Orient2", (12.0, 0, 300.0, 25), 300.0),
        ("QfBfB", "TimeUS,Dist1,Orient1,Dist2,Orient2", (300.0, 25, 280.0, 25), 300.0),
        ("QfBfB", "TimeUS,Dist1,Orient1,Dist2,Orient2", (300.0, 25, 0.0, 0), 300.0),
        ("Qff", "TimeUS,Dist1,Dist2", (300.0, 0.0), 300.0),
    ],
    ids=["3.6-forward-then-down", "3.6-both-down", "3.6-one", "3.4"],
)
def test_an_rfnd_of_two_rangefinders_a_message_is_read_per_rangefinder(
    poses: list[fl.Pose],
    tmp_path: Path,
    chars: str,
    columns: str,
    readings: tuple[float, ...],
    height: float,
) -> None:
    """Copter and Plane 3.5-3.6 log RFND as TimeUS,Dist1,Orient1,Dist2,Orient2 (3.4 and before
    without the orientations): such a log was refused whole, its reason the one word "Dist".
    Each reading is rangefinder 0 or 1's; the first facing down gives the height, a zero
    distance (no reading: these formats have no status) is none."""
    formats = {**_FORMATS, "RFND": (chars, columns, "s" + "-" * (len(chars) - 1))}
    rows = [r if r[0] != "RFND" else ("RFND", r[1], *readings) for r in _flight_rows(poses)]
    track = read_mavlink(_dataflash(tmp_path / "flight.bin", formats, rows))
    assert track.height is not None and track.height.values[:, 0].tolist() == [height] * 4
    assert not any("ignored" in n for n in track.notes)


def test_an_optional_message_in_a_layout_not_read_is_ignored_and_said(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    """A rangefinder or accuracy message whose format lacks a column read (another ArduPilot
    version's) refused the whole log, naming only the column. The log is read without them and
    its notes name each type and column; the frames' heights then come from the home."""
    formats = {
        **_FORMATS,
        "RFND": ("Qf", "TimeUS,Range", "sm"),
        "GPA": ("QBf", "TimeUS,I,VAcc", "s#m"),
    }
    rows = [r if r[0] != "RFND" else ("RFND", r[1], r[3]) for r in _flight_rows(poses)]
    track = read_mavlink(_dataflash(tmp_path / "flight.bin", formats, rows))
    assert track.height is None and track.position is not None and track.gnss is not None
    assert np.isnan(track.gnss.values[:, 3]).all()  # no stated accuracy
    said = "messages in a format this importer does not read, ignored: GPA (no column HAcc), "
    assert said + "RFND (no column Dist)" in track.notes
    without_position = {**formats, "POS": ("QLL", "TimeUS,Lat,Lon", "sDU")}
    rows = [r for r in rows if r[0] not in ("GPS", "POS")]
    rows += [("POS", r[1], r[2], r[3]) for r in _flight_rows(poses) if r[0] == "POS"]
    with pytest.raises(InvalidInputError) as refused:
        read_mavlink(_dataflash(tmp_path / "no_position.bin", without_position, rows))
    assert "the log holds no position" in str(refused.value)
    assert "POS (no column Lng)" in str(refused.value)


def _east(poses: Sequence[fl.Pose]) -> list[fl.Pose]:
    return [dataclasses.replace(p, lon=p.lon + 0.025) for p in poses]


def _two_systems(
    path: Path, poses: Sequence[fl.Pose], feedback: tuple[bool, bool], ahead_s: float
) -> Path:
    """A telemetry log of system 1 (as :func:`write_tlog` writes it: positions, attitude,
    camera feedback) and system 2, an aircraft 0.025 deg (2 km) east on the same link, its
    records ``ahead_s`` earlier; ``feedback``: whether each sends its camera feedback."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    flaws = [() if f else ("no_trigger",) for f in feedback]
    own = _tlog_positions(poses) + _tlog_frames(poses, flaws[0])
    theirs = _tlog_positions(_east(poses)) + _tlog_frames(_east(poses), flaws[1])
    records = [(t, 0, 1, m) for t, m in own] + [(t - ahead_s, 1, 2, m) for t, m in theirs]
    links = {n: mavlink.MAVLink(None, srcSystem=n, srcComponent=1) for n in (1, 2)}
    with path.open("wb") as fh:
        for t, _, n, msg in sorted(records, key=lambda r: r[:2]):
            fh.write(struct.pack(">Q", int((fl.UTC0 + t) * 1e6)) + msg.pack(links[n]))
    return path


@pytest.mark.parametrize(
    ("own_feedback", "ahead_s", "read"),
    [(True, 0.0, 1), (True, 0.1, 1), (False, 0.1, 2)],
    ids=["camera-feedback", "camera-feedback-after-the-other", "given"],
)
def test_a_telemetry_log_of_two_vehicles_is_read_for_the_camera_vehicle(
    poses: list[fl.Pose], tmp_path: Path, own_feedback: bool, ahead_s: float, read: int
) -> None:
    """A ground station's log of two aircraft 2 km apart was read as one track, each frame
    placed between them. Read: the system of the camera feedback, else the one given
    (``--mavlink-system``; see ``test_import_mavlink_links.py`` for a log where none is)."""
    log = _two_systems(tmp_path / "flight.tlog", poses, (own_feedback, False), ahead_s)
    track = read_mavlink(log) if own_feedback else read_mavlink(log, read)
    truth, shift = (poses, 0.0) if read == 1 else (_east(poses), ahead_s)
    assert track.position is not None and track.attitude is not None
    assert len(track.position) == len(fl.dense_track(poses))
    at = [track.position.at(fl.UTC0 + p.t_s - shift, 0.01) for p in truth]
    got = [a[:2] for a in at if a is not None]
    assert len(got) == len(truth)
    assert np.allclose(got, [(p.lat, p.lon) for p in truth], atol=1e-6)
    why = "its camera feedback" if own_feedback else "given by --mavlink-system"
    assert track.notes[0] == f"MAVLink systems 1, 2 in the log: read system {read} ({why})"


def test_camera_feedback_from_two_vehicles_is_refused_naming_them(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    log = _two_systems(tmp_path / "flight.tlog", poses, (True, True), 0.0)
    with pytest.raises(InvalidInputError) as refused:
        read_mavlink(log)
    assert "camera feedback from MAVLink systems 1, 2" in str(refused.value)


# --- the home altitude, set again at arming -------------------------------------------------


@pytest.mark.parametrize("kind", ["ulg", "tlog", "bin"])
def test_each_frame_s_height_is_above_the_home_in_force_at_its_time(
    poses: list[fl.Pose], tmp_path: Path, kind: str
) -> None:
    """PX4 and ArduPilot set the home again at arming; the first home in the log (before
    arming, 12 m high here) was taken for every frame: heights 768 m for 780 m, the report
    saying only "altitude - home altitude". Each frame now takes the home in force at its time
    (a MAVLink log's at each position sample) and the report states it, with when it was set."""
    writer = {"ulg": write_ulog, "tlog": write_tlog, "bin": write_dataflash}[kind]
    log = writer(tmp_path / f"flight.{kind}", poses, flaws=("home_reset",))
    images = tmp_path / "images"
    images.mkdir()
    for i, p in enumerate(poses):
        shutil.copyfile(p.image, images / f"IMG_{i:04d}.jpg")
    flight = tmp_path / "flight"
    cal = str(DEMO / "calibration.json")
    proc = run_cli("dataset", "import", images, log, cal, STORE, flight, "--json", cwd=REPO)
    assert proc.returncode == 0, proc.stderr
    frames = load_dataset(flight).frames
    assert [f.height_m for f in frames] == pytest.approx([p.height_m for p in poses], abs=0.01)
    summary = json.loads(proc.stdout)
    assert summary["height_sources"] == {"altitude - home altitude 500.0 m": 4}
    said = [n for n in summary["notes"] if n.startswith("home altitude (")]
    assert len(said) == 1 and " set 2 times: 512.0 m from " in said[0], summary["notes"]
    assert ", 500.0 m from " in said[0]


def test_a_home_holds_from_when_it_was_set() -> None:
    from c3_matcher_tools.dataset.sources.track import home_series

    home, note = home_series("home", [10.0, 50.0, 50.2], [512.0, 500.0, 500.001], source="log")
    assert home is not None and note is not None
    held = [home.held(t)[0] for t in (0.0, 10.0, 49.9, 50.0, 51.0, 1e6)]  # type: ignore[index]
    assert held == [512.0, 512.0, 512.0, 500.0, 500.001, 500.001]
    assert note.startswith("home altitude (home) set 2 times: 512.0 m from 10.0 s, 500.0 m from")
    assert home_series("home", [1.0, 2.0], [500.0, 500.001], source="log")[1] is None
    assert home_series("home", [1.0], [math.nan], source="log") == (None, None)


# --- ROS bags: ROS 1 spelling, images stamped alike -----------------------------------------


def test_a_ros1_bag_s_camera_info_is_read_in_its_own_spelling(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    """ROS 1's CameraInfo spells its matrices D, K (ROS 2: d, k): CALIBRATION '-' with a
    ROS 1 bag ended in an internal error ("no attribute 'd'", exit 1)."""
    cal = load_calibration(DEMO / "calibration.json")
    bag = rb.write_bag(tmp_path / "flight.bag", poses, cal, storage="ros1")
    track, shots, recorded = read_bag(bag)
    assert recorded is not None and len(shots) == 4 and track.attitude is not None
    assert np.allclose(recorded.K, cal.K) and recorded.image_size == cal.image_size
    assert np.allclose(recorded.distortion, cal.distortion)
    flight = tmp_path / "flight"
    ground = ("--ground-elevation", str(fl.GROUND_M), "--geoid-height", str(rb.GEOID_HEIGHT_M))
    proc = run_cli("dataset", "import", "-", bag, "-", STORE, flight, *ground, "--json", cwd=REPO)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["frames"] == 4


def test_images_stamped_alike_are_frames_of_their_own_and_a_recorded_copy_is_set_aside(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    """Two images of one header stamp were named alike ("topic@stamp"), so their frames had
    one frame id: the import wrote a dataset that ``dataset info`` and ``replay`` refuse.
    Each is now named by its index in the topic too; an image recorded twice (the same bytes)
    is imported once, naming both."""
    cal = load_calibration(DEMO / "calibration.json")
    alike = dataclasses.replace(poses[1], t_s=poses[0].t_s)  # another image, frame 0's stamp
    bag = rb.write_bag(tmp_path / "bag", [poses[0], alike, poses[2], poses[2], poses[3]], cal)
    flight = tmp_path / "flight"
    ground = ("--ground-elevation", str(fl.GROUND_M), "--geoid-height", str(rb.GEOID_HEIGHT_M))
    proc = run_cli("dataset", "import", "-", bag, "-", STORE, flight, *ground, "--json", cwd=REPO)
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    topic = "/camera/image_raw/compressed"
    stamp = [f"{fl.UTC0 + p.t_s:.6f}" for p in poses]
    assert summary["frames"] == 4
    copy, first = f"{topic}@{stamp[2]}#3", f"{topic}@{stamp[2]}#2"
    reason = f"a copy of {first} (the same bytes): imported once, as {first}"
    assert summary["skipped"] == [{"image": copy, "reason": reason}]
    assert any(
        n.startswith("4 images at 2 header stamp(s) that several share") for n in summary["notes"]
    )
    frames = load_dataset(flight).frames  # refused before: one frame id twice
    names = [f.telemetry["source_image"] for f in frames]
    assert names == [
        f"{topic}@{stamp[0]}#0",
        f"{topic}@{stamp[0]}#1",
        first,
        f"{topic}@{stamp[3]}#4",
    ]
    assert len({f.frame_id for f in frames}) == 4
    info = run_cli("dataset", "info", flight, cwd=REPO)
    assert info.returncode == 0, info.stderr


# --- Series ---------------------------------------------------------------------------------


def test_a_series_at_a_sample_time_gives_that_sample_beside_a_missing_value() -> None:
    """At a sample's own time the series gave (1 - 1) * NaN + 1 * value = NaN when the sample
    before lacked that value."""
    s = Series.build("x", [0.0, 1.0, 2.0], [[math.nan, 10.0], [5.0, 20.0], [7.0, 30.0]], source="x")
    assert s.at(1.0, 5.0).tolist() == [5.0, 20.0]  # type: ignore[union-attr]
    assert s.at(0.0, 5.0).tolist()[1] == 10.0  # type: ignore[index]
    assert s.at(2.0, 0.0).tolist() == [7.0, 30.0]  # type: ignore[union-attr]


def test_a_series_time_that_is_not_a_number_is_refused() -> None:
    """A NaN time hid a jump back (5 s, NaN, 1 s passed as ascending)."""
    with pytest.raises(InvalidInputError) as refused:
        Series.build("p", [0.0, 5.0, math.nan, 1.0], [[1.0]] * 4, source="log")
    assert "sample 2 of p has no finite time (nan)" in str(refused.value)
