"""Two images or telemetry rows that state the same time are refused, never placed on one pose:
photos paired with a log by their own capture times (a camera writing whole seconds, a clock
that stalled) are refused naming both and the time, with the ways out, as the telemetry CSV's
rows are; photos that carry their own position keep it. Logs and photos are written with the
libraries' own writers (:mod:`c3_matcher_tools.testing.flightlogs`) over the shipped demo
flight."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from c3_matcher.errors import InvalidInputError
from c3_matcher.serialize import load_calibration
from c3_matcher_tools.dataset.format import load_dataset
from c3_matcher_tools.dataset.sources.images import folder_shots
from c3_matcher_tools.dataset.sources.options import ImportOptions, ProposalOptions
from c3_matcher_tools.dataset.sources.pairing import match_shots, same_times, utc_text
from c3_matcher_tools.dataset.sources.ulog import read_ulog
from c3_matcher_tools.dataset.telemetry import read_telemetry_table
from c3_matcher_tools.testing import flightlogs as fl
from c3_matcher_tools.testing.flightlogs.exif import write_exif_photos
from c3_matcher_tools.testing.flightlogs.ulog import write_ulog

from .conftest import DEMO
from .conftest import DEMO_CALIBRATION as CAL
from .conftest import DEMO_STORE as STORE
from .conftest import run_in_repo as c3


@pytest.fixture(scope="module")
def poses() -> list[fl.Pose]:
    return fl.flight_poses(DEMO, range(5))


def _same_second(poses: list[fl.Pose], folder: Path, *, xmp: bool = False) -> Path:
    """The poses' EXIF photos, DJI_0001.JPG stating DJI_0000.JPG's capture time."""
    stamped = [dataclasses.replace(poses[1], t_s=poses[0].t_s), *poses[2:]]
    return write_exif_photos(folder, [poses[0], *stamped], xmp=xmp)


def test_photos_at_one_capture_time_are_refused_not_put_on_one_pose(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    """A log without camera triggers pairs the photos by their own times: two at one time are
    refused naming both and the time, and file order (the way out said) imports all five."""
    log = write_ulog(tmp_path / "flight.ulg", poses, flaws=("no_trigger",))
    photos = _same_second(poses, tmp_path / "photos")
    for asked in ((), ("--time-source", "exif")):
        proc = c3("dataset", "import", photos, log, CAL, STORE, tmp_path / "x", *asked)
        assert proc.returncode == 2, (proc.stdout[-1000:], proc.stderr[-2000:])
        lines = [x for x in proc.stderr.splitlines() if x.strip()]
        assert len(lines) == 1, proc.stderr
        when = utc_text(fl.UTC0 + poses[0].t_s)
        assert f"DJI_0000.JPG and DJI_0001.JPG: same capture time {when}" in lines[0]
        assert "--time-source order with --interval" in lines[0]
        assert not (tmp_path / "x").exists()
    start = f"{fl.BOOT_S + poses[0].t_s:g}"
    proc = c3("dataset", "import", photos, log, CAL, STORE, tmp_path / "f", "--json",
              "--time-source", "order", "--interval", "2", "--time-offset", start)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert json.loads(proc.stdout)["frames"] == 5


def test_with_camera_triggers_the_refusal_names_them_as_the_way_out(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    track = read_ulog(write_ulog(tmp_path / "flight.ulg", poses))
    shots = folder_shots(_same_second(poses, tmp_path / "photos"))
    options = ImportOptions(
        load_calibration(Path(CAL)), ProposalOptions(Path(STORE)), time_source="exif"
    )
    with pytest.raises(InvalidInputError, match="log's 5 camera trigger"):
        match_shots(track, shots, options)
    auto = match_shots(track, shots, dataclasses.replace(options, time_source="auto"))
    assert len(auto.taken) == 5  # as many triggers as photos: paired in capture order


def test_photos_with_their_own_position_keep_it_at_one_capture_time(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    photos = _same_second(poses, tmp_path / "photos", xmp=True)
    proc = c3("dataset", "import", photos, "-", CAL, STORE, tmp_path / "f", "--json")
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert json.loads(proc.stdout)["frames"] == 5
    at = {f.telemetry["source_image"]: f.telemetry for f in load_dataset(tmp_path / "f").frames}
    for k in (0, 1):  # each on its own position
        own = at[f"DJI_{k:04d}.JPG"]
        assert (own["lat"], own["lon"]) == pytest.approx((poses[k].lat, poses[k].lon), abs=1e-6)


def test_telemetry_rows_at_one_time_are_refused_by_the_same_rule(tmp_path: Path) -> None:
    """Rows out of time order: the repeat is found among neighbours in time, named by line."""
    csv = tmp_path / "t.csv"
    rows = [(3.0, "c"), (1.0, "a"), (2.0, "b"), (1.0, "d")]
    csv.write_text(
        "time_s,image,lat,lon,altitude_m,roll_deg,pitch_deg,yaw_deg\n"
        + "".join(f"{t},{name}.jpg,47.0,8.0,100,0,0,0\n" for t, name in rows)
    )
    with pytest.raises(InvalidInputError, match=r"t\.csv: lines 3 and 5: same time_s 1\.0$"):
        read_telemetry_table(csv)
    assert same_times([3.0, 1.0, 2.0, 1.0, 1.0]) == [(1, 3), (3, 4)]
    assert same_times([1.0, 2.0]) == []
