"""Photos and camera triggers of different counts under a camera clock off the log's: the clock's
offset is one number for the whole flight, found as the one that pairs the most photos with a
trigger and stated, or the import is refused naming the offsets and ``--time-offset`` (a tie of
two offsets whole trigger intervals apart, an offset beyond the flight). Without triggers the
photos' clock is taken as stated, and the import says nothing checks it. Logs and photos are
written with the libraries' own writers over the shipped demo flight."""

from __future__ import annotations

import dataclasses
import json
import shlex
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest

from c3_matcher.errors import InvalidInputError
from c3_matcher.serialize import load_calibration
from c3_matcher_tools.dataset.format import load_dataset
from c3_matcher_tools.dataset.provenance import reimport_command
from c3_matcher_tools.dataset.sources.camera_clock import TIGHTER, fit_camera_clock
from c3_matcher_tools.dataset.sources.images import folder_shots
from c3_matcher_tools.dataset.sources.options import ImportOptions, ProposalOptions
from c3_matcher_tools.dataset.sources.pairing import match_shots
from c3_matcher_tools.dataset.sources.ulog import read_ulog
from c3_matcher_tools.testing import flightlogs as fl
from c3_matcher_tools.testing.flightlogs.exif import write_exif_photos
from c3_matcher_tools.testing.flightlogs.ulog import write_ulog

from .conftest import DEMO
from .conftest import DEMO_CALIBRATION as CAL
from .conftest import DEMO_STORE as STORE
from .conftest import run_in_repo as c3


@pytest.fixture(scope="module")
def poses() -> list[fl.Pose]:
    return fl.flight_poses(DEMO, range(5))  # 2 s apart


def _options(**kw: object) -> ImportOptions:
    return ImportOptions(load_calibration(CAL), ProposalOptions(Path(STORE)), **kw)  # type: ignore[arg-type]


def _photos(root: Path, poses: list[fl.Pose], ahead_s: float, without: int) -> Path:
    """The photos of ``poses`` but the one at ``without`` (its trigger left without a photo),
    the camera's clock ``ahead_s`` ahead of the log's."""
    kept = [
        dataclasses.replace(p, t_s=p.t_s + ahead_s) for i, p in enumerate(poses) if i != without
    ]
    names = [f"DJI_{i:04d}.JPG" for i in range(len(poses)) if i != without]
    folder = write_exif_photos(root, kept, xmp=False)
    for k, name in reversed(list(enumerate(names))):  # the writer numbers them from 0
        (folder / f"DJI_{k:04d}.JPG").rename(folder / f"x{name}")
    for name in names:
        (folder / f"x{name}").rename(folder / name)
    return folder


def test_a_camera_clock_off_by_two_trigger_intervals_is_found_and_said(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    """Clock 4 s ahead, triggers 2 s apart, a trigger without its photo: each photo lay within
    the tolerance of the trigger two later and took that pose (tens of metres off) with no
    word but a count. The offset that pairs the most, -4 s, puts each on its own pose, and the
    import says so."""
    log = write_ulog(tmp_path / "flight.ulg", poses)
    photos = _photos(tmp_path / "photos", poses, 4.0, without=2)
    flight = tmp_path / "f"
    proc = c3("dataset", "import", photos, log, CAL, STORE, flight, "--json")
    assert proc.returncode == 0, proc.stderr[-2000:]
    _on_their_own_poses(flight, poses, (0, 1, 3, 4))
    summary = json.loads(proc.stdout)
    assert summary["time_offset_s"] == pytest.approx(-4.0, abs=1e-3)  # applied, not 0
    assert summary["time_offset_origin"] == "found"
    said = summary["time_source"]
    assert "the images' times moved -4.00 s (the camera's clock 4.00 s ahead of the log's" in said
    assert "that offset pairs 4 of them" in said and said.endswith(
        "(5 in the log, 4 image(s): 1 trigger(s) left without an image)"
    )


def test_two_offsets_pairing_as_many_are_refused_naming_both_and_the_way_out(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    """The first trigger without its photo, the triggers a steady timer's (exactly 2 s
    apart): the photos at their clock, or all one interval earlier, pair 4 each (a photo lost
    at one end looks like a trigger lost at the other), and their differences to the triggers
    spread alike, as nothing in even triggers' timing tells the two apart. Refused naming both
    offsets, the triggers each leaves without a photo, and --time-offset; a --time-offset
    given is used as given."""
    track = read_ulog(write_ulog(tmp_path / "flight.ulg", poses))
    shots = folder_shots(_photos(tmp_path / "photos", poses, 0.0, without=0))
    with pytest.raises(InvalidInputError) as refused:
        match_shots(track, shots, _options())
    said = str(refused.value)
    assert "the camera clock's offset is not told by them: -2.00 s" in said
    assert "and +0.00 s each pair 4 image(s) with a trigger (the photo-trigger differences " in said
    assert "spread 1.0 ms at -2.00 s, 1.0 ms at +0.00 s)" in said
    assert said.endswith(
        "give the one that is right, --time-offset 0 (pairs DJI_0001.JPG at the trigger at "
        "102.0 s .. DJI_0004.JPG at 108.0 s, leaving the trigger(s) at 100.0 s without an image) "
        "or --time-offset -2 (pairs DJI_0001.JPG at the trigger at 100.0 s .. DJI_0004.JPG at "
        "106.0 s, leaving the trigger(s) at 108.0 s without an image)"
    )
    assert "remove the images" not in said
    right = match_shots(track, shots, _options(time_offset_s=0.0))  # the clock is right
    assert [t for _, t in right.taken] == pytest.approx([fl.BOOT_S + p.t_s for p in poses[1:]])
    given = match_shots(track, shots, _options(time_offset_s=-2.0))  # the user's word
    assert [t for _, t in given.taken] == pytest.approx([fl.BOOT_S + p.t_s for p in poses[:4]])
    assert "--time-offset -2 s as given" in given.how


def _without_first_trigger(log: Path) -> Path:
    """The ULog at ``log`` written again without its first camera trigger (lost in flight: the
    photo was taken, the log did not record it)."""
    from pyulog import ULog

    ulog = ULog(str(log))
    for data in ulog.data_list:
        if data.name == "camera_capture":
            data.data = {k: v[1:] for k, v in data.data.items()}
    with log.open("wb") as fh:
        ulog.write_ulog(fh)
    return log


def test_a_lost_first_trigger_is_refused_as_a_tie_and_imports_with_a_time_offset_of_0(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    """The first trigger lost, the camera's clock right, the triggers a steady timer's: at its
    clock, or one interval later, the photos pair 4 each with differences spread alike, so the
    import is refused naming both as --time-offset values and
    what each pairs. ``--time-offset 0`` says the camera's clock is the log's: no offset is
    searched for, and every photo but the first (no trigger) lands on its own pose. A 0 given
    was taken as not given, searched and refused alike, leaving 0.001 as the only way out."""
    log = _without_first_trigger(write_ulog(tmp_path / "flight.ulg", poses))
    photos = _photos(tmp_path / "photos", poses, 0.0, without=-1)
    flight = tmp_path / "f"
    refused = c3("dataset", "import", photos, log, CAL, STORE, flight)
    assert refused.returncode != 0 and not flight.exists()
    said = " ".join(refused.stderr.split())
    assert (
        "--time-offset 0 (pairs DJI_0001.JPG at the trigger at 102.0 s .. DJI_0004.JPG at "
        "108.0 s, leaving DJI_0000.JPG without a trigger) or --time-offset 2 (pairs "
        "DJI_0000.JPG at the trigger at 102.0 s .. DJI_0003.JPG at 108.0 s, leaving "
        "DJI_0004.JPG without a trigger)" in said
    ), said
    proc = c3("dataset", "import", photos, log, CAL, STORE, flight, "--time-offset", "0", "--json")
    assert proc.returncode == 0, proc.stderr[-2000:]
    _on_their_own_poses(flight, poses, (1, 2, 3, 4))
    summary = json.loads(proc.stdout)
    assert "--time-offset +0 s as given" in summary["time_source"]
    assert summary["time_offset_s"] == 0.0 and summary["time_offset_origin"] == "given"
    assert [s["image"] for s in summary["skipped"]] == ["DJI_0000.JPG"]
    spec = json.loads((flight / "dataset.json").read_text())["spec"]
    assert spec["time_offset_s"] == 0.0  # given, where one not given is None
    redo = shlex.split(reimport_command(flight, spec).split(" (", 1)[0])
    assert redo[redo.index("--time-offset") + 1] == "0.0", redo  # else refused as a tie again


def _uneven(poses: list[fl.Pose], seed: int) -> list[fl.Pose]:
    """``poses`` at times moved up to 0.15 s either way: triggers of a camera that fires by
    distance, or a timer that jitters, as a flight's do."""
    rng = np.random.default_rng(seed)
    return [dataclasses.replace(p, t_s=p.t_s + float(rng.uniform(-0.15, 0.15))) for p in poses]


@pytest.mark.parametrize("lost", [(0,), (4,), (0, 4)], ids=["first", "last", "both"])
def test_a_right_clock_with_triggers_lost_at_the_ends_imports_by_the_spread(
    poses: list[fl.Pose], tmp_path: Path, lost: tuple[int, ...]
) -> None:
    """The camera's clock right, triggers uneven (as a flight's are), one lost at either end or
    both: the photos at their clock and shifted one interval pair as many, but at their clock
    the differences spread by the time stamps' millisecond, shifted by the triggers'
    unevenness, so the clock is found right and every photo with a trigger lands on its own
    pose (refused as a tie before, though the camera's clock was right)."""
    flown = _uneven(poses, seed=3)
    log = write_ulog(tmp_path / "flight.ulg", flown)
    from pyulog import ULog

    ulog = ULog(str(log))
    for data in ulog.data_list:
        if data.name == "camera_capture":
            keep = [i for i in range(len(flown)) if i not in lost]
            data.data = {k: v[keep] for k, v in data.data.items()}
    with log.open("wb") as fh:
        ulog.write_ulog(fh)
    track = read_ulog(log)
    shots = folder_shots(_photos(tmp_path / "photos", flown, 0.0, without=-1))
    pairing = match_shots(track, shots, _options())
    kept = [k for k in range(len(flown)) if k not in lost]
    assert [s.name for s, _ in pairing.taken] == [f"DJI_{k:04d}.JPG" for k in kept]
    assert [t for _, t in pairing.taken] == pytest.approx([fl.BOOT_S + flown[k].t_s for k in kept])
    assert pairing.found_offset_s == pytest.approx(0.0, abs=0.002)
    assert "the camera's clock on the log's, found" in pairing.how, pairing.how
    assert "the photo-trigger differences spread 1.0 ms at +0.00 s" in pairing.how, pairing.how


def test_the_spread_breaks_a_tie_only_where_the_timing_tells() -> None:
    """Triggers uneven, photos stamped to the millisecond, a trigger lost at either end or
    both: the offset whose differences spread the least wins, clearly. Whole-second EXIF times
    of even triggers spread alike at either offset: still a tie."""
    rng = np.random.default_rng(1)
    shots = 100.0 + np.cumsum(rng.uniform(1.85, 2.15, 10))
    own = np.round(shots, 3) + 4.0  # the camera's clock 4 s ahead
    for triggers in (shots[:-1], shots[1:], shots[1:-1]):
        fit = fit_camera_clock(own, triggers, 1.0)
        assert fit is not None and not fit.tied
        assert fit.offset_s == pytest.approx(-4.0, abs=0.002)
        assert fit.runner_up is not None and fit.runner_up[1] == fit.paired
        assert fit.spread_s * TIGHTER <= fit.runner_up_spread_s
    even = 100.0 + 2.0 * np.arange(10)
    fit = fit_camera_clock(np.floor(even + 0.5), even[1:], 1.0)
    assert fit is not None and fit.tied


def test_an_offset_beyond_the_flight_is_refused_then_paired_as_given(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    """A camera clock an hour ahead (its time zone): photos whose times lie off the flight are
    no evidence they are of it, so the offset is named, not used; given, it pairs them."""
    track = read_ulog(write_ulog(tmp_path / "flight.ulg", poses))
    shots = folder_shots(_photos(tmp_path / "photos", poses, 3600.0, without=2))
    with pytest.raises(InvalidInputError, match=r"-3600\.00 s .*lies within the triggers' span"):
        match_shots(track, shots, _options())
    given = match_shots(track, shots, _options(time_offset_s=-3600.0))
    assert [t for _, t in given.taken] == pytest.approx(
        [fl.BOOT_S + poses[k].t_s for k in (0, 1, 3, 4)]
    )


def test_photos_by_their_own_time_alone_say_their_clock_is_unchecked(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    """No trigger: a camera clock off the log's moves every frame along the track and nothing
    shows it; no offset is guessed, and the import says the clock is taken as stated."""
    track = read_ulog(write_ulog(tmp_path / "flight.ulg", poses, flaws=("no_trigger",)))
    shots = folder_shots(_photos(tmp_path / "photos", poses, 0.0, without=-1))
    pairing = match_shots(track, shots, _options())
    assert len(pairing.taken) == 5
    assert len(pairing.notes) == 1 and "no camera trigger meets them" in pairing.notes[0]


def test_the_fit_holds_on_a_long_flight_of_whole_second_times() -> None:
    """2000 photos, triggers 2 s apart with jitter, the camera clock 37.3 s ahead, EXIF times
    cut to the second, three triggers lost and two stray photos: the offset found is the
    clock's (within the second the times are cut to), and quickly."""
    rng = np.random.default_rng(7)
    shots = 100.0 + np.cumsum(rng.uniform(1.9, 2.1, 2000))
    triggers = np.delete(shots, [0, 900, 1500])
    own = np.floor(np.concatenate([shots, shots[[10, 20]] + 0.7]) + 37.3)
    began = time.perf_counter()
    fit = fit_camera_clock(own, triggers, 1.0)
    assert time.perf_counter() - began < 20
    assert fit is not None and -37.3 <= fit.offset_s < -36.3  # own - trigger in (36.3, 37.3]
    assert fit.paired == triggers.size
    assert fit.runner_up is not None and fit.runner_up[1] < fit.paired


def _on_their_own_poses(flight: Path, poses: Sequence[fl.Pose], kept: Sequence[int]) -> None:
    """``flight``'s frames are the photos ``kept``, each at its own pose's time and place."""
    frames = load_dataset(flight).frames
    assert [f.telemetry["source_image"] for f in frames] == [f"DJI_{k:04d}.JPG" for k in kept]
    for f, k in zip(frames, kept, strict=True):
        p = poses[k]
        assert f.telemetry["time_s"] == pytest.approx(fl.BOOT_S + p.t_s, abs=1e-6)
        assert (f.telemetry["lat"], f.telemetry["lon"]) == pytest.approx((p.lat, p.lon), abs=1e-7)
