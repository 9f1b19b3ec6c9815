"""What made a flight dataset, and the faults known of the importer that made it.

Every writer records in ``dataset.json``'s ``spec`` the c3-matcher that made the dataset
(``"c3-matcher"``) and the revision of what it writes (``"import_revision"`` for ``dataset
import``, ``"render_revision"`` for ``dataset render``): :func:`made_by`. A fix that changes what
an import writes raises :data:`IMPORT_REVISION` and adds a :class:`_KnownFault` fixed at that
revision, so a dataset of an earlier revision is told by its revision.

Datasets written before revisions were recorded (none in ``spec``) are told by their content:
the faults below fixed on 2026-12-02 left marks of their own in what the importer wrote
(:func:`import_faults`). A loaded dataset carries the notes (``FlightDataset.import_faults``);
``dataset info`` prints them, ``replay`` and ``eval`` say each in one line
(:func:`say_import_faults`).
"""

from __future__ import annotations

import re
import shlex
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from c3_matcher import __version__

__all__ = [
    "IMPORT_REVISION",
    "LOG_OPTIONS",
    "OFFSET_RECORDED_REVISION",
    "RENDER_REVISION",
    "ImportFault",
    "Noted",
    "import_faults",
    "made_by",
    "reimport_command",
    "say_import_faults",
]

IMPORT_REVISION = 4
"""The revision of what ``dataset import`` writes. 1: the first recorded (2026-12-03), with the
home altitude in force at each frame's time, the first downward rangefinder and one camera
trigger per photo; 2 (2026-12-03): an import from a recorded log records the options of
:data:`LOG_OPTIONS` it was given in ``spec["options"]``; 3 (2026-12-05): photos that meet
camera triggers of another count by their own times find the camera clock's offset (before,
the camera's clock was taken as the log's), PX4 estimates marked invalid give way to the
receiver's fix, a MAVLink camera message recorded twice is read once and a telemetry log of
several vehicles is refused; ``spec["time_offset_s"]`` is ``--time-offset`` as given (None
when not: before, 0 stood for both) and the import record says where the offset it applied
came from (``time_offset_origin``); 4 (2026-12-05): a ROS bag's NavSatFix altitude is taken as
above the WGS84 ellipsoid, brought to sea level with ``--geoid-height`` (recorded in
``spec["options"]``) before the ground is taken from it, an ArduPilot rangefinder's range is
made vertical with the attitude (x cos roll cos pitch), and a DEM's scale, offset and unit in
feet are applied; each height source names what it took."""
OFFSET_RECORDED_REVISION = 3
"""The import revision from which ``spec["time_offset_s"]`` tells a ``--time-offset 0`` given
(which says the camera's clock is the log's) from none given (None)."""
RENDER_REVISION = 1
"""The revision of what ``dataset render`` writes (1: the first recorded, 2026-12-03)."""


@dataclass(frozen=True)
class ImportFault:
    """A fault of the importer that made a dataset, fixed since: ``what`` is wrong, what it
    ``affects`` (the figures and results that change) and the command that re-imports it
    (``redo``)."""

    what: str
    affects: str
    redo: str

    def line(self) -> str:
        """The note in one line."""
        return f"{self.what}; this changes {self.affects}; re-import it: {self.redo}"

    def to_json(self) -> dict[str, str]:
        return {"what": self.what, "affects": self.affects, "redo": self.redo}


def made_by(spec: Mapping[str, Any]) -> dict[str, Any]:
    """``spec`` (a dataset's record of how it was made) with the c3-matcher that writes it and
    the revision of its writer: an import's (``kind`` ``import``) or a render's."""
    revision = (
        {"import_revision": IMPORT_REVISION}
        if spec.get("kind") == "import"
        else {"render_revision": RENDER_REVISION}
    )
    return {**spec, "c3-matcher": __version__, **revision}


class Noted(Protocol):
    """What :func:`say_import_faults` reads of a loaded ``FlightDataset``."""

    @property
    def root(self) -> Path: ...

    @property
    def import_faults(self) -> tuple[ImportFault, ...]: ...


def say_import_faults(*datasets: Noted, say: Callable[[str], None]) -> None:
    """Each import fault of each of ``datasets`` (loaded ``FlightDataset``) as one line, given
    to ``say`` (a command's ``ctx.err``): said before a run, never refused, as a user may replay
    such a dataset on purpose."""
    for dataset in datasets:
        for fault in dataset.import_faults:
            say(f"warning: dataset {dataset.root}: {fault.line()}")


_OLD_HOME = re.compile(r"altitude - home altitude(?! -?\d)")
"""A height source as the importer wrote it before 2026-12-02 (since, it names the home
altitude used: ``altitude - home altitude 500.0 m``)."""
_OLD_TRIGGER_NOTE = re.compile(r"\d+ camera trigger\(s\)")
"""An ArduPilot import's trigger note before 2026-12-02 (since: ``... from CAM``)."""
_TRIGGER_COUNTS = re.compile(r"\((\d+) in the log, (\d+) image\(s\)")
ARDUPILOT_KINDS = ("ArduPilot DataFlash", "MAVLink telemetry log")
_HEIGHTS_AFFECT = (
    "the heights, which feed the rectification, the geometric prior and the telemetry "
    "errors: positions and accuracy figures differ from a re-import's"
)


@dataclass(frozen=True)
class _Seen:
    """What a dataset's files say of its import: ``dataset.json``'s ``spec`` and ``import``
    record, and each frame's telemetry."""

    root: Path
    spec: Mapping[str, Any]
    record: Mapping[str, Any]
    telemetry: Sequence[Mapping[str, Any]]


@dataclass(frozen=True)
class _KnownFault:
    """A fault fixed at import revision ``fixed_in``: ``found`` tells from a dataset's content
    whether it shows the fault (a dataset of a later revision is never checked) and returns
    (what, affects), or None."""

    fixed_in: int
    found: Callable[[_Seen], tuple[str, str] | None]


@dataclass(frozen=True)
class _OldHeights:
    """Heights as the importer wrote them before a fix, told by each frame's height source
    (``pattern``, searched) in a log that ``applies`` to (its spec); ``said`` is the fault in
    words, ``{old}`` and ``{frames}`` standing for how many frames show it of how many."""

    pattern: re.Pattern[str]
    said: str
    applies: Callable[[Mapping[str, Any]], bool] = lambda _spec: True

    def __call__(self, seen: _Seen) -> tuple[str, str] | None:
        if not self.applies(seen.spec):
            return None
        sources = (str(t.get("height_source", "")) for t in seen.telemetry)
        old = sum(1 for source in sources if self.pattern.search(source))
        if not old:
            return None
        return self.said.format(old=old, frames=len(seen.telemetry)), _HEIGHTS_AFFECT


_first_home = _OldHeights(  # PX4 and ArduPilot logs, before 2026-12-02
    _OLD_HOME,
    "its heights ({old} of {frames} frames) are the altitude minus the log's first home "
    "altitude, as the importer read them before 2026-12-02, which missed a home set again at "
    "arming, as PX4 and ArduPilot set it (a home 12 m high before arming made 780 m read 768 m)",
)


def _triggers_twice(seen: _Seen) -> tuple[str, str] | None:
    """An ArduPilot log's photos counted twice, once by ``CAM`` and once by ``TRIG`` (before
    2026-12-02): told by the trigger note of then and a log of at least twice as many triggers
    as images."""
    notes = seen.record.get("notes")
    if seen.spec.get("log_kind") not in ARDUPILOT_KINDS or not isinstance(notes, list):
        return None
    if not any(_OLD_TRIGGER_NOTE.fullmatch(str(n)) for n in notes):
        return None
    counts = _TRIGGER_COUNTS.search(str(seen.record.get("time_source", "")))
    if counts is None or int(counts[1]) < 2 * int(counts[2]):
        return None
    what = (
        f"the log held {counts[1]} camera triggers for {counts[2]} images: the importer before "
        "2026-12-02 counted a photo logged as both CAM and TRIG (ArduPilot with a feedback pin) "
        "twice, so the images may have met other photos' triggers"
    )
    affects = (
        "each frame's time, and so its position, attitude, height and candidates: every "
        "result and figure of the flight"
    )
    return what, affects


_OLD_BY_OWN_TIME = re.compile(
    r"camera trigger nearest each image's own UTC time, within [\d.e+-]+ s "
    r"\((\d+) in the log, (\d+) image\(s\)"
)
"""How photos met camera triggers of another count by their own times before import revision
3 (since, ``how`` says the offset: ``..., the images' times moved ... (found ...)`` or
``..., --time-offset ... as given``)."""


def _clock_unsought(seen: _Seen) -> tuple[str, str] | None:
    """Photos that met camera triggers of another count each at the trigger nearest its own
    time, the camera's clock taken as the log's (before import revision 3) with no
    ``--time-offset`` given: a clock off by a trigger interval or more put every photo on
    another's trigger. Told by the time source of then and an offset of 0."""
    how = str(seen.spec.get("time_source", seen.record.get("time_source", "")))
    counts = _OLD_BY_OWN_TIME.match(how)
    if counts is None or seen.spec.get("time_offset_s") not in (None, 0, 0.0):
        return None
    what = (
        f"its {counts[2]} photos met the log's {counts[1]} camera triggers each at the trigger "
        "nearest its own time, the camera's clock taken as the log's, as the importer did before "
        "2026-12-05: a camera clock off the log's by a trigger interval or more put every photo "
        "on another photo's trigger and pose (tens to hundreds of metres off) with no word; the "
        "importer now finds the clock's offset, or refuses naming the offsets it cannot tell apart"
    )
    affects = (
        "each frame's time, and so its position, attitude, height and candidates: every "
        "result and figure of the flight"
    )
    return what, affects


_OLD_GROUND = re.compile(r"^(nearest frame's height \()?altitude - (ground elevation|DEM)\b")
"""A height source from the altitude minus the ground as the importer wrote it before import
revision 4 (since, it names the altitude's datum: ``altitude above sea level - DEM``, a bag's
``altitude above the ellipsoid - geoid height 47.4 m - DEM``)."""

_bag_ellipsoid = _OldHeights(  # NavSatFix altitude above the ellipsoid, a sea-level ground
    _OLD_GROUND,
    "its heights ({old} of {frames} frames) are the bag's NavSatFix altitude minus the ground, "
    "as the importer took them before 2026-12-05: that altitude is above the WGS84 ellipsoid "
    "and the ground above sea level, so each height is off by the geoid height there (47 m at "
    "Zurich); add --geoid-height N (sea level's height above the ellipsoid there, m; 0 if the "
    "bag's driver writes sea-level altitude)",
    lambda spec: spec.get("source_kind") == "rosbag" or spec.get("log_kind") == "ROS bag",
)

_OLD_SLANT = re.compile(r"^(nearest frame's height \()?(RFND|DISTANCE_SENSOR) \(above ground\)")
"""An ArduPilot rangefinder's height source before import revision 4 (since: ``RFND x
cos(roll) cos(pitch) (above ground)``)."""

_rangefinder_slant = _OldHeights(  # the range along the tilted body taken as vertical
    _OLD_SLANT,
    "its heights ({old} of {frames} frames) are the rangefinder's range along the tilted body, "
    "taken as vertical by the importer before 2026-12-05 (6 % too high at 20 deg of tilt, 15 % "
    "at 30 deg); the importer now multiplies it by cos(roll) cos(pitch), as ArduPilot does",
    lambda spec: spec.get("log_kind") in ARDUPILOT_KINDS,
)


_KNOWN = (
    _KnownFault(1, _first_home),
    _KnownFault(1, _triggers_twice),
    _KnownFault(3, _clock_unsought),
    _KnownFault(4, _bag_ellipsoid),
    _KnownFault(4, _rangefinder_slant),
)
"""Every import fault fixed since datasets were first written, in the order they are said."""


def import_faults(
    root: Path, meta: Mapping[str, Any], telemetry: Sequence[Mapping[str, Any]]
) -> tuple[ImportFault, ...]:
    """The known faults of the importer that made the dataset at ``root`` (its ``dataset.json``
    ``meta``, each frame's ``telemetry``): none for a dataset not imported (rendered) or
    imported at a revision that has every fix."""
    spec, record = meta.get("spec"), meta.get("import")
    if not isinstance(spec, Mapping) or spec.get("kind") != "import":
        return ()
    revision = spec.get("import_revision", 0)
    revision = revision if isinstance(revision, int) else 0
    seen = _Seen(root, spec, record if isinstance(record, Mapping) else {}, telemetry)
    name = meta.get("name")
    redo = reimport_command(root, spec, name=str(name) if name else None)
    found = (known.found(seen) for known in _KNOWN if revision < known.fixed_in)
    return tuple(ImportFault(what, affects, redo) for what, affects in filter(None, found))


LOG_OPTIONS = (
    "--time-source",
    "--interval",
    "--max-gap",
    "--gnss-degraded-m",
    "--frame-step",
    "--image-topic",
    "--attitude-topic",
    "--navsat-topic",
    "--camera-info-topic",
    "--mavlink-system",
    "--geoid-height",
)
"""The options of an import from a recorded log that change what it writes beside those
:data:`_OPTIONS` reads: since import revision 2 its ``spec["options"]`` maps each one given to
its value, and its ground is recorded as a telemetry CSV's import records it; a log import's
spec without ``options`` is older and tells none of them, nor its ground."""

_OPTIONS = (
    ("uncertainty_m", "--uncertainty-m", 50.0),
    ("candidates", "--candidates", 3),
    ("candidate_size_px", "--candidate-size", 512),
    ("zoom", "--zoom", None),
    ("seed", "--seed", 0),
    ("time_offset_s", "--time-offset", None),
    ("ground_elevation_m", "--ground-elevation", None),
    ("dem", "--dem", None),
)
"""(``spec`` key, ``dataset import`` option, its default) of the options an import records in
keys of their own (``dem`` by the DEM's file name; ``time_offset_s`` None when not given, so a
0 given is repeated: :func:`_as_given`)."""


def reimport_command(root: Path, spec: Mapping[str, Any], *, name: str | None = None) -> str:
    """The ``dataset import`` that makes the dataset at ``root`` again, replacing it: its
    images, telemetry and store as ``spec`` names them (by file name), its ``name`` and the
    options it was imported with; CALIBRATION stands for the camera calibration, which a
    dataset keeps without its file's name, and N for a bag's geoid height where it was imported
    before the option was. A log import's spec that does not record its log
    options (:data:`LOG_OPTIONS`) is said to."""
    images = spec.get("images") or spec.get("images_dir") or "IMAGES"
    telemetry = spec.get("log") or spec.get("telemetry_csv") or "TELEMETRY"
    calibration = spec.get("calibration_json") or "CALIBRATION"
    words = ["c3-matcher", "dataset", "import", images, telemetry, calibration]
    words += [spec.get("store") or "STORE", str(root), *_option_words(spec)]
    if name:
        words += ["--name", name]
    words.append("--force")
    note = "its sources as the dataset names them: give their paths"
    if spec.get("log") and not isinstance(spec.get("options"), Mapping):
        note += f"; the dataset does not record its log options: {_unknown_options(spec)}"
    return " ".join(shlex.quote(str(w)) for w in words) + f" ({note})"


def _option_words(spec: Mapping[str, Any]) -> list[str]:
    """The options of ``dataset import`` that ``spec`` records, as command-line words: the
    source kind, those of :data:`_OPTIONS` not at their default, ``--skip-outside`` and the log
    options given (:data:`LOG_OPTIONS`)."""
    kind = spec.get("source_kind") or ("csv" if spec.get("telemetry_csv") else None)
    words = ["--source", str(kind)] if kind else []
    as_given = _as_given(spec)
    for key, option, default in _OPTIONS:
        if as_given.get(key) is not None and as_given.get(key) != default:
            words += [option, str(as_given[key])]
    if spec.get("skip_outside"):
        words.append("--skip-outside")
    given = spec.get("options")
    given = given if isinstance(given, Mapping) else {}
    words += [w for o in LOG_OPTIONS if o in given for w in (o, str(given[o]))]
    if spec.get("source_kind") == "rosbag" and "--geoid-height" not in given:
        words += ["--geoid-height", "N"]  # before revision 4: the bag's geoid height, to give
    return words


def _as_given(spec: Mapping[str, Any]) -> Mapping[str, Any]:
    """``spec`` with its ``time_offset_s`` as given: an import before
    :data:`OFFSET_RECORDED_REVISION` recorded 0 for no ``--time-offset`` (and a 0 given meant
    the same then), so its 0 is taken as not given, and the re-import finds the camera clock's
    offset as an import now does."""
    revision = spec.get("import_revision", 0)
    old = not isinstance(revision, int) or revision < OFFSET_RECORDED_REVISION
    if old and spec.get("time_offset_s") == 0:
        return {**spec, "time_offset_s": None}
    return spec


def _unknown_options(spec: Mapping[str, Any]) -> str:
    """What to add to the command of a log import that did not record its log options (a bag's
    topics and intrinsics only for a bag's)."""
    bag = spec.get("source_kind") == "rosbag"
    named = "/".join(
        o for o in LOG_OPTIONS if (bag or not o.endswith("-topic")) and o != "--geoid-height"
    )
    said = f"add {named} and --ground-elevation or --dem if you gave them"
    return said + ("; '-' for CALIBRATION if it took the bag's CameraInfo" if bag else "")
