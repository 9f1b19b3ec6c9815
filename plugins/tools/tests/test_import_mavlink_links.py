"""ArduPilot logs as they come off a ground station or a vehicle without an estimator origin: a
log whose positions are the GNSS receiver's alone (no ``GLOBAL_POSITION_INT``, or all of them at
0, 0; a DataFlash log without ``POS``) is imported with the ground given; a telemetry log of
several MAVLink systems that sent positions and no camera feedback is refused naming them, and
``--mavlink-system`` reads the one given; a photo's ``CAMERA_FEEDBACK`` received twice (a ground
station on two links) is one trigger. Logs are written with pymavlink's own packer over frames
of the shipped demo flight, and imported from its images."""

from __future__ import annotations

import dataclasses
import json
import struct
import subprocess
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from c3_matcher.errors import InvalidInputError
from c3_matcher_tools.dataset.format import load_dataset
from c3_matcher_tools.dataset.sources.mavlink import read_mavlink
from c3_matcher_tools.testing import flightlogs as fl
from c3_matcher_tools.testing.cli import run_cli
from c3_matcher_tools.testing.flightlogs.dataflash import write_dataflash
from c3_matcher_tools.testing.flightlogs.mavlink import _tlog_frames, _tlog_positions
from c3_matcher_tools.testing.flightlogs.ulog import write_ulog

REPO = Path(__file__).resolve().parents[3]
DEMO = REPO / "data" / "flights" / "naip_demo"
STORE = str(DEMO / "tiles.mbtiles")
CAL = str(DEMO / "calibration.json")

Record = tuple[float, int, Any]
"""(time s from the first frame, the MAVLink system that sent it, the message)."""


@pytest.fixture(scope="module")
def poses() -> list[fl.Pose]:
    return fl.flight_poses(DEMO, range(4))


def _flight(poses: Sequence[fl.Pose], system: int = 1, flaws: Sequence[str] = ()) -> list[Record]:
    """A vehicle's messages as :func:`~c3_matcher_tools.testing.flightlogs.mavlink.write_tlog`
    writes them (positions, GNSS, attitude, camera feedback), sent by ``system``."""
    return [(t, system, m) for t, m in _tlog_positions(poses) + _tlog_frames(poses, flaws)]


def _tlog(path: Path, records: Sequence[Record]) -> Path:
    """A telemetry log of ``records`` in time order (stable), each packed by its system's link."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    links: dict[int, Any] = {}
    with path.open("wb") as fh:
        for t, system, msg in sorted(records, key=lambda r: r[0]):
            link = links.setdefault(system, mavlink.MAVLink(None, srcSystem=system, srcComponent=1))
            fh.write(struct.pack(">Q", int((fl.UTC0 + t) * 1e6)) + msg.pack(link))
    return path


def _import(
    tmp_path: Path, images: Path, log: Path, *extra: str
) -> subprocess.CompletedProcess[str]:
    out = tmp_path / "flight"
    return run_cli("dataset", "import", images, log, CAL, STORE, out, "--json", *extra, cwd=REPO)


def _placed(flight: Path) -> list[tuple[float, float, float]]:
    """Each imported frame's position and height above ground."""
    frames = load_dataset(flight).frames
    return [(f.telemetry["lat"], f.telemetry["lon"], f.height_m) for f in frames]


def _expected(poses: Sequence[fl.Pose]) -> list[tuple[float, float, float]]:
    return [(p.lat, p.lon, p.height_m) for p in poses]


# --- positions from the GNSS receiver alone -------------------------------------------------


def _at_zero(m: Any) -> Any:
    """A GLOBAL_POSITION_INT as ArduPilot sends it before its estimator has an origin."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    return mavlink.MAVLink_global_position_int_message(
        m.time_boot_ms, 0, 0, m.alt, m.relative_alt, 0, 0, 0, 0
    )


def _without_pos(path: Path, poses: Sequence[fl.Pose]) -> Path:
    """A DataFlash log as :func:`write_dataflash` writes it, without its POS messages."""
    data = write_dataflash(path, poses).read_bytes()
    pos = next(kind for kind, name in _fmt_names(data).items() if name == "POS")
    path.write_bytes(_drop_type(data, pos))
    return path


def _fmt_names(data: bytes) -> dict[int, str]:
    """The DataFlash message types a log's FMT messages define, by id (each FMT message, 89
    bytes: the header, 128, then the type's id, its length and its name)."""
    names, at = {}, 0
    while at + 3 < len(data) and data[at + 2] == 128:
        names[data[at + 3]] = data[at + 5 : at + 9].rstrip(b"\0").decode()
        at += 89
    return names


def _drop_type(data: bytes, dropped: int) -> bytes:
    """``data`` (a binary DataFlash log) without its messages of type ``dropped``."""
    lengths, kept, at = {128: 89}, bytearray(), 0
    while at < len(data):
        kind = data[at + 2]
        if kind == 128:
            lengths[data[at + 3]] = data[at + 4]
        if kind != dropped:
            kept += data[at : at + lengths[kind]]
        at += lengths[kind]
    return bytes(kept)


@pytest.mark.parametrize("log", ["tlog-gnss-alone", "tlog-positions-at-0-0", "bin-without-pos"])
def test_a_log_whose_positions_are_the_receiver_s_alone_is_imported_with_the_ground_given(
    poses: list[fl.Pose], tmp_path: Path, log: str
) -> None:
    """A telemetry log without GLOBAL_POSITION_INT (or with all of them at 0, 0: an estimator
    without origin), or a DataFlash log without POS, stopped ``dataset import --ground-elevation``
    with "internal error: ValueError: cannot reshape array of size 0": the home altitude was
    read from no sample. The frames now take the receiver's fixes, their heights above the
    ground given."""
    path = tmp_path / ("flight.bin" if log.startswith("bin") else "flight.tlog")
    if log == "bin-without-pos":
        _without_pos(path, poses)
    else:
        edit = (lambda m: None) if log == "tlog-gnss-alone" else _at_zero
        records = [
            (t, n, m if m.get_type() != "GLOBAL_POSITION_INT" else edit(m))
            for t, n, m in _flight(poses)
        ]
        _tlog(path, [r for r in records if r[2] is not None])
    track = read_mavlink(path)
    assert track.position is None and track.home is None
    assert track.gnss is not None and len(track.gnss) == len(fl.dense_track(poses))
    proc = _import(
        tmp_path, fl.pose_images(tmp_path, poses), path, "--ground-elevation", str(fl.GROUND_M)
    )
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["height_sources"] == {
        "altitude above sea level - ground elevation 500 m": 4
    }
    assert np.allclose(_placed(tmp_path / "flight"), _expected(poses), atol=1e-6)


# --- several MAVLink systems ----------------------------------------------------------------


def _tracker(poses: Sequence[fl.Pose], system: int = 2) -> list[Record]:
    """An antenna tracker on the ground at the first frame's place, sending its position and
    attitude twice a second from 60 s before the first frame to the last."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    first, records = poses[0], []
    lat, lon = round(first.lat * 1e7), round(first.lon * 1e7)
    for k in range(round((poses[-1].t_s - first.t_s + 60.0) * 2) + 1):
        t = first.t_s - 60.0 + k / 2
        ms = int((fl.BOOT_S + t) * 1e3)
        place = mavlink.MAVLink_global_position_int_message(
            ms, lat, lon, round(fl.GROUND_M * 1e3), 0, 0, 0, 0, 0
        )
        records += [
            (t, system, place),
            (t, system, mavlink.MAVLink_attitude_message(ms, 0, 0.3, 0.7, 0, 0, 0)),
        ]
    return records


def test_several_systems_without_camera_feedback_are_refused_naming_them(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    """A tracker sending its position beside a vehicle without camera feedback: the system
    whose position came first (the tracker's) was read, every frame placed at the tracker, with
    a note alone. Now refused, naming each system, what it sent and whether it moves, and the
    option that reads one; with it, that system is read and the notes name it."""
    tracker = _tracker(poses)
    log = _tlog(tmp_path / "flight.tlog", _flight(poses, flaws=("no_trigger",)) + tracker)
    with pytest.raises(InvalidInputError) as refused:
        read_mavlink(log)
    said = str(refused.value)
    assert "MAVLink systems 1, 2 in the log sent positions and none sent camera feedback" in said
    moves = len(fl.dense_track(poses))
    assert f"system 1 ({moves} position(s), {moves} GNSS fix(es), 4 attitude(s), 0 camera" in said
    still = len(tracker) // 2
    assert f"system 2 ({still} position(s), 0 GNSS fix(es), {still} attitude(s), 0 camera" in said
    assert "stays within 0 m" in said and said.count("moves over") == 1
    assert said.endswith("give --mavlink-system N to read system N")
    track = read_mavlink(log, 1)
    assert (
        track.notes[0]
        == "MAVLink systems 1, 2 in the log: read system 1 (given by --mavlink-system)"
    )
    assert track.position is not None
    at = [track.position.at(fl.UTC0 + p.t_s, 0.01) for p in poses]
    assert np.allclose([a[:2] for a in at if a is not None], [(p.lat, p.lon) for p in poses])
    with pytest.raises(InvalidInputError, match=r"no MAVLink system 3 in the log; it holds "):
        read_mavlink(log, 3)


def test_one_of_two_camera_vehicles_is_imported_by_mavlink_system_and_recorded(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    """Two aircraft on one link, each sending camera feedback: refused unasked (naming the
    option); ``--mavlink-system 2`` imports the second's flight and the dataset records the
    option, so that its re-import reads the same system. The option is refused for a log that
    names no system (a DataFlash log, a PX4 ULog)."""
    east = [dataclasses.replace(p, lon=p.lon + 0.025) for p in poses]
    log = _tlog(tmp_path / "flight.tlog", _flight(poses) + _flight(east, system=2))
    images = fl.pose_images(tmp_path, poses)
    refused = _import(tmp_path, images, log)
    assert refused.returncode == 2 and "camera feedback from MAVLink systems 1, 2" in refused.stderr
    assert "give --mavlink-system N to read system N" in refused.stderr
    proc = _import(tmp_path, images, log, "--mavlink-system", "2")
    assert proc.returncode == 0, proc.stderr
    notes = json.loads(proc.stdout)["notes"]
    assert "MAVLink systems 1, 2 in the log: read system 2 (given by --mavlink-system)" in notes
    assert np.allclose(_placed(tmp_path / "flight"), _expected(east), atol=1e-6)
    spec = json.loads((tmp_path / "flight" / "dataset.json").read_text())["spec"]
    assert spec["options"] == {"--mavlink-system": 2}
    for other, why in (
        (write_dataflash(tmp_path / "f.bin", poses), "a DataFlash log is written on one vehicle"),
        (write_ulog(tmp_path / "f.ulg", poses), "not used by an import from a PX4 ULog (only an"),
    ):
        proc = _import(tmp_path, images, other, "--mavlink-system", "1", "--force")
        assert proc.returncode == 2 and "--mavlink-system: " in proc.stderr, proc.stderr
        assert why in proc.stderr


# --- a photo's camera feedback received twice -----------------------------------------------


def test_camera_feedback_received_twice_is_one_photo(poses: list[fl.Pose], tmp_path: Path) -> None:
    """A ground station on two links records each CAMERA_FEEDBACK twice, 30 ms apart: twice as
    many triggers as photos, refused with advice to pair them in order (which put every other
    photo on its neighbour's pose). The copies (same camera, image number and time) are now
    dropped, and the notes say how many."""
    records = _flight(poses)
    again = [(t + 0.03, n, m) for t, n, m in records if m.get_type() == "CAMERA_FEEDBACK"]
    log = _tlog(tmp_path / "flight.tlog", records + again)
    proc = _import(tmp_path, fl.pose_images(tmp_path, poses), log)
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    assert summary["time_source"] == "camera trigger (4 in the log, 4 image(s))"
    assert (
        "4 camera trigger(s) from CAMERA_FEEDBACK; 4 more CAMERA_FEEDBACK of the same photos "
        "(each received again, as over a second link) dropped"
    ) in summary["notes"]
    assert np.allclose(_placed(tmp_path / "flight"), _expected(poses), atol=1e-6)


def test_photos_a_camera_numbers_alike_are_each_a_trigger(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    """Only a copy is dropped: photos whose feedback gives one image number (a camera that
    does not count) but each its own time are each a trigger."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    records = []
    for t, n, m in _flight(poses):
        if m.get_type() == "CAMERA_FEEDBACK":
            fields = [getattr(m, name) for name in m.get_fieldnames()]
            fields[m.get_fieldnames().index("img_idx")] = 0
            m = mavlink.MAVLink_camera_feedback_message(*fields)
        records.append((t, n, m))
    track = read_mavlink(_tlog(tmp_path / "flight.tlog", records))
    assert track.triggers_s is not None and len(track.triggers_s) == len(poses)
    assert track.notes == (f"{len(poses)} camera trigger(s) from CAMERA_FEEDBACK",)
