"""The ground tools installed without one of their extras (``engine-build``, ``report``, ``geo``,
``logs``, ``dask``): every command gives working output, or one line naming the extra to install
as ``pip install 'c3-matcher-tools[EXTRA]'`` (exit 2, nothing written). An extra is taken away in
this process: its modules set to None in ``sys.modules``, so importing them raises ImportError as
where they are not installed."""

from __future__ import annotations

import json
import shutil
import sqlite3
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

from c3_matcher.errors import InvalidInputError

REPO = Path(__file__).resolve().parents[3]
DEMO = REPO / "data" / "flights" / "naip_demo"
CAL = str(DEMO / "calibration.json")
STORE = str(DEMO / "tiles.mbtiles")
ZURICH = REPO / "data" / "imagery" / "open_orthophotos" / "swissimage_zurich_1091-322_00_0p5m.tif"
QUICK = ("--determinism-frames", "1", "--samples", "0")

SmallFlight = Callable[..., Path]  # the fixtures of conftest.py
Without = Callable[..., None]

DASK = "pip install 'c3-matcher-tools[dask]'"
LOGS = "pip install 'c3-matcher-tools[logs]'"
GEO = "pip install 'c3-matcher-tools[geo]'"
ENGINE_BUILD = "pip install 'c3-matcher-tools[engine-build]'"
REPORT = "pip install 'c3-matcher-tools[report]'"


@pytest.fixture()
def without(monkeypatch: pytest.MonkeyPatch) -> Without:
    """``without("dask", ...)``: each package, and every module of it already imported, is not
    installed for the rest of the test (importing it raises ImportError)."""

    def take_away(*packages: str) -> None:
        for package in packages:
            for name in [n for n in sys.modules if n == package or n.startswith(package + ".")]:
                monkeypatch.setitem(sys.modules, name, None)
            monkeypatch.setitem(sys.modules, package, None)

    return take_away


def _one_line(err: str, *needles: str) -> str:
    """The one non-empty line of ``err``, holding every needle."""
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    for needle in needles:
        assert needle in lines[0], lines[0]
    return lines[0]


# features build: the dask extra


def _sidecar_rows(flight: Path) -> list[tuple[object, ...]]:
    """Every stored window and every set (without its creation time) of ``flight``'s sidecar."""
    with sqlite3.connect(flight / "tiles.mbtiles.features.sqlite") as db:
        windows = db.execute("SELECT * FROM window_features ORDER BY set_id, zoom, gx, gy")
        sets = db.execute(
            "SELECT set_id, extractor_sha256, provider, multiple, photometric, border_erode_px, "
            "window_px, stride_px, descriptor_dim, strategy, complete, windows, descriptor_dtype "
            "FROM window_sets ORDER BY set_id"
        )
        return [*windows.fetchall(), *sets.fetchall()]


@pytest.mark.slow
def test_features_build_without_dask_builds_in_this_process_as_workers_0_does(
    small_flight: SmallFlight,
    engine_dir: Path,
    without: Without,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """The default (``--workers 2``) died "internal error: ModuleNotFoundError: No module named
    'dask'" (exit 1)."""
    from c3_matcher.cli import main

    monkeypatch.setenv("C3_MATCHER_ENGINES__DIRECTORY", str(engine_dir))
    here = small_flight("here", where="here")
    argv = ["features", "build", "--strategy", "xfeat", "--flight-candidates"]
    assert main([*argv, str(here), "--workers", "0"]) == 0
    capsys.readouterr()
    default = small_flight("default", where="default")
    without("dask", "distributed")
    assert main([*argv, str(default)]) == 0
    said = capsys.readouterr()
    assert said.err.count(DASK) == 1, said.err
    assert "dask is not installed" in said.err and "in this process" in said.err
    assert "xfeat:" in said.out and "extracted" in said.out
    assert _sidecar_rows(default) == _sidecar_rows(here)  # the same sets, bit for bit
    assert not list(default.glob("*.lock"))


@pytest.mark.parametrize(
    "where", [["--workers", "2"], ["--workers", "1"], ["--scheduler", "tcp://127.0.0.1:8786"]]
)
def test_features_build_asked_for_dask_workers_without_dask_is_refused_naming_the_extra(
    where: list[str],
    small_flight: SmallFlight,
    without: Without,
    capsys: pytest.CaptureFixture[str],
) -> None:
    from c3_matcher.cli import main

    flight = small_flight("asked")
    before = sorted(p.name for p in flight.iterdir())
    without("dask", "distributed")
    assert main(["features", "build", str(flight), "--strategy", "xfeat", *where]) == 2
    err = capsys.readouterr().err
    _one_line(err, where[0], DASK, "--workers 0")
    assert "internal error" not in err and "Traceback" not in err
    assert sorted(p.name for p in flight.iterdir()) == before  # no sidecar, no lock file


# dataset import of a photo folder: the logs extra


def test_a_photo_folder_import_without_the_logs_extra_names_it_not_the_photos_gps(
    tmp_path: Path, without: Without, capsys: pytest.CaptureFixture[str]
) -> None:
    """It said "none of the 4 photo(s) has a GPS position in its EXIF", which was not so."""
    from c3_matcher.cli import main
    from c3_matcher_tools.testing import flightlogs as fl
    from c3_matcher_tools.testing.flightlogs.exif import write_exif_photos

    photos = write_exif_photos(tmp_path / "photos", fl.flight_poses(DEMO, range(4)))
    out = tmp_path / "flight"
    without("exifread")
    assert main(["dataset", "import", str(photos), "-", CAL, STORE, str(out)]) == 2
    err = capsys.readouterr().err
    _one_line(err, str(photos), "photo", "the logs extra", LOGS)
    assert "GPS position" not in err
    assert not out.exists()


def test_photos_read_without_exifread_are_refused_once_naming_the_extra(
    tmp_path: Path, without: Without
) -> None:
    """Where photos meet a flight log by their EXIF times, too."""
    from c3_matcher_tools.dataset.sources.images import folder_shots
    from c3_matcher_tools.testing import flightlogs as fl
    from c3_matcher_tools.testing.flightlogs.exif import write_exif_photos

    photos = write_exif_photos(tmp_path / "photos", fl.flight_poses(DEMO, range(2)))
    without("exifread")
    with pytest.raises(InvalidInputError, match=r"reading photo metadata \(EXIF\) needs the logs"):
        folder_shots(photos)
    assert [s.name for s in folder_shots(photos, metadata=False)] == sorted(
        p.name for p in photos.iterdir()
    )


@pytest.mark.parametrize(
    "pairing", [["trigger"], ["order", "--interval", "2", "--time-offset", "100"]]
)
def test_photos_paired_with_a_log_by_trigger_or_order_need_no_exif_reader(
    pairing: list[str], tmp_path: Path, without: Without
) -> None:
    """Their EXIF is never read there: imported without exifread (pyulog installed alone)."""
    from c3_matcher.cli import main
    from c3_matcher_tools.testing import flightlogs as fl
    from c3_matcher_tools.testing.flightlogs.ulog import write_ulog

    poses = fl.flight_poses(DEMO, range(4))
    photos = tmp_path / "photos"
    photos.mkdir()
    for i, pose in enumerate(poses):
        shutil.copyfile(pose.image, photos / f"IMG_{i:04d}.jpg")
    log = write_ulog(tmp_path / "flight.ulg", poses)
    out = tmp_path / "flight"
    without("exifread")
    argv = ["dataset", "import", str(photos), str(log), CAL, STORE, str(out)]
    assert main([*argv, "--time-source", *pairing]) == 0
    assert len((out / "frames.jsonl").read_text().splitlines()) == 4


# engines build: the engine-build extra and the weights


def test_engines_build_without_the_extra_names_what_is_missing_and_one_install_line(
    tmp_path: Path,
    without: Without,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """It said ``pip install 'c3-matcher[engine-build]'``, an extra that does not exist, and
    exited 1."""
    from c3_matcher.cli import main

    engines = tmp_path / "engines"
    monkeypatch.setenv("C3_MATCHER_ENGINES__DIRECTORY", str(engines))
    without("torch", "onnxscript", "kornia")
    assert main(["engines", "build", "--only", "xfeat/default"]) == 2
    err = capsys.readouterr().err
    line = _one_line(err, "xfeat/default", "torch", "onnxscript", "kornia", ENGINE_BUILD)
    assert "c3-matcher[engine-build]" not in line and "Traceback" not in err
    assert not engines.exists()  # refused before anything is made


# bench: the PyTorch reference (engine-build) and a wheel install's missing demo frame


def _bench_untimed(monkeypatch: pytest.MonkeyPatch) -> list[list[str]]:
    """bench's cases planned but not timed (no worker starts): the labels of each group."""
    import c3_matcher_tools.bench

    planned: list[list[str]] = []

    def untimed(group: list, *args: object) -> tuple[list, list]:  # type: ignore[type-arg]
        planned.append([case.label for case in group])
        return [], []

    monkeypatch.setattr(c3_matcher_tools.bench, "time_interleaved", untimed)
    return planned


@pytest.mark.parametrize("as_json", [False, True])
def test_bench_without_torch_says_once_why_the_pytorch_reference_is_not_timed(
    as_json: bool,
    without: Without,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """It left the reference out without a word: the "vs torch" column blank."""
    from c3_matcher.cli import main

    planned = _bench_untimed(monkeypatch)
    without("torch")
    argv = ["bench", "--runs", "1", "--strategy", "xfeat", "--data", str(DEMO)]
    assert main([*argv, *(["--json"] if as_json else [])]) == 0
    out = capsys.readouterr().out
    assert planned and not any("pytorch" in label for group in planned for label in group)
    if as_json:
        reference = json.loads(out)["pytorch_reference"]
        assert reference["timed"] is False
        assert "torch is not installed" in reference["reason"]
        assert ENGINE_BUILD in reference["reason"]
    else:
        assert out.count("PyTorch reference") == 1, out
        assert out.count(ENGINE_BUILD) == 1 and "torch is not installed" in out


def test_bench_says_nothing_of_the_reference_when_asked_for_none(
    without: Without, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from c3_matcher.cli import main

    _bench_untimed(monkeypatch)
    without("torch")
    argv = ["bench", "--runs", "1", "--strategy", "xfeat", "--no-reference", "--data", str(DEMO)]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "PyTorch reference" not in out and ENGINE_BUILD not in out
    assert main([*argv, "--json"]) == 0
    reference = json.loads(capsys.readouterr().out)["pytorch_reference"]
    assert reference == {"timed": False, "reason": None}  # asked for: nothing to explain


def test_bench_without_data_where_no_demo_frame_ships_is_bad_input_exit_2(
    no_bench_case: None, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """It exited 1."""
    from c3_matcher.cli import main
    from c3_matcher.engines import store

    monkeypatch.setattr(store, "checkout_root", lambda: None)  # as installed from wheels
    assert main(["bench", "--runs", "3", "--no-reference", "--strategy", "xfeat"]) == 2
    _one_line(capsys.readouterr().err, "--data: required", "installed from wheels")


# tiles build of an EPSG grid: the geo extra


def test_tiles_build_of_an_epsg_grid_without_the_geo_extra_names_it_beside_ref_latlon(
    tmp_path: Path, without: Without, capsys: pytest.CaptureFixture[str]
) -> None:
    """It named pyproj and --ref-latlon, never the extra that brings pyproj."""
    from c3_matcher.cli import main

    out = tmp_path / "zurich.mbtiles"
    without("pyproj", "rasterio")
    assert main(["tiles", "build", str(ZURICH), str(out)]) == 2
    _one_line(capsys.readouterr().err, "EPSG:2056", "without pyproj", GEO, "--ref-latlon")
    assert list(tmp_path.iterdir()) == []


def test_a_grid_given_by_its_parameters_is_not_called_epsg_32767(
    tmp_path: Path, without: Without, capsys: pytest.CaptureFixture[str]
) -> None:
    """32767 marks a CRS given by its parameters (as GDAL writes one without an EPSG code): it
    named "EPSG:32767" as if it were a grid. The geo extra's reader may resolve it."""
    import numpy as np

    from c3_matcher.cli import main
    from c3_matcher_tools.testing.geotiff import projected_keys, write_geotiff

    image = np.full((64, 64, 3), 128, np.uint8)
    keys = projected_keys(32767)
    tif = write_geotiff(
        tmp_path / "g.tif", image, scale=(0.5, 0.5), top_left=(2.6e6, 1.2e6), keys=keys
    )
    without("pyproj", "rasterio")
    assert main(["tiles", "build", str(tif), str(tmp_path / "g.mbtiles")]) == 2
    err = capsys.readouterr().err
    _one_line(err, "no EPSG code", GEO, "parameters", "--ref-latlon")
    assert "32767" not in err


# eval without matplotlib: the report extra


@pytest.mark.parametrize("command", ["eval", "replay"])
def test_a_run_without_matplotlib_says_once_that_no_report_html_is_written(
    command: str,
    small_flight: SmallFlight,
    tmp_path: Path,
    without: Without,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Once a run: eval of two flights, a replay of one; the rest of each run written."""
    from c3_matcher.cli import main

    monkeypatch.setenv("C3_MATCHER_FDR__PATH", str(tmp_path / "fdr" / "c3_fdr.jsonl"))
    names = ("north", "south") if command == "eval" else ("replayed",)
    flights = [str(small_flight(name, where=name)) for name in names]
    out = tmp_path / "out"
    without("matplotlib")
    quick = QUICK if command == "eval" else []
    argv = [command, *flights, "--strategy", "sift_magsac", "--out", str(out), *quick]
    assert main(argv) == 0
    err = capsys.readouterr().err
    assert err.count("no report.html") == 1 and err.count(REPORT) == 1, err
    assert not list(out.rglob("report.html")) and list(out.rglob("flight.geojson"))
