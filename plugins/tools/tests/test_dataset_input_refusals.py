"""Dataset inputs refused with one line naming the option or file and what was wrong (exit 2):
a damaged or unreferenced ``--dem`` (no GDAL "see previous exception", no Python warning, the
file closed), a dataset's own calibration.json named as the dataset's (not ``--calibration``),
``--force`` onto a file, unbounded ``--image-size`` / ``--frames``, and a dataset.json that
``dataset info``, ``replay`` and ``eval`` refuse alike, naming the key."""

from __future__ import annotations

import json
import shutil
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from c3_matcher.cli import main
from c3_matcher.errors import InvalidInputError
from c3_matcher_tools.dataset.atomic import check_output_dir
from c3_matcher_tools.dataset.sources.frames import ground_elevation_sampler
from c3_matcher_tools.testing.cli import run_cli

SmallFlight = Callable[..., Path]  # the fixtures of conftest.py
REPO = Path(__file__).resolve().parents[3]
FLIGHT = REPO / "data" / "flights" / "naip_demo"
DEMO = REPO / "data" / "demo"
TILED = REPO / "data" / "imagery" / "open_orthophotos" / "test_tiled.tif"
NAIP_2020 = REPO / "data" / "imagery" / "naip_timeseries" / "m_4709963_se_14_1_20200831.tif"
ULOG = (
    REPO / "plugins" / "tools" / "tests" / "data" / "logs" / "px4_cubeorange_sample_log_small.ulg"
)


def _one_line(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "internal error" not in err, err
    return err


# --- 1. --dem -------------------------------------------------------------------------------


def _truncated(tmp_path: Path) -> Path:
    path = tmp_path / "trunc.tif"
    path.write_bytes(TILED.read_bytes()[:60000])
    return path


def _png_named_tif(tmp_path: Path) -> Path:
    path = tmp_path / "png.tif"
    shutil.copyfile(DEMO / "tile_a.png", path)
    return path


def test_a_truncated_dem_names_the_option_the_file_and_the_cause(tmp_path: Path) -> None:
    dem = _truncated(tmp_path)
    with pytest.raises(InvalidInputError) as refused:
        ground_elevation_sampler(dem)
    said = str(refused.value)
    assert said.startswith(f"--dem: {dem}: damaged raster, its pixels cannot be read ("), said
    assert "previous exception" not in said


def test_a_dem_without_georeference_is_refused_without_a_python_warning(tmp_path: Path) -> None:
    dem = _png_named_tif(tmp_path)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with pytest.raises(InvalidInputError, match=f"^--dem: {dem}: no georeference"):
            ground_elevation_sampler(dem)
    assert [str(w.message) for w in caught] == []


def test_the_dem_is_closed_once_read_and_still_answers(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import rasterio
    from affine import Affine

    dem = tmp_path / "dem.tif"
    values = np.full((1, 20, 20), 312.5, np.float32)
    values[:, :, 10:] = -9999.0
    with rasterio.open(
        dem, "w", driver="GTiff", width=20, height=20, count=1, dtype="float32",
        crs="EPSG:4326", transform=Affine.translation(10.0, 50.0) @ Affine.scale(0.01, -0.01),
        nodata=-9999.0,
    ) as ds:  # fmt: skip
        ds.write(values)
    opened: list[Any] = []
    real_open = rasterio.open

    def spy(*args: Any, **kwargs: Any) -> Any:
        opened.append(real_open(*args, **kwargs))
        return opened[-1]

    monkeypatch.setattr(rasterio, "open", spy)
    at = ground_elevation_sampler(dem)
    assert opened and all(ds.closed for ds in opened)
    assert at(49.95, 10.05) == pytest.approx(312.5)
    assert at(49.95, 10.15) is None  # nodata
    assert at(40.0, 10.05) is None  # outside


@pytest.mark.parametrize(
    ("make", "said"),
    [
        (_truncated, "damaged raster, its pixels cannot be read ("),
        (_png_named_tif, "no georeference (CRS)"),
    ],
)
def test_dataset_import_with_a_bad_dem_says_one_line(
    tmp_path: Path, make: Callable[[Path], Path], said: str
) -> None:
    """The audit's reproduction: a PX4 log import whose --dem is damaged or not georeferenced."""
    images = tmp_path / "imgs"
    images.mkdir()
    for i in range(5):
        shutil.copyfile(FLIGHT / "frames" / f"{i:06d}.jpg", images / f"{i:06d}.jpg")
    dem = make(tmp_path)
    proc = run_cli(
        "dataset", "import", images, ULOG, FLIGHT / "calibration.json", FLIGHT / "tiles.mbtiles",
        tmp_path / "out", "--interval", "1", "--time-offset", "21", "--dem", dem,
        cwd=REPO, timeout=300,
    )  # fmt: skip
    assert proc.returncode == 2, proc.stderr
    lines = [x for x in proc.stderr.splitlines() if x.strip()]
    assert len(lines) == 1 and lines[0].startswith(f"c3-matcher: --dem: {dem}: {said}"), lines
    assert not (tmp_path / "out").exists()


# --- 2 and 6. a dataset's own files ----------------------------------------------------------


def _refusals(root: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> list[str]:
    """What ``dataset info``, ``replay``, ``eval`` and ``bench --data`` say of ``root`` (each
    exit 2, one line, no output directory made)."""
    said = []
    for argv in (
        ["dataset", "info", str(root)],
        ["replay", str(root), "--out", str(tmp_path / "replay")],
        ["eval", str(root), "--out", str(tmp_path / "eval")],
        ["bench", "--data", str(root), "--runs", "1", "--no-reference", "--no-baseline"],
    ):
        assert main(argv) == 2, argv
        said.append(_one_line(capsys))
    assert not (tmp_path / "replay").exists() and not (tmp_path / "eval").exists()
    return said


@pytest.mark.parametrize(
    ("damage", "why"),
    [
        (lambda cal: cal.unlink(), "no such file"),
        (lambda cal: cal.write_text('{"K": 1}'), 'missing key "image_size"'),
        (
            lambda cal: cal.write_text(
                json.dumps({**json.loads(cal.read_text()), "image_size": ["a", 480]})
            ),
            "image_size: expected [width, height] as whole numbers of px, got ['a', 480]",
        ),
    ],
)
def test_a_datasets_calibration_is_named_as_the_datasets_not_as_an_option(
    small_flight: SmallFlight,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    damage: Callable[[Path], None],
    why: str,
) -> None:
    root = small_flight("flight")
    damage(root / "calibration.json")
    for said in _refusals(root, tmp_path, capsys):
        assert said.startswith(f"c3-matcher: dataset: {root / 'calibration.json'}: {why}"), said
        assert "--calibration" not in said


def _edit_meta(root: Path, **values: Any) -> None:
    meta = json.loads((root / "dataset.json").read_text())
    (root / "dataset.json").write_text(json.dumps({**meta, **values}))


@pytest.mark.parametrize(
    ("values", "why"),
    [
        ({"name": "a/b"}, "name: 'a/b': cannot name an output directory"),
        ({"name": 7}, "name: 7: expected a string"),
        ({"zoom": "fifteen"}, "zoom: expected an integer, got 'fifteen'"),
        ({"zoom": 31}, "zoom: must be in [0, 30], got 31"),
        ({"absent_frames": "all"}, "absent_frames: expected a list of frame indices, got 'all'"),
        ({"absent_frames": [13, -1]}, "absent_frames: must be in [0, "),
        ({"tiles_source": 5}, "tiles_source: expected a string, got 5"),
        ({"gt_fit_max_residual_px": "small"}, "gt_fit_max_residual_px: expected a number"),
        ({"spec": []}, "spec: expected a JSON object, got list"),
    ],
)
def test_info_replay_eval_and_bench_refuse_the_same_dataset_json_naming_the_key(
    small_flight: SmallFlight,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    values: dict[str, Any],
    why: str,
) -> None:
    root = small_flight("flight")
    _edit_meta(root, **values)
    said = _refusals(root, tmp_path, capsys)
    assert said[0].startswith(f"c3-matcher: dataset: {root / 'dataset.json'}: {why}"), said[0]
    assert len(set(said)) == 1, said


def _edit_first_homography(root: Path, edit: Callable[[np.ndarray], np.ndarray]) -> None:
    """Replace the first candidate's ground-truth homography of the first frame by its edit."""
    lines = (root / "frames.jsonl").read_text().splitlines()
    frame = json.loads(lines[0])
    h = np.asarray(frame["candidates"][0]["h_tile_to_undistorted"], dtype=np.float64)
    frame["candidates"][0]["h_tile_to_undistorted"] = edit(h).tolist()
    (root / "frames.jsonl").write_text("\n".join([json.dumps(frame), *lines[1:]]) + "\n")


def test_a_singular_ground_truth_homography_is_refused_before_anything_runs(
    small_flight: SmallFlight, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """It crashed replay and eval mid-run (LinAlgError, an internal error) after --out was
    emptied of the previous run."""
    root = small_flight("flight")
    _edit_first_homography(root, lambda h: np.vstack([h[:2], h[:1]]))
    for said in _refusals(root, tmp_path, capsys):
        assert "h_tile_to_undistorted: singular" in said, said


def test_a_homography_that_sends_the_frames_centre_to_infinity_gives_no_truth_from_it(
    small_flight: SmallFlight,
) -> None:
    """Its truth position was infinite and written as ``Infinity`` into results.jsonl and the
    GeoJSON (not JSON), then refused mid-run: the next candidate's homography gives it."""
    from c3_matcher_tools.dataset.format import load_dataset
    from c3_matcher_tools.run.scoring import truth_position

    root = small_flight("flight")
    before = load_dataset(root)
    expected = truth_position(before, before.frames[0])
    k = before.calibration.K

    def to_infinity(h: np.ndarray) -> np.ndarray:
        g = np.linalg.inv(h)  # undistorted -> tile: its w row now 0 at the principal point
        g[2] = [1.0, 0.0, -k[0, 2]]
        return np.linalg.inv(g)

    _edit_first_homography(root, to_infinity)
    after = load_dataset(root)
    first = after.frames[0]
    assert len(first.candidates) > 1 and expected is not None
    got = truth_position(after, first)
    assert got is not None and np.allclose(got, expected, atol=1e-6)


def test_the_shipped_flights_still_pass_dataset_info(capsys: pytest.CaptureFixture[str]) -> None:
    for meta in sorted(FLIGHT.parent.glob("*/dataset.json")):
        assert main(["dataset", "info", str(meta.parent), "--json"]) == 0, meta
        assert json.loads(capsys.readouterr().out)["name"] == meta.parent.name


def test_every_shipped_frame_with_its_true_tile_is_shown_by_it() -> None:
    """What ``dataset render`` now requires of a frame it labels present (its true tile holds
    imagery under at least 95 % of it): each true tile's data mask warped onto the frame through
    the recorded ground truth. 0.0 % nodata on every shipped flight when written."""
    import cv2

    from c3_matcher_tools.dataset.flight_plan import MAX_TRUE_NODATA
    from c3_matcher_tools.dataset.format import load_dataset

    for meta in sorted(FLIGHT.parent.glob("*/dataset.json")):
        dataset = load_dataset(meta.parent)
        size = tuple(dataset.calibration.image_size)
        with dataset.open_store() as store:
            for frame in dataset.frames:
                if frame.true_index is None:
                    continue
                truth = frame.candidates[frame.true_index]
                tile = store.handle(truth.tile_id, dataset.candidate_size_px).decode()
                data = np.where(tile.max(axis=2) > 0, np.uint8(255), np.uint8(0))
                seen = cv2.warpPerspective(
                    data, truth.h_tile_to_undistorted, size, flags=cv2.INTER_NEAREST
                )
                nodata = float((seen == 0).mean())
                assert nodata <= MAX_TRUE_NODATA, (meta.parent.name, frame.index, nodata)


# --- 4. --force onto a file ------------------------------------------------------------------


def test_force_onto_a_file_says_force_replaces_only_a_dataset_directory(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    target = tmp_path / "empty.jpg"
    target.write_bytes(b"keep")
    argv = ["dataset", "render", str(NAIP_2020), str(FLIGHT / "tiles.mbtiles"), str(target)]
    assert main([*argv, "--frames", "3", "--force"]) == 2
    said = _one_line(capsys)
    assert said == (
        f"c3-matcher: OUT: {target} already exists and is not a directory: --force replaces "
        "only a dataset directory, not a file; choose another OUT or remove the file"
    )
    assert "or --force" not in said and target.read_bytes() == b"keep"
    assert main([*argv, "--frames", "3"]) == 2  # without --force: the hint to use it stays
    assert _one_line(capsys).endswith("already exists (and is not a directory): choose another "
                                      "or --force")  # fmt: skip


def test_force_never_replaces_a_directory_that_is_not_a_dataset(
    small_flight: SmallFlight, tmp_path: Path
) -> None:
    other = tmp_path / "photos"
    other.mkdir()
    (other / "IMG_0001.jpg").write_bytes(b"keep")
    with pytest.raises(InvalidInputError, match="not a dataset .*--force replaces only a dataset"):
        check_output_dir(other, force=True)
    check_output_dir(small_flight("flight"), force=True)  # a dataset: replaced
    (tmp_path / "empty").mkdir()
    check_output_dir(tmp_path / "empty", force=True)  # nothing to lose


# --- 5. bounded render sizes -----------------------------------------------------------------

RENDER = ["dataset", "render", str(NAIP_2020), str(FLIGHT / "tiles.mbtiles")]


@pytest.fixture
def no_rendering(monkeypatch: pytest.MonkeyPatch) -> None:
    """A render that gets as far as rendering fails the test at once (instead of allocating
    100000x100000 px or planning 10^8 frames)."""
    import c3_matcher_tools.dataset.flight as flight

    def refuse(*args: object, **kwargs: object) -> None:
        raise AssertionError("the render started: the sizes were not refused up front")

    monkeypatch.setattr(flight, "render_flight", refuse)


@pytest.mark.parametrize(
    ("option", "value", "said"),
    [
        ("--image-size", "100000x100000", "each side must be in [16, 8192] px, got 100000x100000"),
        ("--image-size", "0x0", "each side must be in [16, 8192] px, got 0x0"),
        ("--image-size", "320x8193", "each side must be in [16, 8192] px, got 320x8193"),
        ("--frames", "100000000", "must be <= 10000 (a render holds every frame in memory)"),
    ],
)
@pytest.mark.usefixtures("no_rendering")
def test_render_sizes_are_bounded_while_parsing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], option: str, value: str, said: str
) -> None:
    with pytest.raises(SystemExit) as stop:
        main([*RENDER, str(tmp_path / "out"), option, value])
    assert stop.value.code == 2
    err = _one_line(capsys)
    assert f"argument {option}: {said}" in err, err
    assert not (tmp_path / "out").exists()


@pytest.mark.usefixtures("no_rendering")
def test_render_refuses_frames_that_would_not_fit_in_memory_before_rendering(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "out"
    assert main([*RENDER, str(out), "--frames", "1000", "--image-size", "8192x8192"]) == 2
    assert _one_line(capsys) == (
        "c3-matcher: --frames: 1000 frames of 8192x8192 px is 67.1 Gpx, more than a render "
        "holds in memory (2.1 Gpx): at most 32 frames of this --image-size; lower --frames or "
        "--image-size"
    )
    assert not out.exists()


def test_render_help_states_the_limits(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["dataset", "render", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "each side 16..8192" in text and "1..10000" in text
