"""``c3-matcher dataset import`` from a recorded log: the source kinds beside the telemetry CSV,
their options, and the run (see :mod:`c3_matcher_tools.dataset.sources.writer`)."""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

from c3_matcher.commands import bounded_float, bounded_int
from c3_matcher.context import CommandContext
from c3_matcher.errors import InvalidInputError
from c3_matcher_tools.dataset.provenance import LOG_OPTIONS
from c3_matcher_tools.dataset.sources.options import (
    MAX_GEOID_HEIGHT_M,
    MAX_TIME_OFFSET_S,
    ImportOptions,
    ImportReport,
    ProposalOptions,
    check_geoid_height,
    check_ground_options,
)

if TYPE_CHECKING:
    from c3_matcher.dto import CameraCalibration
    from c3_matcher_tools.dataset.sources.track import LogTrack, Shot

__all__ = [
    "KINDS",
    "LOG_HELP",
    "add_log_import_options",
    "detect_kind",
    "import_log",
    "proposal_options",
    "recorded",
    "run_log_import",
]

KINDS = ("auto", "csv", "ulog", "ardupilot", "rosbag", "exif")

LOG_HELP = """\

RECORDED LOGS (--source, told from TELEMETRY by default; the logs extra:
pip install 'c3-matcher-tools[logs]'):
  csv        TELEMETRY is the CSV above
  ulog       TELEMETRY is a PX4 ULog (.ulg); IMAGES a folder of images or a video
  ardupilot  TELEMETRY is an ArduPilot DataFlash log (.bin) or telemetry log (.tlog)
  rosbag     TELEMETRY is a ROS 1/2 bag (folder with metadata.yaml, .db3, .mcap, .bag)
             holding the images: IMAGES is '-' (or the bag again); CALIBRATION '-' takes
             the recorded sensor_msgs/CameraInfo
  exif       IMAGES is a folder of photos with EXIF GPS (and XMP gimbal angles and
             RelativeAltitude, as DJI writes them); TELEMETRY is '-' (or the folder again)
Images meet the log by camera trigger (when logged: photos that state their capture time
by that time, else in file order when the log has as many triggers as there are photos,
else refused; a video keeps its own clock), else by their own UTC time (EXIF, bag stamps),
else in file order (--interval, --time-offset). A copy of a photo is imported once; a file
that is not a readable image (a macOS ._ file, a photo cut short) is skipped, not counted.
Height above ground: rangefinder when logged (ArduPilot's made vertical: x cos roll cos
pitch), else altitude above sea level minus --dem or --ground-elevation (not both), else
minus the home altitude in force at the frame's time (set again at arming). A bag's NavSatFix
altitude is above the WGS84 ellipsoid: with a ground, give --geoid-height (0 if its driver
writes sea-level altitude). Options a source does not use are refused (a CSV takes no log timing
or topic option). Frames without attitude or height (a log without attitude included) are
imported and marked; frames that cannot be placed are skipped; the import says which and
why. Each frame keeps its GNSS fix and its stated accuracy: replay
reports the estimate minus that position.
"""


def detect_kind(telemetry: str, images: str) -> str:
    """The source kind of ``telemetry`` (see ``LOG_HELP``); raises InvalidInputError when it
    cannot be told."""
    path = Path(telemetry)
    suffix = path.suffix.lower()
    if telemetry == "-" or (path.is_dir() and path == Path(images) and not _is_bag(path)):
        return "exif"
    if suffix == ".csv":
        return "csv"
    if suffix == ".ulg":
        return "ulog"
    if suffix in (".bin", ".tlog", ".log"):
        return "ardupilot"
    if suffix in (".mcap", ".db3", ".bag") or _is_bag(path):
        return "rosbag"
    raise InvalidInputError(
        "TELEMETRY",
        f"{telemetry}: cannot tell the log's kind from its name: give --source "
        "(csv, ulog, ardupilot, rosbag, exif)",
    )


def _is_bag(path: Path) -> bool:
    """A ROS 2 bag's folder: its metadata.yaml, or its .db3 or .mcap files without it (the bag
    reader then says what it lacks)."""
    if not path.is_dir():
        return False
    return (path / "metadata.yaml").is_file() or any(
        p.suffix.lower() in (".db3", ".mcap") for p in path.iterdir()
    )


def add_log_import_options(m: argparse.ArgumentParser) -> None:
    """The recorded-log options of ``dataset import`` (and its help text)."""
    m.description = (m.description or "") + LOG_HELP
    g = m.add_argument_group("recorded logs")
    g.add_argument(
        "--source", choices=KINDS, default="auto", help="kind of TELEMETRY (default: told from it)"
    )
    g.add_argument(
        "--time-source",
        choices=("auto", "trigger", "exif", "order"),
        default=None,
        help="how images meet the log: camera trigger, the images' own UTC time, or file order "
        "(default: the first available, in that order)",
    )
    g.add_argument(
        "--time-offset",
        type=bounded_float(-MAX_TIME_OFFSET_S, MAX_TIME_OFFSET_S),
        default=None,
        help="seconds added to the images' times: to their own (EXIF) times, negative when the "
        "camera's clock is ahead of the log's (as many photos as triggers keep their triggers' "
        "times: they take them in capture order, which no offset changes); to the trigger times "
        "when images without a time take the triggers in order; in file order, the log time of "
        "the first image; default 0, but where photos and camera triggers differ in count the "
        "camera clock's offset is found (give 0 to say the camera's clock is the log's); "
        f"at most {MAX_TIME_OFFSET_S:g} s either way (127 years: a log clock of UTC seconds since "
        "1970, or a camera clock never set)",
    )
    _positive(g, "--interval", "file order: s between images")
    _positive(g, "--max-gap", "farthest a log sample may be from an image's time, s (default 1)")
    _add_ground_options(g)
    _positive(
        g,
        "--gnss-degraded-m",
        "flag frames whose stated GNSS accuracy is worse than this, m (default 5)",
    )
    g.add_argument(
        "--frame-step",
        type=int,
        default=1,
        help="take every N-th frame of a video or of a bag's image topic (default 1; a "
        "folder's photos are all taken)",
    )
    for topic in ("image", "attitude", "navsat", "camera-info"):
        g.add_argument(f"--{topic}-topic", default=None, help=f"bag: the {topic} topic")
    g.add_argument(
        "--mavlink-system",
        type=bounded_int(1, 255),
        default=None,
        help="telemetry log (.tlog): the MAVLink system (vehicle) to read, when the log holds "
        "several (default: the one that sent camera feedback)",
    )


def _add_ground_options(g: Any) -> None:
    """The options of the ground a height above ground is taken from: ``--ground-elevation``,
    ``--dem`` and a bag's ``--geoid-height``."""
    g.add_argument(
        "--ground-elevation",
        type=bounded_float(),
        default=None,
        help="the ground's altitude above sea level, m: height = altitude - this (or --dem)",
    )
    g.add_argument(
        "--dem",
        type=Path,
        default=None,
        help="DEM GeoTIFF of the ground above sea level (geo extra; its scale and offset "
        "applied, feet converted)",
    )
    g.add_argument(
        "--geoid-height",
        type=bounded_float(-MAX_GEOID_HEIGHT_M, MAX_GEOID_HEIGHT_M),
        default=None,
        help="bag: sea level's height above the WGS84 ellipsoid at the flight, m (EGM2008; 47.4 "
        "at Zurich): the NavSatFix altitude, above the ellipsoid, less this is above sea level, "
        "as the ground is; needed with a ground; 0 if the driver writes sea-level altitude",
    )


def _positive(group: Any, option: str, help: str) -> None:
    """A positive number option of ``group``, None when not given (its default is in
    :data:`DEFAULTS`: given or not is told apart)."""
    group.add_argument(option, type=bounded_float(0.0, above=True), default=None, help=help)


def run_log_import(args: argparse.Namespace, ctx: CommandContext) -> int | None:
    """Run ``dataset import`` for a recorded log; None when TELEMETRY is a CSV (the caller's
    own path)."""
    from c3_matcher_tools.dataset.sources.images import check_frame_step

    images, telemetry = str(args.images_dir), str(args.telemetry)
    kind = args.source if args.source != "auto" else detect_kind(telemetry, images)
    check_frame_step(args.frame_step, video=_frames_of_a_video(kind, images))
    check_ground_options(args.ground_elevation, args.dem)
    refuse_options_not_for(kind, args)
    check_geoid_height(
        telemetry,
        ellipsoidal=kind == "rosbag",
        ground_given=args.ground_elevation is not None or args.dem is not None,
        geoid_height_m=getattr(args, "geoid_height", None),
    )
    if str(args.calibration) == "-" and kind != "rosbag":  # before any log is read
        raise InvalidInputError(
            "CALIBRATION",
            f"'-' takes the intrinsics a ROS bag records (CameraInfo); a {kind} source records "
            "none: give the camera's calibration JSON",
        )
    if kind == "csv":
        return None
    report = import_log(kind, args)
    ctx.out(json.dumps(report.to_json(), indent=2) if args.json else "\n".join(report.lines()))
    return 0


SOURCE_OPTIONS = (
    ("time_source", "--time-source", ("ulog", "ardupilot", "rosbag")),
    ("time_offset", "--time-offset", ("ulog", "ardupilot", "rosbag", "exif")),
    ("interval", "--interval", ("ulog", "ardupilot", "rosbag")),
    ("max_gap", "--max-gap", ("ulog", "ardupilot", "rosbag", "exif")),
    ("gnss_degraded_m", "--gnss-degraded-m", ("ulog", "ardupilot", "rosbag", "exif")),
    *((f"{t}_topic", f"--{t}-topic", ("rosbag",)) for t in ("image", "attitude", "navsat")),
    ("camera_info_topic", "--camera-info-topic", ("rosbag",)),
    ("mavlink_system", "--mavlink-system", ("ardupilot",)),
    ("geoid_height", "--geoid-height", ("rosbag",)),
)
"""(attribute, option, the source kinds it applies to) of each option that some kinds do not
use: a telemetry CSV pairs rows and images by name and states each frame's telemetry; a photo
folder places each photo at its own time; only a bag has topics, and only a bag's altitude
(NavSatFix) is above the ellipsoid rather than sea level."""
DEFAULTS = {"time_source": "auto", "time_offset": None, "max_gap": 1.0, "gnss_degraded_m": 5.0}
"""The values of the options of :data:`SOURCE_OPTIONS` not given (None there: given or not is
told apart; ``--time-offset`` not given adds 0 but, unlike a 0 given, lets the camera clock's
offset be found: see :class:`~c3_matcher_tools.dataset.sources.options.ImportOptions`)."""


def refuse_options_not_for(kind: str, args: argparse.Namespace) -> None:
    """Refuse, naming them, the options given that a ``kind`` import would not use (they would
    change nothing, silently)."""
    given = [
        option
        for name, option, kinds in SOURCE_OPTIONS
        if getattr(args, name, None) is not None and kind not in kinds
    ]
    if not given:
        return
    what = {
        "csv": "a telemetry CSV",
        "exif": "a photo folder",
        "ulog": "a PX4 ULog",
        "ardupilot": "an ArduPilot log",
    }.get(kind, kind)
    only = [
        reason
        for ending, reason in (
            ("-topic", "only a ROS bag has topics"),
            ("--mavlink-system", "only an ArduPilot telemetry log holds several MAVLink systems"),
            (
                "--geoid-height",
                "only a ROS bag states its altitude above the ellipsoid (NavSatFix); this one's "
                "is above sea level already",
            ),
        )
        if any(option.endswith(ending) for option in given)
    ]
    own = {
        "csv": "its rows name their images and state each frame's telemetry",
        "exif": "each photo is placed at its own capture time",
    }.get(kind)
    why = ", and ".join([own, *only]) if own else "; ".join(only)
    raise InvalidInputError(
        ", ".join(given),
        f"not used by an import from {what} ({why}): leave {'it' if len(given) == 1 else 'them'} "
        "out",
    )


def _given(args: argparse.Namespace, name: str) -> Any:
    """Option ``name``'s value, its default (:data:`DEFAULTS`) when not given."""
    value = getattr(args, name, None)
    return DEFAULTS[name] if value is None else value


def _frames_of_a_video(kind: str, images: str) -> bool:
    """Whether IMAGES of a ``kind`` import are a video's (or a bag's) frames, which
    ``--frame-step`` thins, rather than a folder's photos."""
    from c3_matcher_tools.dataset.sources.images import VIDEO_SUFFIXES

    if kind == "rosbag":
        return True
    return kind in ("ulog", "ardupilot") and Path(images).suffix.lower() in VIDEO_SUFFIXES


def import_log(kind: str, args: argparse.Namespace) -> ImportReport:
    """Read the log of ``kind`` named by the parsed ``dataset import`` arguments and write the
    dataset."""
    from c3_matcher_tools.dataset.atomic import check_output_dir
    from c3_matcher_tools.dataset.sources.writer import write_imported_flight

    given = (args.images_dir, args.telemetry, args.calibration, args.store, args.dem)
    check_output_dir(args.out, force=args.force, inputs=given)  # before the log is read
    log = _read_log(kind, args)
    calibration = _calibration(args, log.recorded)
    attitude_of = None
    if kind == "exif":
        from c3_matcher_tools.dataset.sources.exif import photo_attitude

        attitude_of = photo_attitude(calibration)
    return write_imported_flight(
        log.track,
        log.shots,
        _import_options(kind, args, calibration),
        args.out,
        name=args.name,
        force=args.force,
        attitude_of=attitude_of,
        spec={"source_kind": kind, "images": Path(str(args.images_dir)).name, **recorded(args)},
        skipped=log.skipped,
    )


_NOT_GIVEN = MappingProxyType({"--frame-step": 1})
"""The value of an option of :data:`LOG_OPTIONS` that is not given, where it is not None."""


def recorded(args: argparse.Namespace) -> dict[str, Any]:
    """What the spec of the import the parsed arguments ask for records of them beyond its
    sources and its proposal: the log options given (``options``, see
    :data:`~c3_matcher_tools.dataset.provenance.LOG_OPTIONS`), the ground as a telemetry CSV's
    import records it (the DEM by its file name) and a bag's own intrinsics taken
    (CALIBRATION '-'), so that ``dataset import`` can be given them again."""
    given: dict[str, Any] = {}
    for option in LOG_OPTIONS:
        value = getattr(args, option[2:].replace("-", "_"), None)
        if value is not None and value != _NOT_GIVEN.get(option):
            given[option] = value
    spec: dict[str, Any] = {"options": given}
    if args.ground_elevation is not None:
        spec["ground_elevation_m"] = args.ground_elevation
    if args.dem is not None:
        spec["dem"] = Path(args.dem).name
    if str(args.calibration) == "-":
        spec["calibration_json"] = "-"
    return spec


@dataclass(frozen=True)
class _ReadLog:
    """What a recorded log gave: its track, its images, the images set aside (with why) and
    the intrinsics it recorded (a bag's CameraInfo; None otherwise)."""

    track: LogTrack
    shots: list[Shot]
    skipped: list[tuple[str, str]]
    recorded: CameraCalibration | None = None


def _read_log(kind: str, args: argparse.Namespace) -> _ReadLog:
    """The log of ``kind`` and its images, as IMAGES and TELEMETRY name them."""
    telemetry, images = Path(args.telemetry), str(args.images_dir)
    from c3_matcher_tools.dataset.sources.images import read_images, unique_photos

    if kind == "rosbag":
        from c3_matcher_tools.dataset.sources.rosbag import BagTopics, read_bag

        if images not in ("-", str(telemetry)):
            raise InvalidInputError("IMAGES", "a bag holds its images: give '-' as IMAGES")
        topics = BagTopics(
            args.image_topic, args.attitude_topic, args.navsat_topic, args.camera_info_topic
        )
        wanted = str(args.calibration) == "-"  # the recorded intrinsics, checked when wanted
        track, shots, recorded = read_bag(telemetry, topics, args.frame_step, intrinsics=wanted)
        return _ReadLog(track, *unique_photos(shots), recorded)  # a message recorded twice
    if kind == "exif":
        from c3_matcher_tools.dataset.sources.exif import read_photo_folder

        if str(args.telemetry) not in ("-", images):
            raise InvalidInputError("TELEMETRY", "photos carry their own telemetry: give '-'")
        given_ground = args.ground_elevation is not None or args.dem is not None
        return _ReadLog(*read_photo_folder(Path(images), relative_height=not given_ground))
    track = _read_flight_log(kind, telemetry, getattr(args, "mavlink_system", None))
    by_own_time = _given(args, "time_source") not in ("trigger", "order")  # else EXIF unread
    shots, skipped = read_images(Path(images), args.frame_step, metadata=by_own_time)
    return _ReadLog(track, shots, skipped)


def _read_flight_log(kind: str, telemetry: Path, system: int | None = None) -> LogTrack:
    """The track of a flight controller's log (its images come separately); an ArduPilot
    telemetry log's for MAVLink system ``system`` when given."""
    if kind == "ulog":
        from c3_matcher_tools.dataset.sources.ulog import read_ulog

        return read_ulog(telemetry)
    if kind == "ardupilot":
        from c3_matcher_tools.dataset.sources.mavlink import read_mavlink

        return read_mavlink(telemetry, system)
    raise InvalidInputError("--source", f"unknown kind {kind!r}")


def _calibration(args: argparse.Namespace, recorded: CameraCalibration | None) -> CameraCalibration:
    """CALIBRATION's file, or with '-' the intrinsics the log recorded (refused when none)."""
    from c3_matcher.serialize import load_calibration

    if str(args.calibration) == "-":
        if recorded is None:
            raise InvalidInputError(
                "CALIBRATION", "'-' takes the bag's CameraInfo, and none was recorded"
            )
        return recorded
    return load_calibration(Path(args.calibration), field="CALIBRATION")


def _import_options(
    kind: str, args: argparse.Namespace, calibration: CameraCalibration
) -> ImportOptions:
    """How the images meet the log and the candidates are proposed (a photo folder's images
    meet it by their own time)."""
    return ImportOptions(
        calibration=calibration,
        proposal=proposal_options(args),
        time_source="exif" if kind == "exif" else _given(args, "time_source"),
        time_offset_s=_given(args, "time_offset"),
        interval_s=args.interval,
        max_gap_s=_given(args, "max_gap"),
        gnss_degraded_m=_given(args, "gnss_degraded_m"),
        ground_elevation_m=args.ground_elevation,
        dem=args.dem,
        geoid_height_m=getattr(args, "geoid_height", None),
    )


def proposal_options(args: argparse.Namespace) -> ProposalOptions:
    """How the parsed ``dataset import`` arguments say candidates are proposed (every source
    kind, the telemetry CSV's included)."""
    return ProposalOptions(
        store=Path(args.store),
        uncertainty_m=args.uncertainty_m,
        candidates=args.candidates,
        zoom=args.zoom,
        candidate_size_px=args.candidate_size,
        seed=args.seed,
        skip_outside=bool(getattr(args, "skip_outside", False)),  # as parsed, or not given
    )
