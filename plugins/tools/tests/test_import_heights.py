"""Heights above ground taken from recorded logs in the right datum, direction and unit, through
``c3-matcher dataset import`` over logs the product's own writers make of the shipped demo
flight (whose heights are known):

- a ROS bag's NavSatFix altitude is above the WGS84 ellipsoid (the message says so): with a
  ground above sea level the geoid height must be given (``--geoid-height``), is applied, named
  in the height source and repeated by the re-import; other logs' altitudes are above sea level
  and refuse the option;
- an ArduPilot rangefinder reads the range along the tilted body: made vertical with
  cos(roll) cos(pitch), as ArduPilot does;
- a DEM's scale, offset and unit (feet) are applied;
- a ground that leaves every frame at or below it is said so, with the heights it gave."""

from __future__ import annotations

import dataclasses
import json
import math
import shlex
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from c3_matcher.errors import InvalidInputError
from c3_matcher.serialize import load_calibration
from c3_matcher_tools.dataset.format import load_dataset
from c3_matcher_tools.dataset.provenance import IMPORT_REVISION, ImportFault, import_faults
from c3_matcher_tools.dataset.sources.frames import ground_elevation_sampler
from c3_matcher_tools.testing import flightlogs as fl
from c3_matcher_tools.testing.cli import run_cli
from c3_matcher_tools.testing.flightlogs.dataflash import slant_range, write_dataflash
from c3_matcher_tools.testing.flightlogs.mavlink import write_tlog
from c3_matcher_tools.testing.flightlogs.rosbag import write_bag
from c3_matcher_tools.testing.flightlogs.ulog import write_ulog

REPO = Path(__file__).resolve().parents[3]
DEMO = REPO / "data" / "flights" / "naip_demo"
CAL = str(DEMO / "calibration.json")
STORE = str(DEMO / "tiles.mbtiles")
ZURICH_GEOID_M = 47.4
"""Sea level's height above the WGS84 ellipsoid at Zurich (EGM2008), m."""


def c3(*args: str | Path) -> subprocess.CompletedProcess[str]:
    return run_cli(*args, cwd=REPO)


def _refused(proc: subprocess.CompletedProcess[str], *needles: str) -> str:
    """Exit 2 with one error line naming each needle; the line."""
    assert proc.returncode == 2, (proc.returncode, proc.stderr[-2000:])
    lines = [x for x in proc.stderr.splitlines() if x.strip()]
    assert len(lines) == 1, proc.stderr
    for needle in needles:
        assert needle in lines[0], lines[0]
    return lines[0]


def _imported(proc: subprocess.CompletedProcess[str]) -> dict[str, Any]:
    assert proc.returncode == 0, proc.stderr[-3000:]
    return dict(json.loads(proc.stdout))


@pytest.fixture(scope="module")
def poses() -> list[fl.Pose]:
    return fl.flight_poses(DEMO, range(4))


def _heights(flight: Path) -> list[float]:
    return [f.height_m for f in load_dataset(flight).frames]


def test_a_bag_s_ellipsoidal_altitude_needs_and_takes_the_geoid_height(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    """A NavSatFix altitude (above the ellipsoid, 47.4 m above sea level at Zurich) minus a
    ground above sea level made every height 47.4 m too high, with no word. Now the ground
    without --geoid-height is refused naming both ways out; with it the heights are the true
    ones, the report and ``dataset info`` name the datum and the geoid height, and the re-import
    repeats it."""
    cal = load_calibration(DEMO / "calibration.json")
    bag = write_bag(tmp_path / "bag", poses, cal, geoid_height_m=ZURICH_GEOID_M)
    ground = ("--ground-elevation", str(fl.GROUND_M))
    common = ("dataset", "import", "-", bag, "-", STORE)
    _refused(c3(*common, tmp_path / "x", *ground), "--geoid-height", "--geoid-height 0")
    flight = tmp_path / "flight"
    geoid = ("--geoid-height", str(ZURICH_GEOID_M))
    summary = _imported(c3(*common, flight, *ground, *geoid, "--json"))
    source = "altitude above the ellipsoid - geoid height 47.4 m - ground elevation 500 m"
    assert summary["height_sources"] == {source: 4}
    assert _heights(flight) == pytest.approx([p.height_m for p in poses], abs=0.01)
    assert all(f.telemetry["alt_m"] == pytest.approx(p.alt_m, abs=0.01)  # above sea level
               for f, p in zip(load_dataset(flight).frames, poses, strict=True))  # fmt: skip
    info = c3("dataset", "info", flight)
    assert info.returncode == 0 and f"height above ground: {source} (4)" in info.stdout
    meta = json.loads((flight / "dataset.json").read_text())
    assert meta["spec"]["options"]["--geoid-height"] == ZURICH_GEOID_M
    from c3_matcher_tools.dataset.provenance import reimport_command

    words = shlex.split(reimport_command(flight, meta["spec"]).split(" (", 1)[0])
    assert words[words.index("--geoid-height") + 1] == str(ZURICH_GEOID_M), words


def test_a_bag_whose_driver_writes_sea_level_takes_a_geoid_height_of_0(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    """The way out for a driver that writes sea-level altitude into NavSatFix; a --dem without
    --geoid-height is refused as a --ground-elevation is."""
    cal = load_calibration(DEMO / "calibration.json")
    bag = write_bag(tmp_path / "bag", poses[:2], cal, geoid_height_m=0.0)
    common = ("dataset", "import", "-", bag, "-", STORE)
    dem = _dem(tmp_path / "dem.tif", poses, np.float32, fl.GROUND_M)
    _refused(c3(*common, tmp_path / "x", "--dem", dem), "--geoid-height")
    flight = tmp_path / "flight"
    summary = _imported(c3(*common, flight, "--dem", dem, "--geoid-height", "0", "--json"))
    assert summary["height_sources"] == {"altitude above the ellipsoid - geoid height 0 m - DEM": 2}
    assert _heights(flight) == pytest.approx([p.height_m for p in poses[:2]], abs=0.01)


def test_the_geoid_height_is_refused_by_a_log_whose_altitude_is_above_sea_level(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    log = write_ulog(tmp_path / "flight.ulg", poses)
    images = fl.pose_images(tmp_path, poses)
    proc = c3("dataset", "import", images, log, CAL, STORE, tmp_path / "x", "--geoid-height", "47")
    _refused(proc, "--geoid-height: not used by an import from a PX4 ULog", "above sea level")


def test_an_ardupilot_rangefinder_s_range_along_the_tilted_body_is_made_vertical(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    """RFND.Dist (and DISTANCE_SENSOR) is the range along the body's down axis, height / (cos
    roll cos pitch) over flat ground: it was taken as the height (here 2-6 % high, 15 % at 30
    deg of tilt). Now multiplied by cos(roll) cos(pitch) at the frame's time, and said so."""
    assert max(slant_range(p) / p.height_m for p in poses) > 1.02  # the frames do tilt
    log = write_dataflash(tmp_path / "flight.bin", poses, rangefinder=True)
    images = fl.pose_images(tmp_path, poses)
    flight = tmp_path / "bin"
    summary = _imported(c3("dataset", "import", images, log, CAL, STORE, flight, "--json"))
    assert summary["height_sources"] == {"RFND x cos(roll) cos(pitch) (above ground)": 4}
    assert _heights(flight) == pytest.approx([p.height_m for p in poses], rel=1e-4)
    low = [dataclasses.replace(p, height_m=120.0) for p in poses]  # DISTANCE_SENSOR: < 655 m
    tlog = write_tlog(tmp_path / "flight.tlog", low, rangefinder=True)
    flight = tmp_path / "tlog"
    summary = _imported(c3("dataset", "import", images, tlog, CAL, STORE, flight, "--json"))
    assert summary["height_sources"] == {"DISTANCE_SENSOR x cos(roll) cos(pitch) (above ground)": 4}
    assert _heights(flight) == pytest.approx([120.0] * 4, abs=0.01)


def test_a_rangefinder_tilted_past_45_deg_is_corrected_by_0_707_at_most() -> None:
    """ArduPilot's floor of the tilt factor: cos(60) cos(0) = 0.5 is taken as 0.707."""
    from c3_matcher_tools.dataset.sources import frames
    from c3_matcher_tools.dataset.sources.track import LogTrack, Series

    def track(roll: float, along_body: bool = True) -> LogTrack:
        attitude = Series.build("ATT", [0.0], [[roll, 0.0, 0.0]], (2,), source="x")
        height = Series.build("RFND", [0.0], [[100.0]], source="x")
        return LogTrack("x", "ArduPilot DataFlash", attitude, None, height=height,
                        height_along_body=along_body)  # fmt: skip

    assert frames._rangefinder(track(60.0), 0.0, 100.0, 1.0)[0] == pytest.approx(70.7)
    assert frames._rangefinder(track(20.0), 0.0, 100.0, 1.0)[0] == pytest.approx(
        100.0 * math.cos(math.radians(20.0))
    )
    vertical = frames._rangefinder(track(20.0, False), 0.0, 100.0, 1.0)
    assert vertical == (100.0, "RFND (above ground)")


def _dem(path: Path, poses: list[fl.Pose], dtype: Any, value: float, **band: Any) -> Path:
    """A 200 x 200 px DEM of 0.0002 deg over the poses storing ``value`` as ``dtype``, with
    the band's ``scales``, ``offsets`` or ``units`` given."""
    import rasterio
    from affine import Affine

    grid = Affine.translation(poses[0].lon - 0.015, poses[0].lat + 0.02) @ Affine.scale(
        0.0002, -0.0002
    )
    with rasterio.open(
        path, "w", driver="GTiff", width=200, height=200, count=1, dtype=dtype,
        crs="EPSG:4326", transform=grid,
    ) as ds:  # fmt: skip
        ds.write(np.full((1, 200, 200), value, dtype))
        for name, values in band.items():
            setattr(ds, name, values)
    return path


def test_a_dem_s_scale_offset_and_feet_are_applied(poses: list[fl.Pose], tmp_path: Path) -> None:
    """An int16 DEM of decimetres (scale 0.1) read 10x too high (5000 m: every frame below
    ground, the import refused); a unit of feet read as metres. Now its pixels are stored *
    scale + offset, in metres; a unit neither metres nor feet is refused naming it."""
    decimetres = _dem(tmp_path / "dm.tif", poses, np.int16, fl.GROUND_M * 10, scales=(0.1,))
    log = write_ulog(tmp_path / "flight.ulg", poses)
    images = fl.pose_images(tmp_path, poses)
    flight = tmp_path / "flight"
    argv = ("dataset", "import", images, log, CAL, STORE, flight, "--dem", decimetres, "--json")
    assert _imported(c3(*argv))["height_sources"] == {"altitude above sea level - DEM": 4}
    assert _heights(flight) == pytest.approx([p.height_m for p in poses], abs=0.01)
    at = (poses[0].lat, poses[0].lon)
    shifted = _dem(tmp_path / "o.tif", poses, np.int16, 4000, scales=(0.1,), offsets=(100.0,))
    assert ground_elevation_sampler(shifted)(*at) == pytest.approx(fl.GROUND_M)
    feet = _dem(tmp_path / "ft.tif", poses, np.float32, fl.GROUND_M / 0.3048, units=("ft",))
    assert ground_elevation_sampler(feet)(*at) == pytest.approx(fl.GROUND_M, abs=1e-3)
    survey = _dem(tmp_path / "us.tif", poses, np.float32, 1000.0, units=("US survey foot",))
    assert ground_elevation_sampler(survey)(*at) == pytest.approx(1000.0 * 1200 / 3937)
    metres = _dem(tmp_path / "m.tif", poses, np.float32, fl.GROUND_M, units=("metre",))
    assert ground_elevation_sampler(metres)(*at) == pytest.approx(fl.GROUND_M)
    odd = _dem(tmp_path / "odd.tif", poses, np.float32, 5.0, units=("furlong",))
    with pytest.raises(InvalidInputError, match=r"--dem.*'furlong', neither metres nor feet"):
        ground_elevation_sampler(odd)


def test_a_ground_that_leaves_every_frame_below_it_says_the_heights_it_gave(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    """A ground given that put every frame at or below it was answered "give --ground-elevation
    ... or --dem", which the user had. Now the heights it gave are said, and what to check."""
    log = write_ulog(tmp_path / "flight.ulg", poses)
    images = fl.pose_images(tmp_path, poses)
    argv = ("dataset", "import", images, log, CAL, STORE, tmp_path / "x")
    line = _refused(
        c3(*argv, "--ground-elevation", "2000"),
        "--ground-elevation: ",
        "no height above ground for any frame",
        "altitude above sea level - ground elevation 2000 m gave heights from -720.0 to "
        "-720.0 m (none above ground)",
        "check the ground's datum and units",
    )
    assert "give --ground-elevation" not in line
    feet = _dem(tmp_path / "ft.tif", poses, np.float32, 5000.0)  # feet, the unit not stated
    _refused(c3(*argv, "--dem", feet), "--dem: ", "gave heights from -3720.0 to -3720.0 m")


def _faults(kind: str, revision: int, sources: list[str]) -> list[ImportFault]:
    """The import faults said of a dataset of ``kind`` (source kind) and import ``revision``
    whose frames' height sources are ``sources``."""
    log_kind = {"rosbag": "ROS bag", "ardupilot": "ArduPilot DataFlash", "ulog": "PX4 ULog"}[kind]
    spec = {"kind": "import", "log": "f", "log_kind": log_kind, "source_kind": kind,
            "images": "-", "store": "s.mbtiles", "time_source": "camera trigger",
            "time_offset_s": None, "options": {}, "import_revision": revision}  # fmt: skip
    meta = {"name": "f", "spec": spec, "import": {}}
    telemetry = [{"height_source": s} for s in sources]
    return list(import_faults(Path("f"), meta, telemetry))


def _fault_whats(kind: str, revision: int, sources: list[str]) -> list[str]:
    return [f.what for f in _faults(kind, revision, sources)]


def test_datasets_imported_before_are_said_to_be_at_fault() -> None:
    """A bag's heights from its ellipsoidal altitude minus a sea-level ground, and an ArduPilot
    rangefinder's slant range taken as the height, before import revision 4: said, with the
    geoid height to add; a dataset of revision 4, or of a vertical rangefinder (PX4), is not."""
    assert IMPORT_REVISION >= 4
    bag = _fault_whats("rosbag", 3, ["altitude - ground elevation"] * 3)
    assert len(bag) == 1 and "3 of 3 frames" in bag[0] and "add --geoid-height" in bag[0], bag
    (redo,) = {f.redo for f in _faults("rosbag", 3, ["altitude - ground elevation"])}
    assert "--geoid-height N " in redo, redo  # the command as printed runs once N is given
    assert len(_fault_whats("rosbag", 3, ["nearest frame's height (altitude - DEM gave -1 m)"]))
    assert _fault_whats("rosbag", 4, ["altitude - ground elevation"]) == []
    slant = _fault_whats("ardupilot", 3, ["RFND (above ground)", "altitude - home altitude 5 m"])
    assert len(slant) == 1 and "1 of 2 frames" in slant[0] and "cos(roll)" in slant[0], slant
    assert _fault_whats("ardupilot", 4, ["RFND (above ground)"]) == []
    assert _fault_whats("ulog", 3, ["vehicle_local_position.dist_bottom (above ground)"]) == []
