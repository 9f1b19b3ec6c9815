"""A flight dataset imported by an earlier importer with a fault fixed since is said, not used
silently: loading it gives typed notes (what is wrong, what it changes, the command that
re-imports it), ``dataset info`` prints them (and ``--json`` lists them), and the one-call
printer ``replay`` and ``eval`` use writes each as one line. A dataset made now records the
c3-matcher that made it and the revision of its importer (or renderer), so the next fault fixed
is told by that revision.

The aged datasets are imports by the current importer of the shipped test logs (a PX4 ULog and
an ArduPilot DataFlash log whose home was set again at arming), their files then edited the way
the importer of 2026-11-28 wrote them: each frame's height source without the home altitude it
used, the trigger note without its message, no c3-matcher version and no revision."""

from __future__ import annotations

import io
import json
import re
import shlex
import shutil
import subprocess
from pathlib import Path
from typing import Any

import pytest

from c3_matcher import __version__
from c3_matcher_tools.dataset.format import load_dataset
from c3_matcher_tools.dataset.provenance import (
    IMPORT_REVISION,
    RENDER_REVISION,
    ImportFault,
    import_faults,
    reimport_command,
    say_import_faults,
)
from c3_matcher_tools.dataset.sources.options import ImportReport
from c3_matcher_tools.testing import flightlogs as fl
from c3_matcher_tools.testing.cli import run_cli
from c3_matcher_tools.testing.flightlogs.dataflash import write_dataflash
from c3_matcher_tools.testing.flightlogs.ulog import write_ulog

REPO = Path(__file__).resolve().parents[3]
DEMO = REPO / "data" / "flights" / "naip_demo"
NAIP_2020 = REPO / "data" / "imagery" / "naip_timeseries" / "m_4709963_se_14_1_20200831.tif"
OLD_HOME_SOURCE = "altitude - home altitude"  # as the importer of 2026-11-28 wrote it
FRAMES = 4


def _c3(cwd: Path, *args: str | Path) -> subprocess.CompletedProcess[str]:
    return run_cli(*args, cwd=cwd, timeout=600)


@pytest.fixture(scope="module")
def imported(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Fresh imports of a ULog and a DataFlash log (home set again at arming) by this importer:
    ``{"ulog": dataset, "bin": dataset, "work": their folder}``."""
    work = tmp_path_factory.mktemp("import_faults")
    poses = fl.flight_poses(DEMO, range(FRAMES))
    write_ulog(work / "flight.ulg", poses, flaws=("home_reset",))
    write_dataflash(work / "flight.bin", poses, flaws=("home_reset",))
    (work / "images").mkdir()
    for i, p in enumerate(poses):
        shutil.copyfile(p.image, work / "images" / f"IMG_{i:04d}.jpg")
    shutil.copyfile(DEMO / "tiles.mbtiles", work / "naip_store.mbtiles")
    out = {"work": work}
    for key, log in (("ulog", "flight.ulg"), ("bin", "flight.bin")):
        argv = ("images", log, DEMO / "calibration.json", "naip_store.mbtiles", f"{key}_flight")
        proc = _c3(work, "dataset", "import", *argv)
        assert proc.returncode == 0, proc.stderr[-2000:]
        out[key] = work / f"{key}_flight"
    return out


def _aged(fresh: Path, to: Path, *, triggers_in_log: int | None = None) -> Path:
    """A copy of ``fresh`` as the importer of 2026-11-28 wrote it (see the module docstring);
    ``triggers_in_log``: the camera triggers its time source says the log held."""
    shutil.copytree(fresh, to)
    meta = json.loads((to / "dataset.json").read_text())
    for key in ("c3-matcher", "import_revision"):
        meta["spec"].pop(key, None)
    record = meta["import"]
    record["height_sources"] = {OLD_HOME_SOURCE: sum(record["height_sources"].values())}
    then = [n for n in record["notes"] if not n.startswith(("home altitude (", "tiles.mbtiles:"))]
    if record["kind"] == "ArduPilot DataFlash":  # its trigger note named no message then
        then = [re.sub(r"^(\d+ camera trigger\(s\)) from .*", r"\1", n) for n in then]
    record["notes"] = then
    if triggers_in_log is not None:
        images = record["frames"]
        how = f"camera trigger in file order, as asked ({triggers_in_log} in the log, {images} "
        how += f"image(s): {triggers_in_log - images} trigger(s) left without an image)"
        meta["spec"]["time_source"] = record["time_source"] = how
    (to / "dataset.json").write_text(json.dumps(meta, indent=2))
    frames = [json.loads(x) for x in (to / "frames.jsonl").read_text().splitlines()]
    for f in frames:
        f["telemetry"]["height_source"] = OLD_HOME_SOURCE
    (to / "frames.jsonl").write_text("".join(json.dumps(f) + "\n" for f in frames))
    return to


def _info(dataset: Path, *json_flag: str) -> subprocess.CompletedProcess[str]:
    proc = _c3(dataset.parent, "dataset", "info", dataset, *json_flag)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return proc


def test_info_names_the_home_altitude_fault_and_the_reimport(
    imported: dict[str, Path], tmp_path: Path
) -> None:
    aged = _aged(imported["ulog"], tmp_path / "ulog_old")
    text = _info(aged).stdout
    faults = [x for x in text.splitlines() if x.startswith("import fault:")]
    assert len(faults) == 1, text
    line = faults[0]
    assert "first home altitude" in line and f"{FRAMES} of {FRAMES} frames" in line, line
    assert "rectification" in line and "telemetry errors" in line, line
    redo = f"c3-matcher dataset import images flight.ulg CALIBRATION naip_store.mbtiles {aged}"
    assert redo in line and "--force" in line, line
    listed = json.loads(_info(aged, "--json").stdout)["import_faults"]
    assert len(listed) == 1 and set(listed[0]) == {"what", "affects", "redo"}, listed
    assert listed[0]["redo"].startswith(redo), listed


def test_the_dataflash_import_of_then_is_said_too(
    imported: dict[str, Path], tmp_path: Path
) -> None:
    aged = _aged(imported["bin"], tmp_path / "bin_old")
    faults = load_dataset(aged).import_faults
    assert [type(f) for f in faults] == [ImportFault], faults
    assert "first home altitude" in faults[0].what and "flight.bin" in faults[0].redo


def test_triggers_counted_twice_are_said_where_the_counts_show_it(
    imported: dict[str, Path], tmp_path: Path
) -> None:
    twice = load_dataset(_aged(imported["bin"], tmp_path / "twice", triggers_in_log=2 * FRAMES))
    whats = [f.what for f in twice.import_faults]
    assert len(whats) == 2 and "CAM and TRIG" in whats[1], whats
    assert f"{2 * FRAMES} camera triggers for {FRAMES} images" in whats[1], whats
    once = load_dataset(_aged(imported["bin"], tmp_path / "once", triggers_in_log=FRAMES))
    assert len(once.import_faults) == 1, once.import_faults  # the home altitude's alone


def test_each_note_is_one_line_from_the_printer(imported: dict[str, Path], tmp_path: Path) -> None:
    aged = load_dataset(_aged(imported["bin"], tmp_path / "old", triggers_in_log=2 * FRAMES))
    said: list[str] = []
    say_import_faults(aged, say=said.append)
    assert len(said) == 2 and all("\n" not in x for x in said), said
    assert all(x.startswith(f"warning: dataset {aged.root}: ") for x in said), said
    stream = io.StringIO()
    say_import_faults(aged, aged, say=lambda line: print(line, file=stream))
    assert stream.getvalue().splitlines() == said * 2  # each dataset's, in order


def test_a_fresh_import_records_its_maker_and_has_no_note(imported: dict[str, Path]) -> None:
    for key in ("ulog", "bin"):
        spec = json.loads((imported[key] / "dataset.json").read_text())["spec"]
        assert spec["c3-matcher"] == __version__ and spec["import_revision"] == IMPORT_REVISION
        assert load_dataset(imported[key]).import_faults == ()
        assert "import fault" not in _info(imported[key]).stdout
        assert json.loads(_info(imported[key], "--json").stdout)["import_faults"] == []


def test_a_rendered_dataset_has_no_note(tmp_path: Path) -> None:
    assert load_dataset(DEMO).import_faults == ()  # rendered before datasets said their maker
    proc = _c3(
        tmp_path, "dataset", "render", NAIP_2020, DEMO / "tiles.mbtiles", "ds", "--frames", "2"
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    spec = json.loads((tmp_path / "ds" / "dataset.json").read_text())["spec"]
    assert spec["c3-matcher"] == __version__ and spec["render_revision"] == RENDER_REVISION
    assert "import_revision" not in spec
    assert load_dataset(tmp_path / "ds").import_faults == ()
    assert "import fault" not in _info(tmp_path / "ds").stdout


def test_a_dataset_of_a_later_revision_is_told_by_its_revision(
    imported: dict[str, Path], tmp_path: Path
) -> None:
    """A fault fixed at a revision applies to datasets of an earlier one alone: a dataset made
    now, its height sources written as then, is not taken for one made then."""
    aged = _aged(imported["ulog"], tmp_path / "relabelled")
    meta: dict[str, Any] = json.loads((aged / "dataset.json").read_text())
    meta["spec"]["import_revision"] = IMPORT_REVISION
    (aged / "dataset.json").write_text(json.dumps(meta))
    assert load_dataset(aged).import_faults == ()


def test_replay_says_the_fault_before_it_runs(
    imported: dict[str, Path], tmp_path: Path, engine_dir: Path
) -> None:
    """``replay`` of such a dataset runs (a user may replay it on purpose) and says the fault on
    stderr; a fresh import's replay says nothing of the kind."""
    aged = _aged(imported["ulog"], tmp_path / "ulog_old")
    said = {}
    for name, dataset in (("aged", aged), ("fresh", imported["ulog"])):
        argv = ("replay", dataset, "--strategy", "xfeat", "--limit", "1", "--out", tmp_path / name)
        proc = run_cli(*argv, cwd=tmp_path, engine_dir=engine_dir, timeout=600)
        assert proc.returncode == 0, proc.stderr[-2000:]
        said[name] = [x for x in proc.stderr.splitlines() if "first home altitude" in x]
    assert len(said["aged"]) == 1 and str(aged) in said["aged"][0], said
    assert said["fresh"] == [], said


@pytest.fixture(scope="module")
def named(imported: dict[str, Path]) -> Path:
    """A fresh import of the ULog named apart from its folder (``--name``) and given log
    options (``--max-gap``, ``--gnss-degraded-m``)."""
    argv = ("images", "flight.ulg", DEMO / "calibration.json", "naip_store.mbtiles", "named")
    given = ("--name", "myflight", "--max-gap", "2", "--gnss-degraded-m", "3")
    proc = _c3(imported["work"], "dataset", "import", *argv, *given)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return imported["work"] / "named"


def _redo_words(dataset: Path) -> list[str]:
    """The words of the command the dataset's first import fault gives to re-import it (the
    command alone, without the note that follows it)."""
    faults = load_dataset(dataset).import_faults
    assert faults, dataset
    redo = faults[0].redo
    return shlex.split(redo[: redo.index(" --force") + len(" --force")])


def _option(words: list[str], option: str) -> str | None:
    """The value that follows ``option`` among ``words`` (None: not there)."""
    return words[words.index(option) + 1] if option in words else None


def test_the_reimport_carries_the_name_and_the_options_given(named: Path, tmp_path: Path) -> None:
    spec = json.loads((named / "dataset.json").read_text())["spec"]
    assert spec["options"] == {"--max-gap": 2.0, "--gnss-degraded-m": 3.0}, spec
    aged = _aged(named, tmp_path / "old")
    words = _redo_words(aged)
    assert _option(words, "--name") == "myflight", words
    assert _option(words, "--max-gap") == "2.0", words
    assert _option(words, "--gnss-degraded-m") == "3.0", words
    assert "if you gave them" not in load_dataset(aged).import_faults[0].redo


def test_running_the_reimport_makes_the_same_dataset_again(
    named: Path, imported: dict[str, Path], tmp_path: Path
) -> None:
    aged = _aged(named, tmp_path / "old")
    words = _redo_words(aged)
    assert words[:3] == ["c3-matcher", "dataset", "import"], words
    given = [str(DEMO / "calibration.json") if w == "CALIBRATION" else w for w in words[1:]]
    proc = run_cli(*given, cwd=imported["work"], timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    again = load_dataset(aged)
    assert again.name == "myflight" and again.import_faults == ()
    fresh = json.loads((named / "dataset.json").read_text())["spec"]
    assert again.meta["spec"]["options"] == fresh["options"]


def test_a_dataset_that_did_not_record_its_options_says_which_it_cannot_know(
    named: Path, tmp_path: Path
) -> None:
    """A dataset imported before imports recorded their log options: the command carries its
    name, and the note names the options the dataset cannot tell."""
    aged = _aged(named, tmp_path / "older")
    meta: dict[str, Any] = json.loads((aged / "dataset.json").read_text())
    meta["spec"].pop("options", None)
    (aged / "dataset.json").write_text(json.dumps(meta))
    words = _redo_words(aged)
    assert _option(words, "--name") == "myflight" and "--max-gap" not in words, words
    redo = load_dataset(aged).import_faults[0].redo
    for option in ("--max-gap", "--gnss-degraded-m", "--ground-elevation or --dem"):
        assert option in redo.split(" --force", 1)[1], redo
    assert "if you gave them" in redo, redo


_BY_OWN_TIME_THEN = (
    "camera trigger nearest each image's own UTC time, within 1 s (5 in the log, 4 image(s): "
    "1 trigger(s) left without an image)"
)
"""How the importer before 2026-12-05 said photos met triggers of another count."""


def _spec(revision: int | None, offset: float | None, how: str) -> dict[str, Any]:
    """A ULog import's spec of ``revision`` (None: before revisions were recorded) with
    ``time_offset_s`` ``offset`` and the time source ``how``."""
    spec: dict[str, Any] = {
        "kind": "import",
        "log": "flight.ulg",
        "log_kind": "PX4 ULog",
        "source_kind": "ulog",
        "images": "photos",
        "store": "naip_store.mbtiles",
        "time_source": how,
        "time_offset_s": offset,
        "options": {},
    }
    return spec if revision is None else {**spec, "import_revision": revision}


def _faults(spec: dict[str, Any]) -> tuple[ImportFault, ...]:
    meta = {"name": "f", "spec": spec, "import": {"time_source": spec["time_source"]}}
    return import_faults(Path("f"), meta, [])


def test_photos_met_by_their_own_time_before_the_clock_was_sought_are_said() -> None:
    """Before import revision 3 photos met triggers of another count each at the trigger
    nearest its own time with the camera's clock taken as the log's: a clock off by an interval
    put every photo on another's pose. Such a dataset, no offset given, is said with a re-import
    that finds the clock's offset (no --time-offset); one given an offset was placed as it is
    now, and a dataset of revision 3 is told by its revision."""
    for revision in (None, 2):
        faults = _faults(_spec(revision, 0.0, _BY_OWN_TIME_THEN))
        assert len(faults) == 1, faults
        assert "its 4 photos met the log's 5 camera triggers" in faults[0].what, faults
        assert "another photo's trigger" in faults[0].what and "position" in faults[0].affects
        assert "--time-offset" not in faults[0].redo.split(" (", 1)[0], faults[0].redo
    assert _faults(_spec(2, -4.0, _BY_OWN_TIME_THEN)) == ()  # the offset the user gave
    assert _faults(_spec(IMPORT_REVISION, None, _BY_OWN_TIME_THEN)) == ()
    now = _BY_OWN_TIME_THEN.replace("time, within", "time, --time-offset +0 s as given, within")
    assert _faults(_spec(2, 0.0, now)) == ()


def test_a_time_offset_of_0_given_is_repeated_by_the_reimport() -> None:
    """``--time-offset 0`` says the camera's clock is the log's (no offset sought): its dataset
    records 0, one not given None, and the re-import repeats the 0 (without it photos and
    triggers of another count are sought again, and a tie refused). Before revision 3 a 0 was
    recorded for none given, so it is not repeated."""

    def words(spec: dict[str, Any]) -> list[str]:
        return shlex.split(reimport_command(Path("f"), spec).split(" (", 1)[0])

    given = words(_spec(IMPORT_REVISION, 0.0, "camera trigger"))
    assert given[given.index("--time-offset") + 1] == "0.0", given
    assert "--time-offset" not in words(_spec(IMPORT_REVISION, None, "camera trigger"))
    assert "--time-offset" not in words(_spec(2, 0.0, "camera trigger"))
    then = words(_spec(2, -4.0, "camera trigger"))
    assert then[then.index("--time-offset") + 1] == "-4.0", then


def test_the_report_says_the_offset_applied_and_where_it_came_from() -> None:
    """An offset found is reported as applied, not the 0 of no --time-offset; an old record
    without the origin reads as given where its offset is not 0."""
    record: dict[str, Any] = {
        "source": "flight.ulg",
        "kind": "PX4 ULog",
        "frames": 4,
        "skipped": [],
        "time_source": "camera trigger nearest each image's own UTC time, ...",
        "time_offset_s": -4.0,
        "height_sources": {},
        "attitude_assumed": [],
        "height_assumed": [],
        "gnss_degraded": [],
        "zoom": 16,
        "time_offset_origin": "found",
    }
    found = ImportReport.from_record(record, "f")
    assert "..., offset -4.000 s (found)" in found.lines()[1], found.lines()
    assert found.to_json()["time_offset_origin"] == "found"
    del record["time_offset_origin"]
    assert ImportReport.from_record(record, "f").time_offset_origin == "given"
    assert (
        ImportReport.from_record({**record, "time_offset_s": 0}, "f")
        .lines()[1]
        .endswith("offset +0.000 s (not given)")
    )
