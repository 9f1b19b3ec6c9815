"""A dataset's files stay inside its folder: a frame image, store, calibration or frame file
named by an absolute path, by one that leaves the folder once normalised, or by a symbolic link
that leads out of it is refused as the dataset is loaded, naming the file (and the line of
``frames.jsonl``): ``dataset info``, ``replay`` and ``features build`` read nothing outside it,
draw nothing from outside into a report and write nothing beside a store outside it. A link that
stays inside the folder, and a folder reached through a link, load as before."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from c3_matcher.errors import InvalidInputError
from c3_matcher_tools.dataset.format import load_dataset

from .conftest import C3, DEMO, SmallFlight, edit_dataset_meta, edit_frame_record


def _secret(tmp_path: Path) -> Path:
    """A photo outside any dataset (a real JPEG: a demo frame)."""
    secret = tmp_path / "secret" / "private_photo.jpg"
    secret.parent.mkdir()
    first = json.loads((DEMO / "frames.jsonl").read_text().splitlines()[0])
    shutil.copyfile(DEMO / first["image"], secret)
    return secret


@pytest.mark.parametrize(
    ("line", "image", "needle"),
    [
        (1, "{secret}", "is an absolute path"),
        (2, "../secret/private_photo.jpg", "leads outside the dataset folder"),
        (2, "frames/../../secret/private_photo.jpg", "leads outside the dataset folder"),
        (1, "frames/..", "names the dataset folder"),
    ],
)
def test_a_frame_image_outside_the_dataset_is_refused_naming_its_line(
    tmp_path: Path, small_flight: SmallFlight, line: int, image: str, needle: str
) -> None:
    secret, flight = _secret(tmp_path), small_flight("flight")
    edit_frame_record(flight, line, lambda r: r.update(image=image.format(secret=secret)))
    with pytest.raises(InvalidInputError) as refused:
        load_dataset(flight)
    said = str(refused.value)
    assert f"frames.jsonl:{line}: bad frame record: image: " in said and needle in said, said


@pytest.mark.parametrize("key", ["store", "calibration", "frames"])
@pytest.mark.parametrize("where", ["absolute", "../"])
def test_a_file_dataset_json_names_outside_the_dataset_is_refused_naming_it(
    tmp_path: Path, small_flight: SmallFlight, key: str, where: str
) -> None:
    flight = small_flight("flight")
    outside = tmp_path / "elsewhere"
    outside.mkdir()
    own = json.loads((flight / "dataset.json").read_text())[key]
    shutil.copyfile(flight / own, outside / own)  # a file there, so only where it is is wrong
    name = str(outside / own) if where == "absolute" else f"../elsewhere/{own}"
    edit_dataset_meta(flight, lambda m: m.update({key: name}))
    with pytest.raises(InvalidInputError) as refused:
        load_dataset(flight)
    said = str(refused.value)
    assert f"dataset.json: {key}: " in said, said
    assert ("absolute path" if where == "absolute" else "leads outside") in said, said


@pytest.mark.parametrize("key", ["store", "calibration", "frames"])
def test_a_file_of_the_dataset_linked_to_one_outside_is_refused(
    tmp_path: Path, small_flight: SmallFlight, key: str
) -> None:
    flight = small_flight("flight")
    own = json.loads((flight / "dataset.json").read_text())[key]
    (tmp_path / "shared").mkdir()
    shutil.move(flight / own, tmp_path / "shared" / own)
    (flight / own).symlink_to(tmp_path / "shared" / own)
    with pytest.raises(InvalidInputError) as refused:
        load_dataset(flight)
    said = str(refused.value)
    assert f"dataset.json: {key}: {own!r} leads outside the dataset folder" in said, said
    assert "through a symbolic link" in said and "hard-link or copy" in said, said


def test_a_frame_image_linked_to_one_outside_is_refused(
    tmp_path: Path, small_flight: SmallFlight
) -> None:
    secret, flight = _secret(tmp_path), small_flight("flight")
    (flight / "frames" / "linked.jpg").symlink_to(secret)
    edit_frame_record(flight, 2, lambda r: r.update(image="frames/linked.jpg"))
    with pytest.raises(InvalidInputError) as refused:
        load_dataset(flight)
    said = str(refused.value)
    assert "frames.jsonl:2: bad frame record: image: 'frames/linked.jpg' leads outside" in said
    assert str(secret) in said, said


def test_links_inside_the_dataset_and_to_it_load(tmp_path: Path, small_flight: SmallFlight) -> None:
    """A frame linked to another file of the dataset, a folder of frames linked within it and
    a dataset folder reached through a link all stay inside: they load."""
    flight = small_flight("flight")
    first = json.loads((flight / "frames.jsonl").read_text().splitlines()[0])["image"]
    (flight / "frames" / "again.jpg").symlink_to(Path(first).name)
    (flight / "same").symlink_to("frames")
    edit_frame_record(flight, 1, lambda r: r.update(image="frames/again.jpg"))
    edit_frame_record(flight, 2, lambda r: r.update(image="same/" + Path(r["image"]).name))
    (tmp_path / "via").symlink_to(flight)
    for root in (flight, tmp_path / "via"):
        loaded = load_dataset(root)
        assert loaded.frames[0].image == "frames/again.jpg"
        assert all(loaded.nav_frame(f).image.size for f in loaded.frames)


def test_every_shipped_flight_loads() -> None:
    shipped = sorted(p for p in DEMO.parent.iterdir() if (p / "dataset.json").is_file())
    assert len(shipped) >= 15
    for root in shipped:
        assert load_dataset(root).frames, root


def test_dataset_info_and_replay_refuse_a_frame_outside_before_reading_it(
    tmp_path: Path, small_flight: SmallFlight, c3: C3
) -> None:
    """The reported case: frame 2's image is ``../secret/private_photo.jpg``. ``dataset info``
    and ``replay`` exit 2 naming the line; replay writes no report (it would hold the photo)."""
    _secret(tmp_path)
    flight = small_flight("flight")
    edit_frame_record(flight, 2, lambda r: r.update(image="../secret/private_photo.jpg"))
    info = c3("dataset", "info", str(flight))
    assert info.returncode == 2, info.stderr
    assert "frames.jsonl:2: bad frame record: image: " in info.stderr, info.stderr
    out = tmp_path / "out"
    replay = c3("replay", str(flight), "--strategy", "sift_magsac", "--out", str(out))
    assert replay.returncode == 2, replay.stderr
    assert "leads outside the dataset folder" in replay.stderr, replay.stderr
    assert not (out / "report.html").exists()


def test_features_build_writes_nothing_beside_a_store_outside(
    tmp_path: Path, small_flight: SmallFlight, c3: C3
) -> None:
    flight = small_flight("flight")
    (tmp_path / "other").mkdir()
    shutil.move(flight / "tiles.mbtiles", tmp_path / "other" / "tiles.mbtiles")
    edit_dataset_meta(flight, lambda m: m.update(store="../other/tiles.mbtiles"))
    argv = ["features", "build", str(flight), "--strategy", "xfeat", "--workers", "0"]
    done = c3(*argv)
    assert done.returncode == 2, done.stderr
    assert "dataset.json: store: '../other/tiles.mbtiles' leads outside" in done.stderr
    assert [p.name for p in (tmp_path / "other").iterdir()] == ["tiles.mbtiles"]
